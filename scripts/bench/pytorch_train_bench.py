#!/usr/bin/env python3
"""Whole-training throughput of an RDPG loop in Python (Gymnasium + PyTorch), the counterpart
of `rdpg bench train`: the same env, networks, update (scripts/bench/pytorch_update_bench.py), OU
noise, warm-up and updates-per-step ratio, on one environment.

Per env step: the actor (trunk + one LSTM cell step, batch 1, no grad) picks the action, OU
noise is added, Gymnasium steps, the transition is stored in the current episode; finished
episodes go to an episodic replay. After the warm-up, `--ups` updates are made per env step
on full windows of s + l steps sampled uniformly from episodes long enough to hold one.

Prints one JSON line {"impl": "pytorch", ..., "steps_per_sec": X}.
Needs torch and gymnasium[box2d] in one environment:
  .venv/bin/pip install -r scripts/setup/requirements_reference.txt   (torch comes from setup.sh)

Usage: python scripts/bench/pytorch_train_bench.py [--env BipedalWalker-v3] [--steps 3000]
       [--warmup 500] [--ups 0.05] [--threads 2] [--scan 24] [--batch 64] [--opt 8] [--seed 0]
"""

import argparse
import json
import os
import sys
import time

import gymnasium as gym
import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pytorch_update_bench import build, cell  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--env", default="BipedalWalker-v3")
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--warmup", type=int, default=500)
    ap.add_argument("--ups", type=float, default=0.05)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--scan", type=int, default=24)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--opt", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    rng = np.random.default_rng(a.seed)
    n, s, l = a.batch, a.scan, a.opt
    dev = torch.device("cpu")
    actor, update, phases = build(n, s, l, dev)
    env = gym.make(a.env)
    act_dim = env.action_space.shape[0]
    theta, sigma = 0.15, 0.2

    episodes = []  # (obs [T+1, D], act [T, A], rew [T])
    obs, _ = env.reset(seed=a.seed)
    ep_obs, ep_act, ep_rew = [obs], [], []
    h = torch.zeros(1, 256)
    c = torch.zeros(1, 256)
    ou = np.zeros(act_dim)
    debt, updates, n_episodes = 0.0, 0, 0
    t_update = 0.0

    def sample():
        win = s + l
        lens = np.array([len(e[2]) for e in episodes])
        valid = np.maximum(lens - win + 1, 0)
        if valid.sum() == 0:
            return None
        ep = rng.choice(len(episodes), size=n, p=valid / valid.sum())
        o, ac, r = [], [], []
        for i in ep:
            start = rng.integers(0, valid[i])
            eo, ea, er = episodes[i]
            o.append(eo[start : start + win + 1])
            ac.append(ea[start : start + win])
            r.append(er[start : start + win])
        return (
            torch.from_numpy(np.stack(o)),
            torch.from_numpy(np.stack(ac)),
            torch.from_numpy(np.stack(r)),
        )

    t0 = time.perf_counter()
    for step in range(a.steps):
        with torch.no_grad():
            x = actor.trunk(torch.as_tensor(obs, dtype=torch.float32)[None])
            h, c = cell(actor.lstm, x, h, c)
            mu = actor.act(h)[0].numpy()
        if step < a.warmup:
            act = rng.uniform(-1.0, 1.0, act_dim)
        else:
            ou += theta * -ou + sigma * rng.standard_normal(act_dim)
            act = np.clip(mu + ou, -1.0, 1.0)
        obs, r, term, trunc, _ = env.step(act.astype(np.float32))
        ep_obs.append(obs)
        ep_act.append(act)
        ep_rew.append(r)
        if term or trunc:
            episodes.append(
                (
                    np.asarray(ep_obs, dtype=np.float32),
                    np.asarray(ep_act, dtype=np.float32),
                    np.asarray(ep_rew, dtype=np.float32),
                )
            )
            n_episodes += 1
            obs, _ = env.reset()
            ep_obs, ep_act, ep_rew = [obs], [], []
            h.zero_()
            c.zero_()
            ou[:] = 0.0
        if step >= a.warmup and episodes:
            debt += a.ups
            while debt >= 1.0:
                debt -= 1.0
                b = sample()
                if b is None:
                    break
                tu = time.perf_counter()
                update(b, False)
                t_update += time.perf_counter() - tu
                updates += 1
    secs = time.perf_counter() - t0
    print(
        json.dumps(
            {
                "impl": "pytorch",
                "bench": "train",
                "env": a.env,
                "steps": a.steps,
                "warmup": a.warmup,
                "ups": a.ups,
                "threads": a.threads,
                "batch": n,
                "scan": s,
                "opt": l,
                "episodes": n_episodes,
                "updates": updates,
                "seconds": round(secs, 2),
                "update_seconds": round(t_update, 2),
                "steps_per_sec": round(a.steps / secs, 1),
            }
        )
    )


if __name__ == "__main__":
    main()

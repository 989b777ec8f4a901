#!/usr/bin/env python3
"""TD3-FORK's update (Wei & Ying 2021, as its authors' PyTorch code runs it) on synthetic data,
to compare with ``rdpg bench update --config configs/walker-td3-fork.toml``: per update the twin
critics' step (target policy smoothing, minimum of the target critics), one step of the dynamics
model (smooth L1, prediction clamped to the observation bounds) and of the reward model (MSE),
and on every second update the actor's step on ``-Q1(o, mu(o))`` plus ``weight`` times the
two-model-step look-ahead term, then the soft target updates. Networks as the config: actor and
critics 256-256, dynamics model 400-300, reward model 256-256, batch 100, Adam 3e-4.
``--always-term`` keeps the look-ahead term on whatever the model's loss (the trained runs use
it on ~100 % of actor updates; on random data the gate would close).

Prints one JSON line: {"impl": "pytorch", ..., "updates_per_sec": X}.
``--plain`` times TD3 alone (no models, no term), the same networks.

Usage: .venv/bin/python scripts/bench/pytorch_td3_fork_update.py [--iters 200] [--threads 1]
       [--always-term | --plain]
"""

import argparse
import copy
import json
import time

import torch
import torch.nn as nn
import torch.nn.functional as F


def mlp(inp, hidden, out):
    layers, w = [], inp
    for h in hidden:
        layers += [nn.Linear(w, h), nn.ReLU()]
        w = h
    return nn.Sequential(*layers, nn.Linear(w, out))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--batch", type=int, default=100)
    ap.add_argument("--obs", type=int, default=24)
    ap.add_argument("--act", type=int, default=4)
    ap.add_argument("--always-term", action="store_true")
    ap.add_argument("--plain", action="store_true", help="TD3 alone: no models, no term")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.set_flush_denormal(True)
    d, k, n = a.obs, a.act, a.batch
    actor = nn.Sequential(mlp(d, [256, 256], k), nn.Tanh())
    critics = nn.ModuleList([mlp(d + k, [256, 256], 1) for _ in range(2)])
    actor_t, critics_t = copy.deepcopy(actor), copy.deepcopy(critics)
    dyn, rew = mlp(d + k, [400, 300], d), mlp(2 * d + k, [256, 256], 1)
    opt = lambda m: torch.optim.Adam(m.parameters(), lr=3e-4)
    opt_a, opt_c, opt_d, opt_r = opt(actor), opt(critics), opt(dyn), opt(rew)
    gamma, tau, weight, lo, hi = 0.99, 0.005, 0.5, -1.0, 1.0
    q1 = lambda o, act: critics[0](torch.cat([o, act], 1))
    pred = lambda o, act: dyn(torch.cat([o, act], 1)).clamp(lo, hi)

    def update(it):
        o, act = torch.randn(n, d), torch.rand(n, k) * 2 - 1
        r, o2, nd = torch.randn(n, 1), torch.randn(n, d), torch.ones(n, 1)
        with torch.no_grad():
            noise = (torch.randn_like(act) * 0.2).clamp(-0.5, 0.5)
            a2 = (actor_t(o2) + noise).clamp(-1, 1)
            x2 = torch.cat([o2, a2], 1)
            y = r + nd * gamma * torch.min(critics_t[0](x2), critics_t[1](x2))
        x = torch.cat([o, act], 1)
        loss_c = sum(F.mse_loss(c(x), y) for c in critics)
        opt_c.zero_grad(); loss_c.backward(); opt_c.step()
        if not a.plain:
            loss_d = F.smooth_l1_loss(pred(o, act), o2)
            opt_d.zero_grad(); loss_d.backward(); opt_d.step()
            loss_r = F.mse_loss(rew(torch.cat([o, o2, act], 1)), r)
            opt_r.zero_grad(); loss_r.backward(); opt_r.step()
        if it % 2 == 0:
            loss_a = -q1(o, actor(o)).mean()
            if not a.plain and (a.always_term or loss_d.item() < 0.02):
                s1 = pred(o, actor(o))
                r1 = rew(torch.cat([o, s1.detach(), actor(o)], 1))
                s2 = pred(s1, actor(s1.detach()))
                r2 = rew(torch.cat([s1.detach(), s2.detach(), actor(s1.detach())], 1))
                q2 = q1(s2.detach(), actor(s2.detach()))
                loss_a = loss_a + weight * -(r1 + gamma * r2 + gamma ** 2 * q2).mean()
            opt_c.zero_grad(); opt_d.zero_grad(); opt_a.zero_grad()
            loss_a.backward(); opt_a.step()
            with torch.no_grad():
                for net, tgt in ((actor, actor_t), (critics, critics_t)):
                    for p, tp in zip(net.parameters(), tgt.parameters()):
                        tp.lerp_(p, tau)

    for i in range(4):
        update(i)
    t0 = time.perf_counter()
    for i in range(a.iters):
        update(i)
    sec = time.perf_counter() - t0
    print(json.dumps({"impl": "pytorch", "bench": "td3-fork-update", "batch": n, "threads": a.threads,
                      "iters": a.iters, "always_term": a.always_term, "plain": a.plain, "updates_per_sec": a.iters / sec}))


if __name__ == "__main__":
    main()

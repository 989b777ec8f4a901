#!/usr/bin/env python3
"""Steps/s of rdpg's environments from Python against Gymnasium's, in one run.

Each case steps ``--steps`` environment steps in total with uniform random float32 actions
(``np.random.default_rng(0)``), resetting as the API requires, and times the loop only:

- ``single``: ``gym.make("rdpg/<ID>")`` vs ``gym.make("<ID>")`` (both with Gymnasium's
  wrappers: TimeLimit, OrderEnforcing, PassiveEnvChecker);
- ``vector-N`` for each N in ``--envs``: rdpg's vector env (Rust threads, next-step
  autoreset) vs Gymnasium's ``SyncVectorEnv`` and ``AsyncVectorEnv`` (subprocesses) with
  the same autoreset mode; ``--steps`` counts sub-env steps.

Prints one JSON line per measurement and a final line with the ratios. Needs the rdpg package
installed in the venv (scripts/setup/setup_python.sh). Usage::

    .venv/bin/python scripts/bench/bench_python_envs.py --env BipedalWalker-v3 --steps 20000
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np

import rdpg


def time_single(env: gym.Env, steps: int) -> float:
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (steps, 4)).astype(np.float32)
    env.reset(seed=0)
    t0 = time.perf_counter()
    for a in acts:
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()
    return steps / (time.perf_counter() - t0)


def time_vector(env, n: int, steps: int) -> float:
    rng = np.random.default_rng(0)
    rounds = max(1, steps // n)
    acts = rng.uniform(-1, 1, (rounds, n, 4)).astype(np.float32)
    env.reset(seed=0)
    t0 = time.perf_counter()
    for a in acts:
        env.step(a)
    return rounds * n / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", default="BipedalWalker-v3")
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--envs", default="1,2,8", help="vector sizes, comma-separated")
    args = ap.parse_args()
    out: dict[str, float] = {}

    def emit(name: str, impl: str, sps: float) -> None:
        out[f"{name}/{impl}"] = sps
        print(json.dumps({"case": name, "impl": impl, "env": args.env, "steps": args.steps,
                          "steps_per_sec": round(sps, 1)}), flush=True)

    emit("single", "rdpg", time_single(gym.make(f"rdpg/{args.env}"), args.steps))
    emit("single", "gymnasium", time_single(gym.make(args.env), args.steps))
    for n in (int(x) for x in args.envs.split(",")):
        name = f"vector-{n}"
        emit(name, "rdpg", time_vector(rdpg.make_vec(args.env, n), n, args.steps))
        sync = gym.vector.SyncVectorEnv([lambda: gym.make(args.env) for _ in range(n)])
        emit(name, "gymnasium-sync", time_vector(sync, n, args.steps))
        if n > 1:
            asyn = gym.vector.AsyncVectorEnv([lambda: gym.make(args.env) for _ in range(n)])
            emit(name, "gymnasium-async", time_vector(asyn, n, args.steps))
            asyn.close()
    ratios = {
        "single": out["single/rdpg"] / out["single/gymnasium"],
    }
    for n in (int(x) for x in args.envs.split(",")):
        best = max(v for k, v in out.items() if k.startswith(f"vector-{n}/gymnasium"))
        ratios[f"vector-{n}"] = out[f"vector-{n}/rdpg"] / best
    print(json.dumps({"ratios_vs_best_gymnasium": {k: round(v, 2) for k, v in ratios.items()}}))


if __name__ == "__main__":
    main()

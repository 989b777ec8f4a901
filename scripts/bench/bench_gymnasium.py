#!/usr/bin/env python3
"""Benchmark Gymnasium's BipedalWalker step rate (baseline for the Rust port).

Default mode: step ``gym.make(ID)`` (with its usual wrappers: TimeLimit,
OrderEnforcing, PassiveEnvChecker) with uniform random float32 actions from
``np.random.default_rng(seed)``, resetting whenever an episode ends.  Only
the step loop is timed (``time.perf_counter``); resets inside the loop are
included, as they are part of a real rollout.  Prints one JSON line::

    {"impl":"gymnasium","env":ID,"steps":N,"seconds":X,"steps_per_sec":Y}

``--raw-step``: the same random-action rollout, but only the time spent
inside ``env.unwrapped.world.Step(1/50, 180, 60)`` is counted (the world is
wrapped in a proxy that times each call).  This excludes the Python-side work
(action handling, lidar ray casts, observation and reward) and estimates the
bare-physics bound for the same workload.  Printed with ``"impl":
"gymnasium-raw-step"``.

``--raw-step --idle``: after one reset, call ``world.Step(1/50, 180, 60)`` N
times in a plain loop on an uncontrolled walker (the reset leaves the motors
at zero torque, so it slumps and comes to rest).  Box2D may put the resting
bodies to sleep, after which steps are nearly free, so this number depends
strongly on the seed; prefer plain ``--raw-step``.  Printed with ``"impl":
"gymnasium-raw-step-idle"``.

Usage::

    python scripts/bench/bench_gymnasium.py --env BipedalWalker-v3 --steps 20000 --seed 0
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import gymnasium as gym

FPS = 50  # BipedalWalker's control rate; world.Step(1/FPS, 6*30, 2*30)


class TimedWorld:
    """Proxy around a ``Box2D.b2World`` that accumulates time spent in Step.

    Every other attribute access (and assignment, e.g. ``contactListener``)
    is forwarded to the real world, so the env runs unchanged.
    """

    def __init__(self, world):
        object.__setattr__(self, "_world", world)
        object.__setattr__(self, "step_seconds", 0.0)

    def Step(self, *args):  # noqa: N802 (Box2D naming)
        t0 = time.perf_counter()
        self._world.Step(*args)
        dt = time.perf_counter() - t0
        object.__setattr__(self, "step_seconds", self.step_seconds + dt)

    def __getattr__(self, name):
        return getattr(self._world, name)

    def __setattr__(self, name, value):
        setattr(self._world, name, value)


def rollout(env, steps: int, seed: int) -> float:
    """Random-action rollout with resets; returns the wall time of the loop."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    # Pre-draw the actions so RNG cost is not timed.
    actions = rng.uniform(-1, 1, (steps, 4)).astype(np.float32)
    t0 = time.perf_counter()
    for k in range(steps):
        _, _, terminated, truncated, _ = env.step(actions[k])
        if terminated or truncated:
            env.reset()
    return time.perf_counter() - t0


def bench_env(env_id: str, steps: int, seed: int) -> float:
    env = gym.make(env_id)
    seconds = rollout(env, steps, seed)
    env.close()
    return seconds


def bench_raw_step(env_id: str, steps: int, seed: int) -> float:
    env = gym.make(env_id)
    timed = TimedWorld(env.unwrapped.world)
    env.unwrapped.world = timed
    rollout(env, steps, seed)
    env.close()
    return timed.step_seconds


def bench_raw_step_idle(env_id: str, steps: int, seed: int) -> float:
    env = gym.make(env_id)
    env.reset(seed=seed)
    step = env.unwrapped.world.Step
    dt = 1.0 / FPS
    t0 = time.perf_counter()
    for _ in range(steps):
        step(dt, 6 * 30, 2 * 30)
    seconds = time.perf_counter() - t0
    env.close()
    return seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", default="BipedalWalker-v3", help="Gymnasium env id")
    ap.add_argument("--steps", type=int, default=20000, help="number of env steps")
    ap.add_argument("--seed", type=int, default=0, help="env and action seed")
    ap.add_argument("--raw-step", action="store_true",
                    help="count only the time spent in world.Step")
    ap.add_argument("--idle", action="store_true",
                    help="with --raw-step: plain Step loop on a resting walker")
    args = ap.parse_args()
    if args.idle and not args.raw_step:
        ap.error("--idle requires --raw-step")

    if args.raw_step and args.idle:
        seconds = bench_raw_step_idle(args.env, args.steps, args.seed)
        impl = "gymnasium-raw-step-idle"
    elif args.raw_step:
        seconds = bench_raw_step(args.env, args.steps, args.seed)
        impl = "gymnasium-raw-step"
    else:
        seconds = bench_env(args.env, args.steps, args.seed)
        impl = "gymnasium"
    print(json.dumps({
        "impl": impl,
        "env": args.env,
        "steps": args.steps,
        "seconds": round(seconds, 6),
        "steps_per_sec": round(args.steps / seconds, 1),
    }, separators=(",", ":")))


if __name__ == "__main__":
    main()

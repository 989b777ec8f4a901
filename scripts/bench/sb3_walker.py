#!/usr/bin/env python3
"""Stable-Baselines3's TD3, SAC or TQC on BipedalWalker-v3 with the settings of rdpg's recipes:
the speed reference for configs/walker-td3-zoo.toml (``--algo td3``: RL Zoo's TD3),
configs/walker-sac.toml (``--algo sac``: RL Zoo's SAC sizes without gSDE) and
configs/walker-tqc.toml (``--algo tqc``: sb3-contrib's TQC, 2 critics of 25 atoms, 2 dropped
per critic) — same networks, batch, rates, noise, warm-up, one update per step.

Trains for ``--steps`` env steps on ``gym.make("BipedalWalker-v3")`` and prints one JSON line
with the whole-training steps/s after warm-up (the 10k random steps excluded)::

    {"impl":"sb3-td3","sb3":"2.9.2","torch":"2.11.0","threads":1,"steps":N,
     "warmup_steps":10000,"seconds_after_warmup":X,"steps_per_sec_after_warmup":Y}

Usage (needs stable-baselines3 in .venv: pip install stable-baselines3==2.9.2; for ``tqc`` also
sb3-contrib==2.9.2)::

    .venv/bin/python scripts/bench/sb3_walker.py --algo td3 --steps 30000 --threads 1
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np
import stable_baselines3 as sb3
import torch
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import NormalActionNoise

WARMUP = 10_000


class Clock(BaseCallback):
    """Records the wall time when training passes the warm-up."""

    def __init__(self):
        super().__init__()
        self.t_warm: float | None = None

    def _on_step(self) -> bool:
        if self.t_warm is None and self.num_timesteps >= WARMUP:
            self.t_warm = time.perf_counter()
        return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--algo", choices=("td3", "sac", "tqc"), required=True)
    ap.add_argument("--steps", type=int, default=30_000)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    env = gym.make("BipedalWalker-v3")
    common = dict(
        learning_starts=WARMUP,
        batch_size=256,
        train_freq=1,
        gradient_steps=1,
        policy_kwargs={"net_arch": [400, 300]},
        seed=args.seed,
        device="cpu",
        verbose=0,
    )
    if args.algo == "td3":
        model = TD3(
            "MlpPolicy",
            env,
            learning_rate=1e-3,
            buffer_size=200_000,
            tau=0.005,
            gamma=0.98,
            action_noise=NormalActionNoise(np.zeros(4), 0.1 * np.ones(4)),
            policy_delay=2,
            target_policy_noise=0.2,
            target_noise_clip=0.5,
            **common,
        )
    else:
        soft = dict(learning_rate=7.3e-4, buffer_size=300_000, tau=0.02, gamma=0.98, ent_coef="auto")
        if args.algo == "sac":
            model = SAC("MlpPolicy", env, **soft, **common)
        else:
            from sb3_contrib import TQC  # pip install sb3-contrib==2.9.2

            common["policy_kwargs"].update(n_quantiles=25, n_critics=2)
            model = TQC("MlpPolicy", env, top_quantiles_to_drop_per_net=2, **soft, **common)
    clock = Clock()
    model.learn(total_timesteps=args.steps, callback=clock)
    seconds = time.perf_counter() - clock.t_warm
    print(json.dumps({
        "impl": f"sb3-{args.algo}", "sb3": sb3.__version__, "torch": torch.__version__.split("+")[0],
        "threads": args.threads, "steps": args.steps, "warmup_steps": WARMUP,
        "seconds_after_warmup": round(seconds, 2),
        "steps_per_sec_after_warmup": round((args.steps - WARMUP) / seconds, 1),
    }))


if __name__ == "__main__":
    main()

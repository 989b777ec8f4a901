"""Replays the episodes of `rdpg eval --actions-out FILE` in Gymnasium and checks their returns.

Each line of FILE is `{"seed": N, "return": R, "actions": [[a0, a1, ...], ...]}`. The episodes
are replayed in order in one env (as `rdpg eval` ran them: a walker keeps its Box2D world across
resets), each from `env.reset(seed=N)` with the actions as float32 (the dtype rdpg acts in), and
each Gymnasium return must equal R exactly (the walkers are bit-identical). A line with
`"action_repeat": k` (a run trained with an action repeat) holds each action for k frames, the
last one until the episode ends; its return, summed by rdpg per k frames, is compared to 1e-9
relative (the summation order differs, the frames do not).

Usage: .venv-ref/bin/python scripts/reference/replay_actions.py FILE --env BipedalWalker-v3
Exit status 1 if any episode differs.
"""

import argparse
import json
import sys

import gymnasium as gym
import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("file")
    ap.add_argument("--env", required=True, help="Gymnasium id, e.g. BipedalWalker-v3")
    args = ap.parse_args()
    env = gym.make(args.env)
    bad = 0
    with open(args.file) as f:
        for line in f:
            ep = json.loads(line)
            env.reset(seed=ep["seed"])
            k = ep.get("action_repeat", 1)
            ret, steps, done = 0.0, 0, False
            for a in ep["actions"]:
                if done:
                    break
                for _ in range(k):
                    _, r, term, trunc, _ = env.step(np.asarray(a, dtype=np.float32))
                    ret += float(r)
                    done = term or trunc
                    if done:
                        break
                steps += 1
            close = ret == ep["return"] if k == 1 else abs(ret - ep["return"]) <= 1e-9 * max(1.0, abs(ret))
            same = done and steps == len(ep["actions"]) and close
            bad += not same
            print(json.dumps({"seed": ep["seed"], "steps": steps, "rdpg_return": ep["return"],
                              "gymnasium_return": ret, "equal": same}))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

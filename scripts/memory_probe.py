#!/usr/bin/env python3
"""How far back a recurrent agent's memory matters: `rdpg eval --memory K` for each run and K,
against the same episodes with the agent's whole memory.

    python3 scripts/memory_probe.py --out results/memory-probe zoo/memory-rdpg zoo/walker-rdpg ...

Runs every (run, K) evaluation not yet in OUT/evals.jsonl (so an interrupted probe resumes),
then writes OUT/probe.md: per run and K, the mean test return, the success share and the
paired difference to the whole memory on the same test episodes, with a 95 % percentile
bootstrap CI over episodes. `--table-only` rewrites probe.md from evals.jsonl alone.
"""

import argparse
import json
import random
import subprocess
from pathlib import Path

FULL = "full"


def evaluate(rdpg, run, k, episodes):
    cmd = [rdpg, "eval", "--run", run, "--episodes", str(episodes)]
    if k != FULL:
        cmd += ["--memory", k]
    line = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
    keep = ("episodes", "first_seed", "mean_stock_return", "std_stock_return", "success_rate")
    return {"run": run, "k": k, **{key: line[key] for key in keep}, "returns": line["returns"]}


def paired_ci(a, b, rng, resamples=10_000):
    """Mean of a - b (paired by episode) and its 95 % percentile bootstrap interval."""
    d = [x - y for x, y in zip(a, b)]
    n = len(d)
    means = sorted(sum(d[rng.randrange(n)] for _ in range(n)) / n for _ in range(resamples))
    return sum(d) / n, means[int(0.025 * resamples)], means[int(0.975 * resamples) - 1]


def table(rows):
    by_run = {}
    for r in rows:
        by_run.setdefault(r["run"], {})[r["k"]] = r
    out = [
        "| run | K (observations remembered) | test return (mean ± std) | success % "
        "| − whole memory [95 % CI] |",
        "|---|---|---|---|---|",
    ]
    rng = random.Random(0)
    for run, ks in by_run.items():
        full = ks.get(FULL)
        order = sorted((k for k in ks if k != FULL), key=int) + ([FULL] if full else [])
        for k in order:
            r = ks[k]
            diff = "(reference)"
            if full and k != FULL:
                if r["first_seed"] != full["first_seed"] or r["episodes"] != full["episodes"]:
                    raise SystemExit(f"{run} K={k}: not the whole memory's episodes")
                m, lo, hi = paired_ci(r["returns"], full["returns"], rng)
                diff = f"{m:+.1f} [{lo:+.1f}, {hi:+.1f}]"
            label = "whole episode" if k == FULL else k
            out.append(
                f"| {run} | {label} | {r['mean_stock_return']:.1f} ± {r['std_stock_return']:.1f} "
                f"| {100 * r['success_rate']:.0f} | {diff} |"
            )
    first = rows[0]
    out += [
        "",
        f"{first['episodes']} test episodes from seed {first['first_seed']} per line, the same "
        "for every K; bootstrap over episodes, 10 000 resamples. Made by "
        "`python3 scripts/memory_probe.py --table-only`.",
    ]
    return "\n".join(out) + "\n"


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="*", help="run directories or zoo entries of recurrent agents")
    p.add_argument("--out", default="results/memory-probe")
    p.add_argument("--rdpg", default="target/release/rdpg")
    p.add_argument("--k", default="1,2,4,8,16,32,64", help="comma-separated K values")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--table-only", action="store_true")
    a = p.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    store = out / "evals.jsonl"
    rows = [json.loads(l) for l in store.read_text().splitlines()] if store.exists() else []
    if not a.table_only:
        done = {(r["run"], r["k"]) for r in rows}
        for run in a.runs:
            for k in a.k.split(",") + [FULL]:
                if (run, k) not in done:
                    rows.append(evaluate(a.rdpg, run, k, a.episodes))
                    with store.open("a") as f:
                        f.write(json.dumps(rows[-1]) + "\n")
    if not rows:
        raise SystemExit(f"{store}: no evaluations")
    (out / "probe.md").write_text(table(rows))


if __name__ == "__main__":
    main()

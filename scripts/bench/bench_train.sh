#!/usr/bin/env bash
# Whole-training throughput (env steps + acting + storing + updates per second) on
# BipedalWalker-v3 with the paper's networks, measured in one run:
#   1. rdpg vs the Python loop (Gymnasium + PyTorch) at 0 and 0.05 updates per env step;
#   2. rdpg's vector env with batched acting: 1, 2, 4, 8 environments on 1 or 2 workers.
# Needs target/release/rdpg and, for the Python side, torch + gymnasium[box2d] in .venv
# (`.venv/bin/pip install -r scripts/setup/requirements_reference.txt`).
# Usage: scripts/bench/bench_train.sh [STEPS]   (default 3000)
set -euo pipefail
cd "$(dirname "$0")/../.."
steps="${1:-3000}"
for ups in 0 0.05; do
    target/release/rdpg bench train --steps "$steps" --ups "$ups" --threads 2
    if .venv/bin/python3 -c "import gymnasium, torch" 2>/dev/null; then
        .venv/bin/python3 scripts/bench/pytorch_train_bench.py --steps "$steps" --ups "$ups" --threads 2
    fi
done
for envs in 1 2 4 8; do
    workers=$((envs < 2 ? 1 : 2))
    target/release/rdpg bench train --steps "$steps" --ups 0 --envs "$envs" --workers "$workers" --threads 2
done
target/release/rdpg bench train --steps "$steps" --ups 0.05 --envs 4 --workers 2 --threads 2

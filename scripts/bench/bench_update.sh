#!/usr/bin/env bash
# RDPG update throughput, tch (rdpg) vs PyTorch, measured in one run on this machine at the
# paper's sizes. Usage: scripts/bench/bench_update.sh [SCAN] [ITERS]   (defaults: 24, 30)
# Needs target/release/rdpg and .venv (scripts/setup.sh).
set -euo pipefail
cd "$(dirname "$0")/../.."
scan="${1:-24}"
iters="${2:-30}"
target/release/rdpg bench update --scan "$scan" --batch 64 --opt 8 --iters "$iters" --threads 2
.venv/bin/python3 scripts/bench/pytorch_update_bench.py --scan "$scan" --batch 64 --opt 8 --iters "$iters" --threads 2

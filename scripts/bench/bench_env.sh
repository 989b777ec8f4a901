#!/usr/bin/env bash
# Environment throughput, rdpg vs Gymnasium, measured in one run on this machine.
# Usage: scripts/bench/bench_env.sh [STEPS] [REFERENCE_VENV]   (defaults: 30000, .venv-ref)
# Needs target/release/rdpg (scripts/setup.sh) and a reference venv (scripts/setup/setup_reference.sh).
set -euo pipefail
cd "$(dirname "$0")/../.."
steps="${1:-30000}"
py="${2:-.venv-ref}/bin/python"
rdpg=target/release/rdpg
sps() { sed -E 's/.*"steps_per_sec":([0-9.]+).*/\1/'; }
printf '| env | rdpg 1 walker (steps/s) | Gymnasium (steps/s) | ratio | rdpg 2 workers (steps/s) | 2 workers / 1 |\n|---|---|---|---|---|---|\n'
for env in BipedalWalker-v3 BipedalWalkerHardcore-v3; do
  one=$($rdpg bench env --env "$env" --steps "$steps" | sps)
  gym=$("$py" scripts/bench/bench_gymnasium.py --env "$env" --steps "$steps" --seed 0 | sps)
  two=$($rdpg bench env --env "$env" --steps "$steps" --workers 2 | sps)
  awk -v e="$env" -v a="$one" -v g="$gym" -v t="$two" \
    'BEGIN { printf "| %s | %.0f | %.0f | %.2fx | %.0f | %.2fx |\n", e, a, g, a / g, t, t / a }'
done

#!/usr/bin/env bash
# FORK's cost and rdpg against TD3-FORK's PyTorch update, in one run, interleaved per round:
# rdpg walker-td3 (TD3 alone) and walker-td3-fork with the look-ahead term always on (the
# threshold raised for the synthetic batches; trained runs use it on ~100 % of actor updates),
# then the same two updates in PyTorch (scripts/bench/pytorch_td3_fork_update.py). One libtorch
# thread, parallel_twins off. Prints one Markdown row per round (updates/s).
# Usage: scripts/bench/bench_fork_update.sh [ROUNDS] [ITERS]   (defaults: 3, 200)
set -euo pipefail
# shellcheck source=scripts/bench/update_common.sh
source "$(dirname "$0")/update_common.sh"
sed -E 's/^parallel_twins = true.*/parallel_twins = false/' configs/walker-td3.toml > "$tmp/td3.toml"
sed -E -e 's/^parallel_twins = true.*/parallel_twins = false/' -e 's/^threshold = .*/threshold = 1e9/' \
  configs/walker-td3-fork.toml > "$tmp/fork.toml"
printf '| round | rdpg TD3 | rdpg TD3-FORK | PyTorch TD3 | PyTorch TD3-FORK |\n|---|---|---|---|---|\n'
for r in $(seq "$rounds"); do
  a=$($rdpg bench update --config "$tmp/td3.toml" --iters "$iters" --threads 1 | ups)
  b=$($rdpg bench update --config "$tmp/fork.toml" --iters "$iters" --threads 1 | ups)
  c=$($py scripts/bench/pytorch_td3_fork_update.py --iters "$iters" --threads 1 --plain | ups)
  d=$($py scripts/bench/pytorch_td3_fork_update.py --iters "$iters" --threads 1 --always-term | ups)
  printf '| %s | %.1f | %.1f | %.1f | %.1f |\n' "$r" "$a" "$b" "$c" "$d"
done

#!/usr/bin/env bash
# The recurrent recipes' update, rdpg against the same update in PyTorch, in one run: rdpg on
# one thread, rdpg with `parallel_twins`, PyTorch on one and on two threads, and PyTorch again
# with glibc's allocator set as the rdpg binary sets it (rdpg_core::malloc; GLIBC_TUNABLES);
# then the recurrent SAC recipes (one thread: SAC has no `parallel_twins`). Prints one Markdown
# row per config and round (updates/s).
# Usage: scripts/bench/bench_recipe_update.sh [ROUNDS] [ITERS]   (defaults: 3, 200)
# Needs target/release/rdpg (scripts/setup.sh) and torch in .venv
# (.venv/bin/pip install -r scripts/setup/requirements_reference.txt).
set -euo pipefail
# shellcheck source=scripts/bench/update_common.sh
source "$(dirname "$0")/update_common.sh"
# PyTorch with the malloc settings rdpg applies to itself (rdpg_core::malloc, MMAP_THRESHOLD /
# TRIM_THRESHOLD: keep this in step with them).
tuned=GLIBC_TUNABLES=glibc.malloc.mmap_threshold=$((64 << 20)):glibc.malloc.trim_threshold=$((512 << 20))
printf '| config, round | rdpg, 1 thread | rdpg, parallel_twins | PyTorch 1 thread | PyTorch 2 threads | PyTorch 1 thread, tuned malloc | PyTorch 2 threads, tuned malloc |\n|---|---|---|---|---|---|---|\n'
for r in $(seq "$rounds"); do
  for c in walker-rdpg memory-rdpg; do
    dims=(); [ "$c" = memory-rdpg ] && dims=(--obs 2 --act 1)
    sed -E 's/^parallel_twins = true.*/parallel_twins = false/' "configs/$c.toml" > "$tmp/$c.toml"
    sed -E 's/^parallel_twins = false.*/parallel_twins = true/' "configs/$c.toml" > "$tmp/$c-par.toml"
    one=$($rdpg bench update --config "$tmp/$c.toml" --iters "$iters" --threads 1 | ups)
    par=$($rdpg bench update --config "$tmp/$c-par.toml" --iters "$iters" --threads 1 | ups)
    py1=$($py scripts/bench/pytorch_recipe_update.py --config "configs/$c.toml" --iters "$iters" --threads 1 "${dims[@]}" | ups)
    py2=$($py scripts/bench/pytorch_recipe_update.py --config "configs/$c.toml" --iters "$iters" --threads 2 "${dims[@]}" | ups)
    pt1=$(env "$tuned" $py scripts/bench/pytorch_recipe_update.py --config "configs/$c.toml" --iters "$iters" --threads 1 "${dims[@]}" | ups)
    pt2=$(env "$tuned" $py scripts/bench/pytorch_recipe_update.py --config "configs/$c.toml" --iters "$iters" --threads 2 "${dims[@]}" | ups)
    printf '| %s, %s | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f |\n' "$c" "$r" "$one" "$par" "$py1" "$py2" "$pt1" "$pt2"
  done
done
printf '\n| SAC config, round | rdpg, 1 thread | PyTorch 1 thread | PyTorch 2 threads | PyTorch 1 thread, tuned malloc |\n|---|---|---|---|---|\n'
for r in $(seq "$rounds"); do
  for c in memory-sac hardcore-sac-paper; do
    dims=(); [ "$c" = memory-sac ] && dims=(--obs 2 --act 1)
    one=$($rdpg bench update --config "configs/$c.toml" --iters "$iters" --threads 1 | ups)
    py1=$($py scripts/bench/pytorch_recipe_update.py --config "configs/$c.toml" --iters "$iters" --threads 1 "${dims[@]}" | ups)
    py2=$($py scripts/bench/pytorch_recipe_update.py --config "configs/$c.toml" --iters "$iters" --threads 2 "${dims[@]}" | ups)
    pt1=$(env "$tuned" $py scripts/bench/pytorch_recipe_update.py --config "configs/$c.toml" --iters "$iters" --threads 1 "${dims[@]}" | ups)
    printf '| %s, %s | %.1f | %.1f | %.1f | %.1f |\n' "$c" "$r" "$one" "$py1" "$py2" "$pt1"
  done
done

#!/usr/bin/env bash
# Two rdpg binaries' updates alternating in one run: `rdpg bench update --config C --threads 1`
# on each recipe, one round after another (OLD, then NEW, per config and round), so that drift
# in the machine's speed hits both alike. Prints one Markdown row per config and round:
# updates/s of each, the ratio, and NEW's counted GFLOP per update, GFLOP/s and the GEMM
# reference measured in the same process (`ms_at_gemm_ref`: the update's FLOP at that rate).
# Pause training runs meanwhile (kill -STOP PID ... kill -CONT PID).
# Usage: scripts/bench/bench_update_binaries.sh OLD NEW [ROUNDS] [ITERS] [CONFIG...]
#   (defaults: 3 rounds, 200 iters, configs/hardcore-td3-paper.toml configs/hardcore-rdpg-paper.toml)
set -euo pipefail
old="$1"; new="$2"; rounds="${3:-3}"; iters="${4:-200}"; shift $(( $# < 4 ? $# : 4 ))
configs=("$@"); [ ${#configs[@]} -gt 0 ] || configs=(configs/hardcore-td3-paper.toml configs/hardcore-rdpg-paper.toml)
tmp="$(mktemp -d)"; trap 'rm -rf "$tmp"' EXIT
field() { grep -o "\"$1\": *[0-9.e+-]*" | cut -d: -f2 | tr -d ' '; }
printf '| config, round | old updates/s | new updates/s | new / old | new: GFLOP per update | new: GFLOP/s | GEMM reference GFLOP/s | ms per update | ms at the GEMM reference |\n|---|---|---|---|---|---|---|---|---|\n'
for r in $(seq "$rounds"); do
  for c in "${configs[@]}"; do
    name="$(basename "$c" .toml)"
    # One libtorch thread, no second thread (`parallel_twins` off).
    sed -E 's/^parallel_twins = true.*/parallel_twins = false/' "$c" > "$tmp/$name.toml"
    o=$("$old" bench update --config "$tmp/$name.toml" --iters "$iters" --threads 1 | field updates_per_sec)
    line=$("$new" bench update --config "$tmp/$name.toml" --iters "$iters" --threads 1)
    n=$(field updates_per_sec <<<"$line")
    printf '| %s, %s | %.1f | %.1f | %.2fx | %.3f | %.1f | %.1f | %.2f | %.2f |\n' "$name" "$r" "$o" "$n" \
      "$(echo "$n / $o" | bc -l)" "$(field gflop <<<"$line")" "$(field gflops <<<"$line")" \
      "$(field gemm_ref_gflops <<<"$line")" "$(field ms_per_update <<<"$line")" "$(field ms_at_gemm_ref <<<"$line")"
  done
done

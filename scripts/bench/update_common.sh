# Shared by the update benchmarks that compare rdpg with PyTorch round by round
# (bench_recipe_update.sh, bench_fork_update.sh); sourced, not run. Expects the caller's
# arguments [ROUNDS] [ITERS] and sets: rounds, iters, rdpg, py, tmp (removed on exit) and
# `ups` (reads a bench's JSON on stdin, prints its updates per second).
# shellcheck shell=bash
cd "$(dirname "${BASH_SOURCE[0]}")/../.."
rounds="${1:-3}"
iters="${2:-200}"
rdpg=target/release/rdpg
py=.venv/bin/python
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
ups() { grep -o '"updates_per_sec": *[0-9.]*' | cut -d: -f2 | tr -d ' '; }

#!/usr/bin/env bash
# The project's test command (README): setup, then the gates — formatting, clippy with
# warnings as errors, the whole test suite (golden traces, determinism, end-to-end runs,
# learning checks), the Python package's tests (pytest against Gymnasium) and the API docs with
# warnings denied.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
# shellcheck source=scripts/setup/deps.sh
source scripts/setup/deps.sh
cargo fmt --all -- --check
# No oversized rooms: a source file past 600 code lines is split (ARCHITECTURE.md).
scripts/room_sizes.sh
# No import circle between source files (ARCHITECTURE.md).
python3 scripts/import_cycles.py
cargo clippy --workspace --all-targets -- -D warnings
cargo test --workspace
# The Python package against Gymnasium (uses the rdpg binary the tests above built).
python3 -m pytest -q -p no:warnings crates/rdpg-py/tests
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps

#!/usr/bin/env bash
# The project's test command (README): setup, then the three gates — formatting, clippy with
# warnings as errors, and the whole test suite (golden traces, determinism, end-to-end runs,
# learning checks).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
# shellcheck source=scripts/deps.sh
source scripts/deps.sh
cargo fmt --all -- --check
cargo clippy --workspace --all-targets -- -D warnings
cargo test --workspace

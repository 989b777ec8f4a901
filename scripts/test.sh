#!/usr/bin/env bash
# The project's test command (README): setup, then the three gates — formatting, clippy with
# warnings as errors, and the whole test suite (golden traces, determinism, end-to-end runs,
# learning checks).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
scripts/fetch-box2d.sh
if [ -x scripts/setup-torch.sh ]; then
  scripts/setup-torch.sh
fi
# shellcheck source=scripts/env.sh
source scripts/env.sh
cargo fmt --all -- --check
cargo clippy --workspace --all-targets -- -D warnings
cargo test --workspace

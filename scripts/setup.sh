#!/usr/bin/env bash
# Sets up everything rdpg needs on a fresh machine (Rust, Python 3 and pip assumed present):
# pybox2d's Box2D 2.3.0 sources (PyPI sdist) and, for the learners, PyTorch 2.11.0's libtorch
# in .venv (PyPI wheel). Then builds the `rdpg` binary in release mode. Idempotent.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
# shellcheck source=scripts/setup/deps.sh
source scripts/setup/deps.sh
cargo build --release -p rdpg-cli
echo "setup done: $(ls -1 target/release/rdpg)"

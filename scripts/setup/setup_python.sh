#!/usr/bin/env bash
# Installs the `rdpg` Python package (crates/rdpg-py: PyO3 extension + Gymnasium wrappers) into
# .venv, the venv that holds torch 2.11.0 (the extension links the same libtorch), with its
# test dependencies. Run after setup_torch.sh and with the build environment (env.sh).
# Idempotent: pip skips what is installed, maturin rebuilds only what changed.
#
# A wheel instead of an editable install:
#   .venv/bin/maturin build --release -m crates/rdpg-py/Cargo.toml   # -> target/wheels/
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
venv="${RDPG_VENV:-$root/.venv}"
"$venv/bin/python3" -m pip install --quiet -r "$root/scripts/setup/requirements_python.txt"
log="$(mktemp)"
if ! VIRTUAL_ENV="$venv" PYO3_PYTHON="$venv/bin/python3" \
  "$venv/bin/maturin" develop --quiet --release -m "$root/crates/rdpg-py/Cargo.toml" >"$log" 2>&1; then
  cat "$log" >&2
  rm -f "$log"
  echo "error: building the rdpg Python package failed" >&2
  exit 1
fi
rm -f "$log"
"$venv/bin/python3" -c "import rdpg, gymnasium; print('rdpg python package ready in $venv')"

#!/usr/bin/env bash
# Installs the `rdpg` Python package (crates/rdpg-py: PyO3 extension + Gymnasium wrappers) into
# .venv, the venv that holds torch 2.11.0 (the extension links the same libtorch), with its
# test dependencies. Run after setup_torch.sh and with the build environment (env.sh).
# Idempotent: pip skips what is installed, maturin rebuilds only what changed.
#
# A wheel instead of an editable install (after this script, which puts the policy module
# in the package directory the wheel takes its Python files from):
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
# The policies are a second extension module (crates/rdpg-py-policy, `rdpg._policy`: it links
# libtorch, which `import rdpg` and the envs must not load), built the way maturin builds the
# first and put beside it in the package.
if ! VIRTUAL_ENV="$venv" PYO3_PYTHON="$venv/bin/python3" PYO3_BUILD_EXTENSION_MODULE=1 \
  cargo build --quiet --release -p rdpg-py-policy --manifest-path "$root/Cargo.toml" >"$log" 2>&1; then
  cat "$log" >&2
  rm -f "$log"
  echo "error: building the rdpg policy module failed" >&2
  exit 1
fi
rm -f "$log"
suffix="$("$venv/bin/python3" -c 'import sysconfig; print(sysconfig.get_config_var("EXT_SUFFIX"))')"
install -m 755 "${CARGO_TARGET_DIR:-$root/target}/release/lib_policy.so" \
  "$root/crates/rdpg-py/python/rdpg/_policy$suffix"
"$venv/bin/python3" -c "import rdpg, gymnasium; rdpg.policy._extension(); print('rdpg python package ready in $venv')"

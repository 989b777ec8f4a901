#!/usr/bin/env bash
# Create a Python virtual environment with the exact Gymnasium/Box2D/NumPy
# versions the reference traces were generated with.
#
# Usage: scripts/setup/setup_reference.sh [VENV_DIR]     (default: .venv-ref)
# Env:   PYTHON=python3.11 to choose the interpreter (CPython 3.11 expected).
#
# Afterwards:
#   VENV_DIR/bin/python scripts/reference/gymnasium_traces.py          # regenerate fixtures
#   VENV_DIR/bin/python scripts/bench/bench_gymnasium.py --env BipedalWalker-v3 --steps 20000
set -euo pipefail

venv="${1:-.venv-ref}"
python="${PYTHON:-python3.11}"
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"

if ! command -v "$python" >/dev/null 2>&1; then
    echo "error: $python not found (set PYTHON=/path/to/python3.11)" >&2
    exit 1
fi
ver="$("$python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
if [ "$ver" != "3.11" ]; then
    echo "warning: $python is Python $ver; the fixtures were generated with 3.11" >&2
fi

"$python" -m venv "$venv"
"$venv/bin/python" -m pip install --upgrade pip
# box2d 2.3.10 ships wheels for CPython 3.11 on common platforms; building it
# from source needs swig.
"$venv/bin/python" -m pip install -r "$here/requirements_reference.txt"
"$venv/bin/python" - <<'PY'
import Box2D, gymnasium, numpy, platform
print(f"ok: python {platform.python_version()}, gymnasium {gymnasium.__version__}, "
      f"box2d {Box2D.__version__}, numpy {numpy.__version__}")
PY
echo "reference venv ready: $venv"

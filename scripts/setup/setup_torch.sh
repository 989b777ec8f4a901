#!/usr/bin/env bash
# Installs PyTorch 2.11.0 (the libtorch that tch 0.24 links against, and the version on the GPU
# machines) into .venv at the repository root, from PyPI. Idempotent: does nothing when the venv
# already has torch 2.11.0. PyPI's Linux wheel is the CUDA build (~2.5 GB download); the same
# binaries then run on CPU-only machines and on GPUs.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
venv="${RDPG_VENV:-$root/.venv}"
want="2.11.0"
if [ -x "$venv/bin/python3" ] && "$venv/bin/python3" -c "import torch, sys; sys.exit(0 if torch.__version__.split('+')[0] == '$want' else 1)" 2>/dev/null; then
  exit 0
fi
python3 -m venv "$venv"
"$venv/bin/python3" -m pip install --quiet --upgrade pip
"$venv/bin/python3" -m pip install --quiet "torch==$want" numpy
"$venv/bin/python3" -c "import torch; print('torch', torch.__version__, 'in $venv')"

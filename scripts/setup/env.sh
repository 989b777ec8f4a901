# Sourced by the other scripts: points the tch build at the project's PyTorch venv, if any.
_rdpg_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
if [ -x "$_rdpg_root/.venv/bin/python3" ]; then
  export PATH="$_rdpg_root/.venv/bin:$PATH"
  export LIBTORCH_USE_PYTORCH=1
fi
unset _rdpg_root

# Sourced by setup.sh and test.sh: fetches what the build needs (Box2D sources; PyTorch's
# libtorch when the learners are part of the workspace) and exports the build environment.
_rdpg_scripts="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
"$_rdpg_scripts/fetch_box2d.sh"
if [ -x "$_rdpg_scripts/setup_torch.sh" ]; then
  "$_rdpg_scripts/setup_torch.sh"
fi
# shellcheck source=scripts/setup/env.sh
source "$_rdpg_scripts/env.sh"
# The Python package (crates/rdpg-py) in the same venv, once the build environment is set.
if [ -x "$_rdpg_scripts/setup_python.sh" ] && [ -d "$_rdpg_scripts/../../crates/rdpg-py" ]; then
  "$_rdpg_scripts/setup_python.sh"
fi
unset _rdpg_scripts

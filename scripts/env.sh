# Source this file (bash/zsh) to use the workspace: `source scripts/env.sh`.
# Activates .venv, sources the colcon overlay and puts the project's command-line tools on PATH.
_vla_root=$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")/.." && pwd)
# shellcheck source=/dev/null
source "$_vla_root/.venv/bin/activate"
# The ROS wheels re-exec Python once to set LD_LIBRARY_PATH; do it here instead, for every child.
_vla_site=$("$_vla_root/.venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])' 2>/dev/null)
export LD_LIBRARY_PATH="$_vla_root/.venv/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
for _d in "$_vla_site"/ros_*.libs; do [ -d "$_d" ] && LD_LIBRARY_PATH="$_d:$LD_LIBRARY_PATH"; done
export _ROS_WHEELS_BOOTSTRAP_COMPLETE=1
export AMENT_PREFIX_PATH="$_vla_root/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
# shellcheck source=/dev/null
[ -f "$_vla_root/install/setup.bash" ] && source "$_vla_root/install/setup.bash"
export PATH="$_vla_root/bin:$PATH"
export MUJOCO_GL="${MUJOCO_GL:-egl}"
export VLA_ROOT="$_vla_root"
unset _vla_root _vla_site _d

#!/usr/bin/env bash
# One-command setup: the pinned virtual environment in .venv, the CMake path fix the ROS wheels
# need, and a colcon build of the workspace. Idempotent: a second run only rebuilds what changed.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD

# The operator station's browser tests drive Debian's headless Chromium with Selenium (Playwright cannot
# download its own browsers offline).
if ! { [ -x /usr/lib/chromium/chromium ] && command -v chromedriver >/dev/null; }; then
  if [ "$(id -u)" = 0 ]; then
    echo "[setup] installing chromium and chromium-driver (apt)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null
  else
    echo "[setup] chromium/chromium-driver missing: run as root (apt-get install chromium chromium-driver)" >&2
  fi
fi
venv=$root/.venv
py=${PYTHON:-python3}

stamp=$venv/.requirements.sha256
want=$(sha256sum requirements.txt | cut -d' ' -f1)
if [ ! -x "$venv/bin/python" ] || [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "[setup] creating $venv from requirements.txt (the pinned lock of pyproject.toml)"
  [ -x "$venv/bin/python" ] || "$py" -m venv "$venv"
  "$venv/bin/python" -m pip install -q --disable-pip-version-check --upgrade 'pip==26.3' 2>&1 | grep -v '^WARNING: Location' || true
  # One pip command for everything: colcon-core needs setuptools<80 and pip must see that pin.
  "$venv/bin/python" -m pip install -q --disable-pip-version-check -r requirements.txt 2>&1 \
    | grep -v '^WARNING: Location' || true
  # axe-core for the accessibility tests: the bundle only (its playwright dependency is not used).
  "$venv/bin/python" -m pip install -q --disable-pip-version-check --no-deps 'axe-playwright-python==0.1.8' 2>&1 \
    | grep -v '^WARNING: Location' || true
  "$venv/bin/python" -c "import aiohttp, selenium, axe_playwright_python" \
    || { echo "[setup] the operator station's packages do not import" >&2; exit 1; }
  "$venv/bin/python" -c "import rclpy, mujoco, pinocchio, cv2, onnxruntime, torch, ray, rosbags, mcap" \
    || { echo "[setup] the environment does not import; see the pip output above" >&2; exit 1; }
  echo "$want" > "$stamp"
fi

# The ROS wheels' exported CMake files hard-code the Python paths of the machine they were built
# on; point them at this venv so rosidl's Python generator can compile our interfaces.
site=$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
inc=$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
npinc=$("$venv/bin/python" -c 'import numpy; print(numpy.get_include())')
{ grep -rl --include="*.cmake" "/opt/python/cp311-cp311" "$venv/share" 2>/dev/null || true; } | while read -r f; do
  sed -i -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$npinc#g" \
         -e "s#/opt/python/cp311-cp311/include/python3.11#$inc#g" "$f"
done

# shellcheck source=/dev/null
source "$venv/bin/activate"
export AMENT_PREFIX_PATH=$venv CMAKE_PREFIX_PATH=$venv
export _ROS_WHEELS_BOOTSTRAP_COMPLETE=1
export LD_LIBRARY_PATH=$venv/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
for d in "$site"/ros_*.libs; do [ -d "$d" ] && LD_LIBRARY_PATH=$d:$LD_LIBRARY_PATH; done
# A file moved or deleted in the tree leaves a dangling symlink in a symlink-install build, which
# makes colcon fail ("can't copy ... doesn't exist"): drop dangling links first.
find build install -xtype l -delete 2>/dev/null || true
echo "[setup] colcon build"
colcon --log-base build/log build --symlink-install --base-paths src \
  --event-handlers console_cohesion- status- summary+ \
  --cmake-args -DPython3_EXECUTABLE="$venv/bin/python" -DBUILD_TESTING=OFF -Wno-dev
# The franka-sim robot server (libfranka protocol simulator) for the libfranka tests, in its own
# pinned venv: it pins numpy 1.26 / mujoco < 3.3, which the project's venv cannot share.
bash scripts/setup_franka_sim.sh "$root/.venv-franka-sim"
echo "[setup] done: source scripts/env.sh to use the workspace"

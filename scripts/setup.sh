#!/usr/bin/env bash
# Create the virtual environment and install binpick into it; safe to run again (it skips what is there).
#   scripts/setup.sh [VENV]      (default .venv; PYTHON=python3.11 chooses the interpreter)
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${1:-.venv}
PYTHON=${PYTHON:-$(command -v python3.11 || command -v python3)}

# Headless MuJoCo rendering needs EGL from Mesa (MUJOCO_GL=egl); the ROS 1 bridge needs Debian's
# rospy and actionlib (thesis §6.1.1). Install them when we can (root + apt).
ROS_PACKAGES="python3-rospy python3-actionlib python3-rosmaster python3-genpy python3-genmsg ros-std-msgs ros-actionlib-msgs python3-actionlib-msgs python3-std-msgs"
if command -v dpkg >/dev/null 2>&1; then
  missing=()
  for pkg in libegl1 libegl-mesa0 libgl1-mesa-dri $ROS_PACKAGES; do
    dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
  done
  if [ ${#missing[@]} -gt 0 ]; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
      echo "== installing Debian packages for headless rendering and ROS: ${missing[*]}"
      apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
    else
      echo "warning: rendering and the ROS bridge need the Debian packages ${missing[*]}: run 'sudo apt-get install ${missing[*]}'" >&2
    fi
  fi
fi

pip_quiet() {  # this machine's pip config names local index folders that may not exist: hide that noise
  "$VENV/bin/python" -m pip install -q "$@" 2>&1 | { grep -v "^WARNING: Location 'file:" || true; }
  return "${PIPESTATUS[0]}"
}

if [ ! -x "$VENV/bin/python" ]; then
  echo "== creating $VENV with $PYTHON"
  "$PYTHON" -m venv "$VENV"
fi
echo "== installing binpick and its pinned dependencies into $VENV"
# torch first, pinned: the local CPU build. Anything unpinned would pull GBs of CUDA wheels.
pip_quiet torch==2.13.0
pip_quiet -e ".[test]"
# robosuite only for its object meshes and textures (bottle, bread, can, cereal, lemon, milk): never
# imported, so none of its dependencies (which would downgrade numpy) are needed.
pip_quiet --no-deps robosuite==1.5.2
# ROS 1 lives in Debian's dist-packages: *append* it to the venv's path (a .pth file), so pip's own
# packages keep priority (prepending it through PYTHONPATH would swap in Debian's older PyYAML etc.).
SITE=$("$VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
if [ -d /usr/lib/python3/dist-packages/rospy ]; then
  echo /usr/lib/python3/dist-packages > "$SITE/binpick-debian-ros.pth"
else
  rm -f "$SITE/binpick-debian-ros.pth"
fi
touch "$VENV/.binpick-installed"
echo "== ready: $VENV/bin/binpick"

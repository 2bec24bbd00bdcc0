#!/usr/bin/env bash
# Create the virtual environment and install binpick into it; safe to run again (it skips what is there).
#   scripts/setup.sh [VENV]      (default .venv; PYTHON=python3.11 chooses the interpreter)
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${1:-.venv}
PYTHON=${PYTHON:-$(command -v python3.11 || command -v python3)}

# Headless MuJoCo rendering needs EGL from Mesa (MUJOCO_GL=egl); the ROS 1 bridge needs Debian's
# rospy and actionlib (thesis §6.1.1). Install them when we can (root + apt).
ROS_PACKAGES="python3-rospy python3-actionlib python3-rosmaster python3-genpy python3-genmsg ros-std-msgs ros-actionlib-msgs python3-actionlib-msgs python3-std-msgs python3-sensor-msgs ros-sensor-msgs python3-geometry-msgs ros-geometry-msgs python3-tf2-msgs python3-visualization-msgs python3-roslaunch"
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
pip_quiet -e ".[test,onnx,rerun]"
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
# ROS 2 from PyPI's wheels, in its own interpreter: its std_msgs/geometry_msgs would shadow ROS 1's
# (Debian's) in one path. The ROS 2 venv reads binpick and its dependencies from the main venv (a .pth
# naming its site-packages and src/, without the Debian line); only the ROS 2 wheels are its own.
# BINPICK_ROS2=0 skips it.
ROS2_VENV="${VENV%/}-ros2"
if [ "${BINPICK_ROS2:-1}" != 0 ]; then
  echo "== installing ROS 2 (ros-rclpy wheels) into $ROS2_VENV"
  [ -x "$ROS2_VENV/bin/python" ] || "$PYTHON" -m venv "$ROS2_VENV"
  SITE2=$("$ROS2_VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
  printf '%s\n%s\n' "$(cd "$SITE" && pwd)" "$(pwd)/src" > "$SITE2/binpick-main-venv.pth"
  if "$ROS2_VENV/bin/python" -m pip install -q ros-rclpy==9.1.2 ros-std-msgs==5.5.1 ros-sensor-msgs==5.5.1 \
       ros-geometry-msgs==5.5.1 ros-visualization-msgs==5.5.1 ros-rmw-fastrtps-cpp==9.3.3 2>&1 | { grep -v "^WARNING: Location 'file:" || true; }; then
    printf '#!/bin/sh\nexec "%s" -c "from binpick.cli import main; main()" "$@"\n' "$(cd "$ROS2_VENV" && pwd)/bin/python" > "$ROS2_VENV/bin/binpick"
    chmod +x "$ROS2_VENV/bin/binpick"
  else
    echo "warning: the ROS 2 wheels did not install; the ROS 2 node and its tests are unavailable" >&2
  fi
fi
# binpick's own modules compiled now, as pip compiles what it installs: an interpreter that may not write
# bytecode (PYTHONDONTWRITEBYTECODE) would compile them again in every process and worker it starts
"$VENV/bin/python" -m compileall -q -j 0 src >/dev/null || echo "warning: binpick's modules did not compile ahead" >&2
touch "$VENV/.binpick-installed"
echo "== ready: $VENV/bin/binpick"

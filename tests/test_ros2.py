"""The pick node over ROS 2 (PyPI's ros-rclpy wheels, in .venv-ros2), inside a network namespace with
only loopback: the whole loop, simulator to node to executed grasp. Skipped, with the reason, where the
ROS 2 interpreter is absent or a namespace cannot be made (needs root or user namespaces)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ROS2_PYTHON = Path(sys.prefix).with_name(Path(sys.prefix).name + "-ros2") / "bin" / "python"


def _why_not() -> str | None:
    if not ROS2_PYTHON.is_file():
        return f"no ROS 2 interpreter at {ROS2_PYTHON} (scripts/setup.sh makes it; BINPICK_ROS2=0 skipped it)"
    probe = subprocess.run([str(ROS2_PYTHON), "-c", "from binpick.integrations.ros2 import ros2_missing; print(ros2_missing() or '')"],
                           capture_output=True, text=True)
    if probe.returncode != 0 or probe.stdout.strip():
        return f"ROS 2 is not importable in {ROS2_PYTHON}: {(probe.stdout + probe.stderr).strip()[-200:]}"
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return "unshare or ip (util-linux, iproute2) missing: ROS 2 runs only in a loopback-only network namespace"
    if subprocess.run(["unshare", "-n", "true"], capture_output=True).returncode != 0:
        return "cannot create a network namespace here (unshare -n needs root or user namespaces)"
    return None


pytestmark = pytest.mark.skipif(_why_not() is not None, reason=_why_not() or "")


def test_a_bin_is_picked_through_the_ros2_node_from_its_parameter_file_inside_a_loopback_only_namespace():
    command = (f"ip link set lo up && exec {ROS2_PYTHON} {ROOT / 'benchmarks' / 'ros_loop.py'} --ros 2 --orders 2 "
               "--goal photo,box --timeout 120 --products robosuite/can,pybullet/duck --hostile --launch")  # bins placed at the first grasp
    ran = subprocess.run(["unshare", "-n", "sh", "-c", command], capture_output=True, text=True, timeout=300)
    assert ran.returncode == 0, ran.stderr[-2000:]
    summary = json.loads(ran.stdout.strip().splitlines()[-1])
    assert summary["interfaces"] == ["lo"]  # DDS had no other address to reach
    assert summary["orders"] == 2 and summary["placed"] == 2, summary  # after the hostile messages below
    assert summary["frame"] == "world"
    hostile = summary["hostile"]  # bad camera messages and goals sent to the running node before the first good goal
    assert hostile["goals"] >= 20 and hostile["answered_with_reason"] == hostile["goals"], hostile["goal_answers"]
    assert hostile["camera_messages"] >= 15 and hostile["camera_messages_dropped"] == hostile["camera_messages"]  # each one refused
    assert hostile["camera_internal_errors"] == 0  # none of them failed inside the node
    assert hostile["node_alive_at_end"] and hostile["tracebacks_in_node_log"] == 0, ran.stderr[-3000:]  # the node's log ends it
    assert summary["overlays"] >= 1 and summary["overlay_size"] == [416, 416]  # the node's picture of its plan
    shown = summary["shown"]  # the node started from ros/ros2/pick_node.yaml: grasps as poses and RViz markers, the camera's pose
    assert shown["pose_arrays"] >= 2 and shown["poses"] >= 2 and 3 * shown["poses"] <= shown["markers"] <= 4 * shown["poses"]
    assert shown["static_frames"] == ["world->binpick_camera_optical_frame"]
    client = summary["example_client"]  # ros/ros2/plan_client.py, as a user runs it
    assert client["returncode"] == 0 and client["grasps"] >= 1 and client["frame"] == "world", client


def test_ros2_refuses_to_run_outside_a_namespace():
    ran = subprocess.run([str(ROS2_PYTHON), str(ROOT / "benchmarks" / "ros_loop.py"), "--ros", "2", "--orders", "1"],
                         capture_output=True, text=True, timeout=120)
    assert ran.returncode != 0 and "only inside a namespace with just loopback" in ran.stderr

"""The pick planner as a ROS 2 node, from PyPI's ``ros-rclpy`` wheels (no ROS install, no colcon).

ROS 2's wheels and Debian's ROS 1 both provide ``std_msgs`` and ``geometry_msgs``, so ROS 2 runs in its
own interpreter: ``scripts/setup.sh`` makes ``.venv-ros2`` (the wheels, plus binpick's venv on its
path, without Debian's). Run it inside a network namespace that has only loopback
(``unshare -n``) unless you mean DDS to reach your robot's network; see the README.
"""

from __future__ import annotations

from binpick.core.errors import BinpickError

WHEELS = ("ros-rclpy", "ros-std-msgs", "ros-sensor-msgs", "ros-geometry-msgs", "ros-visualization-msgs", "ros-rmw-fastrtps-cpp")


class Ros2Unavailable(BinpickError):
    """ROS 2's Python packages cannot be imported in this interpreter."""


def ros2_missing() -> str | None:
    """Why the ROS 2 node cannot run in this interpreter, or None when it can."""
    try:
        import geometry_msgs.msg
        import rclpy  # noqa: F401
        import sensor_msgs.msg  # noqa: F401
        import std_msgs.msg  # noqa: F401
        import visualization_msgs.msg  # noqa: F401
    except ImportError as error:
        return (f"ROS 2 is not importable here ({error.name}): run it with .venv-ros2/bin/binpick (scripts/setup.sh makes it; "
                f"it holds the PyPI wheels {' '.join(WHEELS)})")
    if not hasattr(geometry_msgs.msg, "PoseArray") or not hasattr(rclpy, "init"):
        return "the std_msgs/geometry_msgs on this path are ROS 1's (Debian's): run ROS 2 with .venv-ros2/bin/binpick"
    return None


def require_ros2() -> None:
    reason = ros2_missing()
    if reason:
        raise Ros2Unavailable(reason)

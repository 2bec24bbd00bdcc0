"""binpick's ROS 2 pick node, and the camera's pose on tf (tf2_ros's static_transform_publisher), from one
parameter file. Where ROS 2 is installed (launch, launch_ros, tf2_ros), with binpick's ROS 2 command
(`.venv-ros2/bin/binpick`) on PATH or given as binpick:=...:

    ros2 launch ros/ros2/pick_node.launch.py params:=$PWD/ros/ros2/pick_node.yaml

binpick itself runs only in its own venv: this file asks that command for the camera's pose
(`binpick ros2 pick-node --params FILE --camera-tf`) instead of importing binpick into launch's
Python, and starts the node with PYTHONPATH cleared so that a sourced ROS 2's packages do not shadow
the venv's wheels. binpick's tests cannot run this file (PyPI has no launch or tf2_ros wheels); they
start the node from the same parameter file inside a loopback-only namespace.
"""

import os
import shlex
import subprocess
from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

HERE = Path(__file__).resolve().parent
CLEAN = {"PYTHONPATH": ""}  # an empty PYTHONPATH is ignored: the venv's own packages only


def camera_transform(context):
    """A static_transform_publisher for the camera pose in the parameter file's camera.yaml (none when
    its camera_frame is "")."""
    binpick = LaunchConfiguration("binpick").perform(context)
    params = LaunchConfiguration("params").perform(context)
    printed = subprocess.run([binpick, "ros2", "pick-node", "--params", params, "--camera-tf"], capture_output=True, text=True,
                             env={**os.environ, **CLEAN})
    if printed.returncode != 0:
        raise RuntimeError(printed.stderr.strip() or f"{binpick} failed")
    arguments = shlex.split(printed.stdout)
    if not arguments:
        return []
    return [Node(package="tf2_ros", executable="static_transform_publisher", name="binpick_camera_tf", arguments=arguments)]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("params", default_value=str(HERE / "pick_node.yaml"), description="the node's parameter file"),
        DeclareLaunchArgument("binpick", default_value="binpick", description="binpick's ROS 2 command (.venv-ros2/bin/binpick)"),
        ExecuteProcess(cmd=[LaunchConfiguration("binpick"), "ros2", "pick-node", "--params", LaunchConfiguration("params")],
                       additional_env=CLEAN, output="screen"),
        OpaqueFunction(function=camera_transform),
    ])

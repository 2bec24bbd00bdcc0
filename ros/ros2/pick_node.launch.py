"""binpick's ROS 2 pick node, and the camera's pose on tf (tf2_ros's static_transform_publisher), from one
parameter file. Where ROS 2 is installed (launch, launch_ros, tf2_ros), with binpick's ROS 2 venv's
`binpick` on PATH:

    ros2 launch ros/ros2/pick_node.launch.py params:=ros/ros2/pick_node.yaml

binpick's own tests cannot run this file (PyPI has no launch or tf2_ros wheels); they start the node
from the same parameter file (`binpick ros2 pick-node --params ...`) inside a loopback-only namespace.
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

HERE = Path(__file__).resolve().parent


def camera_transform(context):
    """static_transform_publisher's arguments for the camera pose the parameter file's camera.yaml holds."""
    from binpick.picking import read_camera_info
    from binpick.picking.node_params import NodeParams
    from binpick.picking.scene_messages import camera_frame_pose

    params = NodeParams.load(LaunchConfiguration("params").perform(context))
    info = read_camera_info(params.camera)
    pose = camera_frame_pose(info.camera.camera_to_world, info.base_frame, params.camera_frame)
    x, y, z = pose.translation
    qx, qy, qz, qw = pose.rotation
    arguments = ["--x", str(x), "--y", str(y), "--z", str(z), "--qx", str(qx), "--qy", str(qy), "--qz", str(qz), "--qw", str(qw),
                 "--frame-id", pose.parent, "--child-frame-id", pose.child]
    return [Node(package="tf2_ros", executable="static_transform_publisher", name="binpick_camera_tf", arguments=arguments)]


def generate_launch_description() -> LaunchDescription:
    params = LaunchConfiguration("params")
    return LaunchDescription([
        DeclareLaunchArgument("params", default_value=str(HERE / "pick_node.yaml"), description="the node's parameter file"),
        ExecuteProcess(cmd=["binpick", "ros2", "pick-node", "--params", params], output="screen"),
        OpaqueFunction(function=camera_transform),
    ])

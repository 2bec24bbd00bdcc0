"""The ROS bridges: `binpick ros master|serve|bench|pick-node`, `binpick ros2 pick-node`."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from binpick.cli.app import (
    DEFAULT_GRIPPER,
    DEFAULT_POLICY,
    CellOption,
    GripperOption,
    PlanRobotOption,
    RuntimeOption,
    console,
    load_cell,
    output_folder,
    product_library,
    ros2_app,
    ros_app,
)
from binpick.core.errors import BinpickError, ConfigError
from binpick.core.files import atomic_write_json, check_output_file

MasterOption = Annotated[str | None, typer.Option("--master", help="ROS master URI (default: $ROS_MASTER_URI)")]
NamespaceOption = Annotated[str, typer.Option(help="Action namespace clients connect to, e.g. /binpick/env")]


def _check_timeout(timeout: float) -> float:
    from binpick.core.config import check_range

    return check_range("--timeout", timeout, 0.0, 3600.0, low_inclusive=False)


def _check_namespace(namespace: str, option: str = "--namespace") -> str:
    import re

    if not re.fullmatch(r"/?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*/?", namespace):
        raise ConfigError(f"{option} must be a ROS graph name like /binpick/env (letters, digits, _ and /), "
                          f"got {namespace!r}")
    return namespace


def _ros_environment(master: str | None, timeout: float) -> None:
    """Point this process's ROS node at ``master`` on 127.0.0.1 (before rospy is imported), and wait up
    to ``timeout`` seconds for it to answer: rospy would wait forever."""
    import os

    from binpick.integrations.ros1 import (
        check_master_uri,
        local_ros_environment,
        require_ros,
        wait_for_master,
    )

    uri = master or os.environ.get("ROS_MASTER_URI")
    if not uri:
        raise ConfigError("no ROS master: give --master http://127.0.0.1:PORT/ or set ROS_MASTER_URI")
    check_master_uri(uri)
    require_ros()
    wait_for_master(uri, timeout)
    os.environ.update({k: v for k, v in local_ros_environment(uri).items() if k not in os.environ or k == "ROS_MASTER_URI"})


@ros_app.command("master")
def ros_master(port: Annotated[int, typer.Option(min=1, max=65535, help="Port on 127.0.0.1")] = 11311) -> None:
    """Run a ROS master on 127.0.0.1 until Ctrl-C or SIGTERM (both stop the master process too)."""
    import signal

    from binpick.integrations.ros1.master import RosMaster

    def stop(*_: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)  # `kill` of this command must not leave rosmaster listening
    try:  # a stop while rosmaster still starts is as clean as one later (RosMaster stops its child either way)
        with RosMaster(port) as master:
            console.print(f"ROS master at {master.uri} (Ctrl-C to stop)")
            master.process.wait()
    except KeyboardInterrupt:
        pass


@ros_app.command("serve")
def ros_serve(
    env_id: Annotated[str, typer.Argument(help="binpick env id, e.g. binpick/FetchReach-v0")],
    namespace: NamespaceOption = "/binpick/env",
    master: MasterOption = None,
    timeout: Annotated[float, typer.Option(help="Seconds to wait for the ROS master")] = 10.0,
) -> None:
    """Serve an env as an actionlib server: goals reset or step it, results carry observation and reward."""
    from binpick.envs import resolve_env_id

    env_id = resolve_env_id(env_id)
    _check_namespace(namespace)
    _ros_environment(master, _check_timeout(timeout))
    from binpick.integrations.ros1.server import serve

    serve(env_id, namespace, master_timeout=timeout)


@ros_app.command("bench")
def ros_bench(
    namespace: Annotated[str, typer.Option(help="Action namespace of a served Fetch env, e.g. /binpick/env")] = "/binpick/env",
    episodes: Annotated[int, typer.Option(help="Episodes of the scripted reach policy")] = 10,
    master: MasterOption = None,
    out: Annotated[Path | None, typer.Option(help="Also write bench.json (the summary) into this folder")] = None,
    timeout: Annotated[float, typer.Option(help="Seconds to wait for the server and for each result")] = 10.0,
) -> None:
    """Drive a served Fetch env over ROS with the scripted reach policy: success and round-trip latency."""
    from binpick.core.config import check_range

    check_range("episodes", episodes, 1, 100_000, integer=True)
    _check_namespace(namespace)
    json_out = None if out is None else check_output_file(output_folder(out) / "bench.json", "--out")
    _ros_environment(master, _check_timeout(timeout))
    import gymnasium as gym
    import numpy as np

    from binpick.rl.common.evaluate import evaluate_policy
    from binpick.rl.common.heuristic import ReachController

    env = gym.make("binpick/Ros-v0", namespace=namespace, timeout=timeout)
    result = evaluate_policy(ReachController(env.action_space.shape[0]), env, episodes=episodes, seed=0)
    trips = np.array(env.unwrapped.round_trips_ms)
    summary = {**result.to_dict(), "round_trips": int(trips.size), "median_ms": round(float(np.median(trips)), 3),
               "p95_ms": round(float(np.percentile(trips, 95)), 3), "namespace": namespace}
    print(json.dumps(summary))
    if json_out is not None:
        atomic_write_json(json_out, summary)


NodeCamera = Annotated[Path | None, typer.Option("--camera", help="camera.yaml whose camera_to_base places the camera in the robot's "
                                                                   "base frame (intrinsics come from the camera_info topic)")]
ColourTopic = Annotated[str, typer.Option(help="sensor_msgs/Image colour topic")]
DepthTopic = Annotated[str, typer.Option(help="sensor_msgs/Image depth topic, registered to colour (16UC1 mm or 32FC1 m)")]
InfoTopic = Annotated[str, typer.Option(help="sensor_msgs/CameraInfo of the colour camera")]
NodeProducts = Annotated[Path | None, typer.Option("--products", help="YAML of your own products (ids goals may name)")]
NodeWeights = Annotated[Path | None, typer.Option(help="Photo-conditioned detector (default: shipped)")]
NodeGrasp = Annotated[str, typer.Option(help="Grasp policy: learnt, analytic or fixed")]
NodeGraspWeights = Annotated[Path | None, typer.Option(help="Grasp-quality weights (default: shipped)")]
NodeParamsOption = Annotated[Path | None, typer.Option("--params", help="The node's parameter file (YAML: camera, camera_frame, cell, "
                                                                         "namespace, topics, ...; ros/binpick/config/pick_node.yaml); "
                                                                         "an option given on the command line wins over it")]
CameraFrameOption = Annotated[str, typer.Option(help="The camera's tf frame: its pose in the base frame is published as a static "
                                                     "transform (not the camera driver's own optical frame: tf allows one parent; "
                                                     "\"\": none published)")]
COLOUR, DEPTH, INFO = "/camera/color/image_raw", "/camera/aligned_depth_to_color/image_raw", "/camera/color/camera_info"
NODE_OPTIONS = {"camera": "camera", "camera_frame": "camera_frame", "cell": "cell", "namespace": "namespace",
                "products_file": "products", "weights": "weights", "grasp": "grasp", "grasp_weights": "grasp_weights",
                "runtime": "runtime", "robot": "robot", "gripper": "gripper"}
TOPIC_OPTIONS = {"colour_topic": "colour", "depth_topic": "depth", "info_topic": "info"}


def _node_settings(ctx: typer.Context, params: Path | None) -> dict:
    """The node's settings: the command line's options, over the parameter file's values where the
    option was not given on the command line (then over the defaults)."""
    from binpick.picking.node_params import check_frame_name

    settings = dict(ctx.params)
    if params is not None:
        from binpick.picking.node_params import NodeParams

        loaded = NodeParams.load(params)
        # by name: Typer carries its own copy of Click, whose ParameterSource is another enum than click's
        given = {name for name in settings if getattr(ctx.get_parameter_source(name), "name", None) == "COMMANDLINE"}
        for option, key in NODE_OPTIONS.items():
            if option not in given:
                settings[option] = getattr(loaded, key)
        for option, key in TOPIC_OPTIONS.items():
            if option not in given:
                settings[option] = getattr(loaded.topics, key)
        if "gripper" in given and "cell" not in given:  # --gripper on the command line wins over the file's cell too
            settings["cell"] = None
    try:
        check_frame_name(settings["camera_frame"], "--camera-frame")
    except BinpickError as error:
        raise ConfigError(str(error)) from None
    return settings


def _pick_node_setup(settings: dict):
    """Checked names, then the extrinsic (camera.yaml's camera_to_base: every grasp is given in the base
    frame), the picker and the topics: everything a pick node needs before ROS starts."""
    from binpick.picking import Picker, read_camera_info
    from binpick.picking.node import Topics

    for key, option in (("namespace", "--namespace"), ("colour_topic", "--colour-topic"), ("depth_topic", "--depth-topic"),
                        ("info_topic", "--info-topic")):
        _check_namespace(settings[key], option)
    camera = settings["camera"]
    if camera is None:
        raise ConfigError("a pick node needs --camera camera.yaml with camera_to_base (the camera's pose in the robot's "
                          "base frame, in which every grasp is given; the camera_info topic brings the intrinsics), "
                          "or a --params file naming it")
    calibration = read_camera_info(camera)
    pose, frame, workspace = calibration.camera.camera_to_world, calibration.base_frame, calibration.workspace
    # the camera_info topic brings K and D; camera.yaml's workspace bounds every pose the node emits
    if settings["camera_frame"] == frame:
        raise ConfigError(f"the camera's tf frame {frame!r} is the base frame camera.yaml places it in: give --camera-frame "
                          "(or camera_frame in the parameter file) a frame of its own")
    cell = load_cell(settings["cell"], settings["robot"])
    gripper = cell.tools if cell is not None else settings["gripper"]
    reach = None
    if settings["robot"] != "floating":  # grasps the arm cannot take are rejected in the result, with the reason
        from binpick.arm import MotionPlanner

        reach = MotionPlanner.for_cell(cell, gripper, arm=settings["robot"]).reach_check
    picker = Picker.load(settings["weights"], settings["grasp"], settings["grasp_weights"], workspace=workspace,
                         runtime=settings["runtime"], reach=reach, gripper=gripper, cell=cell)
    return pose, frame, picker, Topics(settings["colour_topic"], settings["depth_topic"], settings["info_topic"])


@ros_app.command("pick-node")
def ros_pick_node(
    ctx: typer.Context,
    params: NodeParamsOption = None,
    camera: NodeCamera = None,
    camera_frame: CameraFrameOption = "binpick_camera_optical_frame",
    namespace: Annotated[str, typer.Option(help="Action namespace of the PlanPick server")] = "/binpick/plan_pick",
    colour_topic: ColourTopic = COLOUR, depth_topic: DepthTopic = DEPTH, info_topic: InfoTopic = INFO,
    products_file: NodeProducts = None, weights: NodeWeights = None, grasp: NodeGrasp = DEFAULT_POLICY,
    grasp_weights: NodeGraspWeights = None, runtime: RuntimeOption = "torch", robot: PlanRobotOption = "floating",
    gripper: GripperOption = DEFAULT_GRIPPER, cell: CellOption = None,
    master: MasterOption = None,
    timeout: Annotated[float, typer.Option(help="Seconds to wait for the ROS master")] = 10.0,
) -> None:
    """Serve pick planning over ROS 1: camera topics in, a PlanPick action (grasp poses in the base frame) out;
    grasps also as a PoseArray, RViz markers and tf frames."""
    settings = _node_settings(ctx, params)
    pose, frame, picker, topics = _pick_node_setup(settings)
    library = product_library(settings["products_file"])
    _ros_environment(master, _check_timeout(timeout))
    from binpick.integrations.ros1.pick_node import serve

    serve(picker, pose, frame, settings["namespace"], topics, library, master_timeout=timeout, camera_frame=settings["camera_frame"])


def _static_transform_arguments(settings: dict) -> list[str]:
    """static_transform_publisher's flags for the camera's pose in camera.yaml (none: no camera frame)."""
    from binpick.picking import read_camera_info
    from binpick.picking.scene_messages import camera_frame_pose

    if settings["camera"] is None:
        raise ConfigError("--camera-tf needs --camera camera.yaml (or a --params file naming it)")
    if not settings["camera_frame"]:
        return []
    info = read_camera_info(settings["camera"])
    pose = camera_frame_pose(info.camera.camera_to_world, info.base_frame, settings["camera_frame"])
    values = [*pose.translation, *pose.rotation]
    flags = ["--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw"]
    return [item for flag, value in zip(flags, values) for item in (flag, repr(float(value)))] + [
        "--frame-id", pose.parent, "--child-frame-id", pose.child]


@ros2_app.command("pick-node")
def ros2_pick_node(
    ctx: typer.Context,
    params: NodeParamsOption = None,
    camera: NodeCamera = None,
    camera_frame: CameraFrameOption = "binpick_camera_optical_frame",
    namespace: Annotated[str, typer.Option(help="Namespace of the goal/result topics")] = "/binpick/plan_pick",
    colour_topic: ColourTopic = COLOUR, depth_topic: DepthTopic = DEPTH, info_topic: InfoTopic = INFO,
    products_file: NodeProducts = None, weights: NodeWeights = None, grasp: NodeGrasp = DEFAULT_POLICY,
    grasp_weights: NodeGraspWeights = None, runtime: RuntimeOption = "torch", robot: PlanRobotOption = "floating",
    gripper: GripperOption = DEFAULT_GRIPPER, cell: CellOption = None,
    camera_tf: Annotated[bool, typer.Option("--camera-tf", help="Print the camera's pose as tf2_ros static_transform_publisher "
                                                                "arguments and exit (the ROS 2 launch file uses it)")] = False,
) -> None:
    """Serve pick planning over ROS 2 (run with .venv-ros2/bin/binpick): camera topics in, grasp poses out;
    grasps also as a PoseArray and RViz markers."""
    settings = _node_settings(ctx, params)
    if camera_tf:
        print(" ".join(_static_transform_arguments(settings)))
        return
    from binpick.integrations.ros2 import require_ros2

    require_ros2()
    pose, frame, picker, topics = _pick_node_setup(settings)
    from binpick.integrations.ros2.pick_node import serve

    serve(picker, pose, frame, settings["namespace"], topics, product_library(settings["products_file"]),
          camera_frame=settings["camera_frame"])

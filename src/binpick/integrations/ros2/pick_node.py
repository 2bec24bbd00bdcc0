"""The pick planner as a ROS 2 node: the ROS 1 node's interface over plain topics.

The same camera topics come in (colour, depth registered to colour, camera_info; matched by stamp).
ROS 2 actions and services need interface types compiled by rosidl (colcon, a C compiler, the ROS
build tool chain), which PyPI's wheels do not carry, so the request and answer of ``PlanPick`` travel
as standard messages on ``<namespace>/...``:

- ``goal`` (``std_msgs/String``, JSON ``{"id", "product_id", "max_grasps", "size", "query_box", "copies_only"}``) or ``goal_photo``
  (``sensor_msgs/Image``, the shop photo; ``header.frame_id`` is the request id, or that JSON);
- ``result`` (``std_msgs/String``, JSON ``{"id", "status", "text", "grasps": [{position, orientation,
  score, quality, width, tool}], "opening", "plans"}``): the ROS 1 result's fields, same values;
- ``grasps`` (``geometry_msgs/PoseArray`` in the base frame, best first, for RViz), ``markers``
  (``visualization_msgs/MarkerArray``: each grasp's approach, fingers or cup, rank and score) and ``overlay``;
- ``camera_pose`` (``geometry_msgs/TransformStamped``, latched): the camera's pose in the base frame. tf itself
  (``tf2_msgs``) is not among PyPI's wheels: the ROS 2 launch file (``ros/ros2``) publishes the same pose
  with tf2_ros's ``static_transform_publisher`` where ROS 2 is installed;
- ``dropped`` (``std_msgs/String``, JSON ``{topic: count}``): camera messages the node refused, when the counts change
- ``errors`` (``std_msgs/String``, JSON ``{topic: count}``): camera messages the node's own code failed on (tracebacks in its log).
"""

from __future__ import annotations

import array
import json
import sys

import numpy as np

from binpick.picking.camera_info import CameraInfo
from binpick.picking.node import (Goal, Guard, PlanRequests, colour_of, depth_of, describe, image_array, image_fields, parse_goal,
                                  parse_goal_json, photo_of, request_id_of)
from binpick.picking.scene_messages import camera_frame_pose, grasp_markers
from binpick.integrations.ros_messages import marker_array, pose_array, transform_stamped
from binpick.integrations.ros2 import require_ros2

RELIABLE_DEPTH = 10


def image_message(array_: np.ndarray, encoding: str, stamp=None, frame_id: str = ""):
    import sensor_msgs.msg

    fields = image_fields(array_, encoding)
    message = sensor_msgs.msg.Image(height=fields["height"], width=fields["width"], encoding=encoding,
                                    is_bigendian=0, step=fields["step"])
    message.data = array.array("B", fields["data"])  # array.array: no per-byte validation
    if stamp is not None:
        message.header.stamp = stamp
    message.header.frame_id = frame_id
    return message


def pixels(message) -> np.ndarray:
    return image_array(message.encoding, message.height, message.width, message.step, memoryview(message.data).tobytes(),
                       bool(message.is_bigendian))


def stamp_seconds(header) -> float:
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


def subscribe_camera(node, guard: Guard, frames, topics: tuple[str, str, str], camera_to_base: np.ndarray, base_frame: str) -> None:
    """The camera's colour, depth and camera_info topics into ``frames`` (matched by stamp); a message
    that cannot be read is dropped with its reason by ``guard``."""
    import sensor_msgs.msg
    from rclpy.qos import qos_profile_sensor_data

    colour, depth, info = topics

    def on_info(message) -> None:
        frames.add_info(stamp_seconds(message.header), CameraInfo.from_ros(
            message.k, message.d, message.width, message.height, camera_to_base, message.distortion_model or "plumb_bob", base_frame))

    node.create_subscription(sensor_msgs.msg.Image, colour, guard.frames(colour, lambda m: frames.add_colour(
        stamp_seconds(m.header), colour_of(m.encoding, pixels(m)))), qos_profile_sensor_data)
    node.create_subscription(sensor_msgs.msg.Image, depth, guard.frames(depth, lambda m: frames.add_depth(
        stamp_seconds(m.header), depth_of(m.encoding, pixels(m)))), qos_profile_sensor_data)
    node.create_subscription(sensor_msgs.msg.CameraInfo, info, guard.frames(info, on_info), qos_profile_sensor_data)


def report_drops(node, guard: Guard, namespace: str) -> None:
    """Camera messages refused (``dropped``) and failed on inside (``errors``), published twice a second
    when the counts change."""
    import std_msgs.msg

    dropped = node.create_publisher(std_msgs.msg.String, f"{namespace}/dropped", RELIABLE_DEPTH)
    errors = node.create_publisher(std_msgs.msg.String, f"{namespace}/errors", RELIABLE_DEPTH)

    def publish() -> None:
        counts = guard.report()
        if counts is not None:
            dropped.publish(std_msgs.msg.String(data=counts[0]))
            errors.publish(std_msgs.msg.String(data=counts[1]))

    node.create_timer(0.5, publish)


def answer_json(request_id: str, stamp: float, plans, opening: float) -> str:
    """A goal's answer: its grasps (tool, pose, scores, width) in the base frame, the jaws' opening and
    every plan."""
    grasps = [{"tool": p.tool, "position": p.position, "orientation": p.orientation, "score": p.score, "quality": p.quality,
               "width": p.width} for p in plans.grasps]
    return json.dumps({"id": request_id, "status": "succeeded", "text": "", "frame": plans.frame, "stamp": stamp,
                       "grasps": grasps, "opening": opening, "plans": plans.to_json()})


def make_node(requests: PlanRequests, camera_to_base: np.ndarray, base_frame: str, namespace: str = "/binpick/plan_pick",
              colour: str = "/camera/color/image_raw", depth: str = "/camera/aligned_depth_to_color/image_raw",
              info: str = "/camera/color/camera_info", camera_frame: str = "binpick_camera_optical_frame"):
    """An ``rclpy`` node serving plan requests (``rclpy.init`` first)."""
    require_ros2()
    import builtin_interfaces.msg
    import geometry_msgs.msg
    import rclpy.node
    import sensor_msgs.msg
    import std_msgs.msg
    import visualization_msgs.msg
    from rclpy.qos import DurabilityPolicy, QoSProfile

    namespace = namespace.rstrip("/")
    node = rclpy.node.Node("binpick_pick_planner")
    frames = requests.frames
    guard = Guard(node.get_logger().warning)
    node.binpick_guard = guard  # what was dropped, for whoever runs the node

    subscribe_camera(node, guard, frames, (colour, depth, info), camera_to_base, base_frame)
    results = node.create_publisher(std_msgs.msg.String, f"{namespace}/result", RELIABLE_DEPTH)
    poses = node.create_publisher(geometry_msgs.msg.PoseArray, f"{namespace}/grasps", RELIABLE_DEPTH)
    overlay = node.create_publisher(sensor_msgs.msg.Image, f"{namespace}/overlay", 1)
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)  # late subscribers get the last one
    markers = node.create_publisher(visualization_msgs.msg.MarkerArray, f"{namespace}/markers", latched)
    camera_pose = node.create_publisher(geometry_msgs.msg.TransformStamped, f"{namespace}/camera_pose", latched)
    if camera_frame:  # "": the camera's driver or your own calibration publishes it
        camera_pose.publish(transform_stamped(camera_frame_pose(camera_to_base, base_frame, camera_frame), node.get_clock().now().to_msg()))
    report_drops(node, guard, namespace)

    def aborted(request_id: str, error: BaseException) -> None:
        results.publish(std_msgs.msg.String(data=json.dumps({"id": request_id, "status": "aborted", "text": describe(error)})))

    def answer(goal: Goal) -> None:
        frame, plans = requests.plan(goal.product_id, goal.photo, goal.max_grasps, goal.size, goal.query_box, goal.copies_only)
        answer_text = answer_json(goal.id, frame.stamp, plans, float(requests.picker.grasp.gripper.opening))
        stamp = builtin_interfaces.msg.Time(sec=int(frame.stamp), nanosec=int(1e9 * (frame.stamp % 1)))
        array_message = pose_array(plans.grasps, plans.frame, stamp)
        results.publish(std_msgs.msg.String(data=answer_text))  # built in full first: a goal is answered once
        opening = requests.picker.grasp.gripper.opening
        for topic, publish in ((f"{namespace}/grasps", lambda: poses.publish(array_message)),
                               (f"{namespace}/markers", lambda: markers.publish(marker_array(grasp_markers(plans.grasps, opening), plans.frame, stamp))),
                               (f"{namespace}/overlay", lambda: overlay.publish(image_message(
                                   plans.plot(frame.rgb, frame.camera.camera, opening, goal.photo), "rgb8", stamp, plans.frame)))):
            try:  # the answer is out; what follows it is only logged if it fails, each under its own topic
                publish()
            except Exception as error:  # noqa: BLE001
                guard.drop(topic, error)

    def serve_goal(load, photo_message=None) -> None:
        """Answer one goal message: ``load()`` gives its JSON mapping; every failure is an aborted
        result naming the problem (with the goal's id where it has a readable one), and the node goes
        on serving."""
        request_id = ""
        try:
            request = load()
            request_id = request_id_of(request)
            photo = None if photo_message is None else photo_of(photo_message.encoding, pixels(photo_message))
            answer(parse_goal(request, photo))
        except Exception as error:  # noqa: BLE001 - the client gets the reason instead of a timeout
            try:
                aborted(request_id, error)
            except Exception as failed:  # noqa: BLE001 - even the answer failed: log it, keep serving
                guard.drop(f"{namespace}/result", failed)

    def photo_request(message) -> dict:
        frame_id = str(message.header.frame_id)
        return parse_goal_json(frame_id) if frame_id.startswith("{") else {"id": frame_id}

    node.create_subscription(std_msgs.msg.String, f"{namespace}/goal",
                             lambda message: serve_goal(lambda: parse_goal_json(message.data)), RELIABLE_DEPTH)
    node.create_subscription(sensor_msgs.msg.Image, f"{namespace}/goal_photo",
                             lambda message: serve_goal(lambda: photo_request(message), message), RELIABLE_DEPTH)
    return node


def serve(picker, camera_to_base: np.ndarray, base_frame: str, namespace: str, topics, library=None,
          camera_frame: str = "binpick_camera_optical_frame") -> None:
    """Run the node until Ctrl-C or SIGTERM."""
    require_ros2()
    import rclpy
    from rclpy.executors import ExternalShutdownException

    rclpy.init()
    node = None
    try:
        picker.warm_up()
        from binpick.sim.catalogue import Catalogue

        requests = PlanRequests.with_catalogue(picker, Catalogue(library) if library is not None else None)
        node = make_node(requests, camera_to_base, base_frame, namespace, topics.colour, topics.depth, topics.info, camera_frame)
        node.get_logger().info(f"binpick: planning picks at {namespace} from {topics.colour}, {topics.depth}, {topics.info}")
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):  # Ctrl-C, or SIGTERM through rclpy's handler: a clean stop
        pass
    finally:
        if node is not None:
            print(node.binpick_guard.summary(), file=sys.stderr, flush=True)
        if rclpy.ok():
            rclpy.shutdown()

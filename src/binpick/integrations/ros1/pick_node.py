"""The pick planner as a ROS 1 node (thesis ch. 6): an RGB-D camera's colour, depth and
``CameraInfo`` topics in (matched by time stamp), a ``binpick/PlanPick`` action out (goal: a product id
or its shop photo; result: grasp poses in the robot's base frame with scores), and for each answer an
overlay image (``<namespace>/overlay``), the grasps as a ``geometry_msgs/PoseArray``
(``<namespace>/grasps``), RViz markers (``<namespace>/markers``, ``visualization_msgs/MarkerArray``) and tf
frames ``binpick_grasp_1``, ... (``/tf``); the camera's pose is a static transform (``/tf_static``). Everything
but the ROS plumbing is :mod:`binpick.picking.node` and :mod:`binpick.picking.scene_messages`, shared with
the ROS 2 node. ``roslaunch binpick pick_node.launch`` starts it from a parameter file (``ros/binpick``).
"""

from __future__ import annotations

import json
import sys

import numpy as np

from binpick.picking.camera_info import CameraInfo
from binpick.picking.node import Guard, PlanRequests, Topics, colour_of, depth_of, describe, image_array, image_fields, photo_of
from binpick.picking.scene_messages import camera_frame_pose, grasp_frame_poses, grasp_markers
from binpick.integrations.ros_messages import marker_array, pose_array, pose_of, tf_message
from binpick.integrations.ros1 import init_node_within, master_uri, require_ros, stop_timer, wait_for_master


def stamp_seconds(header) -> float:
    return header.stamp.secs + 1e-9 * header.stamp.nsecs


def pose_stamped(plan, frame: str, stamp):
    import geometry_msgs.msg

    message = geometry_msgs.msg.PoseStamped()
    message.header.frame_id, message.header.stamp = frame, stamp
    message.pose = pose_of(plan.position, plan.orientation)
    return message


class PickNode:
    """Serves ``binpick/PlanPick`` at ``namespace``. Call from a node (``rospy.init_node`` first)."""

    def __init__(self, requests: PlanRequests, camera_to_base: np.ndarray, base_frame: str, namespace: str = "/binpick/plan_pick",
                 topics: Topics = Topics(), camera_frame: str = "binpick_camera_optical_frame") -> None:
        require_ros()
        import actionlib
        import rospy
        import sensor_msgs.msg

        from binpick.integrations.ros1.messages import plan_pick_action_types

        self.requests, self.camera_to_base, self.base_frame = requests, camera_to_base, base_frame
        self.namespace = namespace.rstrip("/")
        self.types = plan_pick_action_types()
        frames = requests.frames
        self.guard = guard = Guard(rospy.logwarn)  # a bad camera message is dropped with a warning, never a traceback
        self.subscribers = [
            rospy.Subscriber(topics.colour, sensor_msgs.msg.Image, guard.frames(topics.colour, lambda m: frames.add_colour(
                stamp_seconds(m.header), colour_of(m.encoding, self._pixels(m)))), queue_size=2, buff_size=2**24),
            rospy.Subscriber(topics.depth, sensor_msgs.msg.Image, guard.frames(topics.depth, lambda m: frames.add_depth(
                stamp_seconds(m.header), depth_of(m.encoding, self._pixels(m)))), queue_size=2, buff_size=2**24),
            rospy.Subscriber(topics.info, sensor_msgs.msg.CameraInfo, guard.frames(topics.info, lambda m: frames.add_info(
                stamp_seconds(m.header), self._camera(m))), queue_size=2),
        ]
        self.overlay = rospy.Publisher(f"{self.namespace}/overlay", sensor_msgs.msg.Image, queue_size=1, latch=True)
        import std_msgs.msg

        self.dropped = rospy.Publisher(f"{self.namespace}/dropped", std_msgs.msg.String, queue_size=2, latch=True)
        self.errors = rospy.Publisher(f"{self.namespace}/errors", std_msgs.msg.String, queue_size=2, latch=True)
        self.string = std_msgs.msg.String
        import geometry_msgs.msg
        import tf2_msgs.msg
        import visualization_msgs.msg

        self.grasps = rospy.Publisher(f"{self.namespace}/grasps", geometry_msgs.msg.PoseArray, queue_size=1, latch=True)
        self.markers = rospy.Publisher(f"{self.namespace}/markers", visualization_msgs.msg.MarkerArray, queue_size=1, latch=True)
        self.tf = rospy.Publisher("/tf", tf2_msgs.msg.TFMessage, queue_size=10)
        self.tf_static = rospy.Publisher("/tf_static", tf2_msgs.msg.TFMessage, queue_size=1, latch=True)
        if camera_frame:  # "": the camera's driver or your own calibration publishes it
            self.tf_static.publish(tf_message([camera_frame_pose(camera_to_base, base_frame, camera_frame)], rospy.Time.now()))
        # camera messages it refused (dropped) and those its own code failed on (errors), JSON {topic: count}
        self.timer = rospy.Timer(rospy.Duration(0.5), self._report_drops)
        self.server = actionlib.ActionServer(self.namespace, self.types["PlanPickAction"], self._on_goal, auto_start=False)
        self.server.start()
        self.stamps: dict[float, object] = {}
        self.stopped = False
        rospy.on_shutdown(self.stop)

    def _report_drops(self, _event=None) -> None:
        counts = self.guard.report()
        if counts is not None:
            self.dropped.publish(self.string(data=counts[0]))
            self.errors.publish(self.string(data=counts[1]))

    @staticmethod
    def _pixels(message) -> np.ndarray:
        return image_array(message.encoding, message.height, message.width, message.step, message.data, bool(message.is_bigendian))

    def _camera(self, message) -> CameraInfo:
        return CameraInfo.from_ros(message.K, message.D, message.width, message.height, self.camera_to_base,
                                   message.distortion_model or "plumb_bob", self.base_frame)

    def _on_goal(self, handle) -> None:
        import rospy

        goal = handle.get_goal()
        handle.set_accepted()
        try:
            handle.publish_feedback(self.types["PlanPickFeedback"](state="planning"))
            photo = None
            if goal.photo.width or goal.photo.height or len(goal.photo.data):
                photo = photo_of(goal.photo.encoding, self._pixels(goal.photo))
            frame, plans = self.requests.plan(goal.product_id, photo, int(goal.max_grasps), list(goal.size),  # checked there
                                              list(goal.query_box), bool(goal.copies_only))
            stamp = rospy.Time.from_sec(frame.stamp)
            result = self.types["PlanPickResult"]()
            result.grasps = [pose_stamped(p, plans.frame, stamp) for p in plans.grasps]
            result.scores = [p.score for p in plans.grasps]
            result.qualities = [p.quality if p.quality is not None else float("nan") for p in plans.grasps]
            result.tools = [p.tool or "jaws" for p in plans.grasps]
            result.widths = [p.width if p.width is not None else float("nan") for p in plans.grasps]
            result.opening = float(self.requests.picker.grasp.gripper.opening)
            result.plans_json = json.dumps({**plans.to_json(), "stamp": frame.stamp})
            handle.set_succeeded(result)
        except Exception as error:  # noqa: BLE001 - the client gets the reason instead of a timeout
            handle.set_aborted(text=describe(error))
            return
        grasps, opening = plans.grasps, self.requests.picker.grasp.gripper.opening
        # the answer is out; what follows it is only logged if it fails, each under its own topic. The grasp
        # frames are stamped now: a plan on the same camera frame again would repeat the frame's stamp on /tf
        for topic, publish in ((f"{self.namespace}/grasps", lambda: self.grasps.publish(pose_array(grasps, plans.frame, stamp))),
                               (f"{self.namespace}/markers", lambda: self.markers.publish(
                                   marker_array(grasp_markers(grasps, opening), plans.frame, stamp))),
                               ("/tf", lambda: grasps and self.tf.publish(tf_message(grasp_frame_poses(grasps, plans.frame), rospy.Time.now()))),
                               (f"{self.namespace}/overlay", lambda: self._publish_overlay(frame, plans, photo, stamp))):
            try:
                publish()
            except Exception as error:  # noqa: BLE001
                self.guard.drop(topic, error)

    def _publish_overlay(self, frame, plans, photo, stamp) -> None:
        import sensor_msgs.msg

        picture = plans.plot(frame.rgb, frame.camera.camera, self.requests.picker.grasp.gripper.opening, photo)
        message = sensor_msgs.msg.Image(**image_fields(picture, "rgb8"))
        message.header.stamp = stamp
        self.overlay.publish(message)

    def stop(self) -> None:
        """Stop the timers, the action server and the subscribers, once. rospy runs it first when it
        shuts down (``on_shutdown``): it closes the node's topics before ``is_shutdown()`` turns true, and
        a timer that published in between (actionlib's status, the drop report) died in its thread
        with "publish() to a closed topic". A goal being planned is finished first (the server's lock)."""
        if self.stopped:
            return
        self.stopped = True
        stop_timer(self.timer)
        self.server.stop()  # under the server's lock: a status being published is finished first
        for subscriber in self.subscribers:
            subscriber.unregister()


def serve(picker, camera_to_base: np.ndarray, base_frame: str, namespace: str, topics: Topics, library=None,
          node_name: str = "binpick_pick_planner", master_timeout: float = 10.0,
          camera_frame: str = "binpick_camera_optical_frame") -> None:
    """Run the node until ROS shuts down (Ctrl-C or SIGTERM)."""
    require_ros()
    import rospy

    wait_for_master(master_uri(), master_timeout)
    init_node_within(node_name, master_timeout)
    picker.warm_up()
    from binpick.sim.catalogue import Catalogue

    requests = PlanRequests.with_catalogue(picker, Catalogue(library) if library is not None else None)
    node = PickNode(requests, camera_to_base, base_frame, namespace, topics, camera_frame)
    rospy.loginfo("binpick: planning picks at %s from %s, %s, %s", namespace, topics.colour, topics.depth, topics.info)
    try:
        rospy.spin()
    finally:
        node.stop()
        print(node.guard.summary(), file=sys.stderr, flush=True)

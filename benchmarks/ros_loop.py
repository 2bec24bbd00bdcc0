"""The whole pick loop over ROS on 127.0.0.1: the simulator plays the robot's camera and arm, the
binpick pick-planning node plans. For each order the simulator settles a bin, publishes its colour,
depth and camera_info, asks the node to plan (goal: the product id), executes the returned grasp
poses in MuJoCo until one places the product in the order tote, and records the round trip.

    python benchmarks/ros_loop.py --ros 1 [--orders 10] [--seed 0] [--json out.json]
    python benchmarks/ros_loop.py --ros 2 ...   # in the ROS 2 interpreter, inside `unshare -n`

The node runs as a separate process (`binpick ros pick-node` / `binpick ros2 pick-node`) started
here; ROS 1's master too. With --launch the node starts as a user starts it: ROS 1 through roslaunch
and ros/binpick's launch file, ROS 2 from ros/ros2's parameter file, each with the shipped parameter
file (only the camera swapped for the simulator's); the markers, grasp poses and tf it publishes are
counted, and the example client (ros/.../plan_client.py) asks for one more plan at the end. Prints one
JSON line: orders, placed, latency_ms {median, p95}.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
ROOT = Path(__file__).resolve().parents[1]
PRODUCTS = ("robosuite/milk", "robosuite/bottle", "robosuite/can", "pybullet/duck", "procedural/box_03")


def launch_parameters(shipped: Path, camera_yaml: Path, out: Path) -> Path:
    """The shipped parameter file with the simulator's camera.yaml in place of the sample's."""
    import yaml

    data = yaml.safe_load(shipped.read_text())
    inner = next(iter(data.values()))["ros__parameters"] if len(data) == 1 else data
    inner["camera"] = str(camera_yaml.resolve())
    out.write_text(yaml.safe_dump(data))
    return out


def run_client(command: list[str], env: dict | None, timeout: float) -> dict:
    """The example client's answer: its exit code and the number of grasps it printed."""
    ran = subprocess.run(command, env=env, capture_output=True, text=True, timeout=timeout + 60)
    lines = ran.stdout.strip().splitlines()
    answer = json.loads(lines[-1]) if ran.returncode == 0 and lines else {}
    return {"returncode": ran.returncode, "grasps": len(answer.get("grasps", [])), "frame": answer.get("frame"),
            "stderr": ran.stderr[-300:] if ran.returncode else ""}


class Ros1:
    """A master, the node (a child process) and this process's publishers and action client."""

    def __init__(self, camera_yaml: Path, node_args: list[str], timeout: float, launch: bool = False) -> None:
        from binpick.integrations.ros1.master import RosMaster

        self.master = RosMaster()
        os.environ.update({k: v for k, v in self.master.environment.items() if k.startswith("ROS_")})
        self.environment = dict(self.master.environment)
        if launch:  # as a user: roslaunch finds the binpick package on ROS_PACKAGE_PATH; its node script runs this venv's python
            params = launch_parameters(ROOT / "ros" / "binpick" / "config" / "pick_node.yaml", camera_yaml,
                                       camera_yaml.with_name("pick_node.yaml"))
            self.environment |= {"ROS_PACKAGE_PATH": str(ROOT / "ros"),
                                 "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
            command = ["roslaunch", "--wait", "binpick", "pick_node.launch", f"params:={params}", f"node_args:={' '.join(node_args)}"]
        else:
            command = [sys.executable, "-c", "from binpick.cli import main; main()", "ros", "pick-node",
                       "--camera", str(camera_yaml), "--master", self.master.uri, *node_args]
        self.node = subprocess.Popen(command, env=self.environment, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        import actionlib
        import geometry_msgs.msg
        import rospy
        import sensor_msgs.msg
        import tf2_msgs.msg
        import visualization_msgs.msg

        from binpick.integrations.ros1.client import init_node_once
        from binpick.integrations.ros1.messages import plan_pick_action_types

        init_node_once("binpick_sim_camera", timeout)
        self.rospy, self.actionlib, self.msgs = rospy, actionlib, sensor_msgs.msg
        self.types = plan_pick_action_types()
        self.publishers = {name: rospy.Publisher(topic, kind, queue_size=2) for name, topic, kind in (
            ("colour", "/camera/color/image_raw", sensor_msgs.msg.Image),
            ("depth", "/camera/aligned_depth_to_color/image_raw", sensor_msgs.msg.Image),
            ("info", "/camera/color/camera_info", sensor_msgs.msg.CameraInfo))}
        self.overlays: list[tuple[int, int]] = []  # (width, height) of each overlay image the node published
        rospy.Subscriber("/binpick/plan_pick/overlay", sensor_msgs.msg.Image, lambda m: self.overlays.append((m.width, m.height)))
        import std_msgs.msg

        self.dropped: dict[str, int] = {}
        rospy.Subscriber("/binpick/plan_pick/dropped", std_msgs.msg.String, lambda m: self.dropped.update(json.loads(m.data)))
        self.errors: dict[str, int] = {}
        rospy.Subscriber("/binpick/plan_pick/errors", std_msgs.msg.String, lambda m: self.errors.update(json.loads(m.data)))
        self.shown = Shown()
        rospy.Subscriber("/binpick/plan_pick/markers", visualization_msgs.msg.MarkerArray, self.shown.on_markers)
        rospy.Subscriber("/binpick/plan_pick/grasps", geometry_msgs.msg.PoseArray, self.shown.on_poses)
        rospy.Subscriber("/tf", tf2_msgs.msg.TFMessage, self.shown.on_tf)
        rospy.Subscriber("/tf_static", tf2_msgs.msg.TFMessage, self.shown.on_tf_static)
        self.client = actionlib.ActionClient("/binpick/plan_pick", self.types["PlanPickAction"])
        deadline = time.monotonic() + timeout
        while not self.client.wait_for_server(rospy.Duration(1.0)):
            if self.node.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the pick node did not come up: {self.output()}")

    def output(self) -> str:
        if self.node.poll() is None:
            return "(still running)"
        return (self.node.stdout.read() or "")[-2000:]

    def publish(self, rgb, depth_mm, K, stamp: float) -> None:
        from binpick.picking.node import image_fields

        now = self.rospy.Time.from_sec(stamp)
        colour = self.msgs.Image(**image_fields(rgb, "rgb8"))
        depth = self.msgs.Image(**image_fields(depth_mm, "16UC1"))
        info = self.msgs.CameraInfo(width=rgb.shape[1], height=rgb.shape[0], distortion_model="plumb_bob", D=[0.0] * 5,
                                    K=[float(v) for v in K.ravel()])
        for message in (colour, depth, info):
            message.header.stamp, message.header.frame_id = now, "camera_color_optical_frame"
        self.publishers["colour"].publish(colour)
        self.publishers["depth"].publish(depth)
        self.publishers["info"].publish(info)

    def plan(self, product_id: str, timeout: float, photo=None, size=None, query_box=None) -> dict:
        done = threading.Event()

        def on_transition(handle) -> None:
            if handle.get_comm_state() == self.actionlib.CommState.DONE:
                done.set()

        goal = self.types["PlanPickGoal"](product_id=product_id, size=list(size or []), query_box=list(query_box or []))
        if photo is not None:
            from binpick.picking.node import image_fields

            for key, value in image_fields(photo, "rgba8" if photo.shape[2] == 4 else "rgb8").items():
                setattr(goal.photo, key, value)
        handle = self.client.send_goal(goal, transition_cb=on_transition)
        if not done.wait(timeout):
            handle.cancel()
            raise RuntimeError(f"no PlanPick result within {timeout:g} s")
        if handle.get_goal_status() != self.actionlib.GoalStatus.SUCCEEDED:
            raise RuntimeError(f"PlanPick failed: {handle.get_goal_status_text()}")
        result = handle.get_result()
        plans = json.loads(result.plans_json)
        poses = [[g.pose.position.x, g.pose.position.y, g.pose.position.z, g.pose.orientation.x, g.pose.orientation.y,
                  g.pose.orientation.z, g.pose.orientation.w] for g in result.grasps]
        return {"plans": plans, "poses": poses, "frame": result.grasps[0].header.frame_id if result.grasps else plans["frame"]}

    def publish_raw(self, topic: str, fields: dict, stamp: float) -> None:
        """One camera message with the given fields, as a broken or hostile publisher would send it."""
        kind = self.msgs.CameraInfo if topic == "info" else self.msgs.Image
        message = kind(**{("K" if k == "k" else "D" if k == "d" else k): v for k, v in fields.items()})
        message.header.stamp, message.header.frame_id = self.rospy.Time.from_sec(stamp), "camera_color_optical_frame"
        self.publishers[topic].publish(message)

    def raw_goal(self, fields: dict, timeout: float) -> dict:
        """Send a goal with the given fields (``photo``: Image fields); its status and text."""
        done = threading.Event()
        photo = fields.pop("photo", None)
        goal = self.types["PlanPickGoal"](**fields)
        for key, value in (photo or {}).items():
            setattr(goal.photo, key, value)
        handle = self.client.send_goal(goal, transition_cb=lambda h: done.set() if h.get_comm_state() == self.actionlib.CommState.DONE else None)
        if not done.wait(timeout):
            return {"status": "no answer", "text": ""}
        status = handle.get_goal_status()
        return {"status": "succeeded" if status == self.actionlib.GoalStatus.SUCCEEDED else "aborted"
                if status == self.actionlib.GoalStatus.ABORTED else str(status), "text": handle.get_goal_status_text()}

    def close(self) -> None:
        self.client = None
        self.node.terminate()
        try:
            self.node.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.node.kill()
        self.master.stop()


class Shown:
    """What the node published beside its answers: marker arrays (and their markers, DELETEALL left
    out), grasp pose arrays (and poses), tf frames of grasps, static transforms (the camera's)."""

    def __init__(self) -> None:
        self.counts = {"marker_arrays": 0, "markers": 0, "pose_arrays": 0, "poses": 0, "grasp_frames": 0, "static_frames": []}

    def on_markers(self, message) -> None:
        self.counts["marker_arrays"] += 1
        self.counts["markers"] += sum(1 for m in message.markers if m.action == 0)

    def on_poses(self, message) -> None:
        self.counts["pose_arrays"] += 1
        self.counts["poses"] += len(message.poses)

    def on_tf(self, message) -> None:
        self.counts["grasp_frames"] += sum(1 for t in message.transforms if t.child_frame_id.startswith("binpick_grasp_"))

    def on_tf_static(self, message) -> None:
        self.counts["static_frames"] += [f"{t.header.frame_id}->{t.child_frame_id}" for t in message.transforms]


def interfaces() -> list[str]:
    """This network namespace's interfaces (/proc/net/dev)."""
    return [line.split(":")[0].strip() for line in Path("/proc/net/dev").read_text().splitlines()[2:]]


class Ros2:
    """The node (a child process) and this process's rclpy publishers and result subscription, inside a
    network namespace that has only loopback (checked: DDS cannot reach another address)."""

    def __init__(self, camera_yaml: Path, node_args: list[str], timeout: float, launch: bool = False) -> None:
        if interfaces() != ["lo"]:
            raise RuntimeError(f"ROS 2 runs only inside a namespace with just loopback (unshare -n); here: {interfaces()}")
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.environment = None
        if launch:  # as a user: the node from the shipped ROS 2 parameter file
            params = launch_parameters(ROOT / "ros" / "ros2" / "pick_node.yaml", camera_yaml, camera_yaml.with_name("pick_node.yaml"))
            given = ["--params", str(params)]
        else:
            given = ["--camera", str(camera_yaml)]
        self.node = subprocess.Popen([sys.executable, "-c", "from binpick.cli import main; main()", "ros2", "pick-node",
                                      *given, *node_args],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        import geometry_msgs.msg
        import rclpy
        import visualization_msgs.msg
        from rclpy.qos import DurabilityPolicy, QoSProfile
        import rclpy.executors
        import rclpy.node
        import sensor_msgs.msg
        import std_msgs.msg
        from rclpy.qos import qos_profile_sensor_data

        from binpick.integrations.ros2.pick_node import image_message

        self.rclpy, self.msgs, self.std, self.image_message = rclpy, sensor_msgs.msg, std_msgs.msg, image_message
        rclpy.init()
        self.client = rclpy.node.Node("binpick_sim_camera")
        self.publishers = {name: self.client.create_publisher(kind, topic, qos_profile_sensor_data) for name, topic, kind in (
            ("colour", "/camera/color/image_raw", sensor_msgs.msg.Image),
            ("depth", "/camera/aligned_depth_to_color/image_raw", sensor_msgs.msg.Image),
            ("info", "/camera/color/camera_info", sensor_msgs.msg.CameraInfo))}
        self.goal = self.client.create_publisher(std_msgs.msg.String, "/binpick/plan_pick/goal", 10)
        self.goal_photo = self.client.create_publisher(sensor_msgs.msg.Image, "/binpick/plan_pick/goal_photo", 10)
        self.answers: dict[str, dict] = {}
        self.answered = threading.Condition()

        def on_result(message) -> None:
            answer = json.loads(message.data)
            with self.answered:
                self.answers[answer.get("id", "")] = answer
                self.answered.notify_all()

        self.client.create_subscription(std_msgs.msg.String, "/binpick/plan_pick/result", on_result, 10)
        self.overlays: list[tuple[int, int]] = []
        self.client.create_subscription(sensor_msgs.msg.Image, "/binpick/plan_pick/overlay",
                                        lambda m: self.overlays.append((m.width, m.height)), 1)
        self.dropped: dict[str, int] = {}
        self.client.create_subscription(std_msgs.msg.String, "/binpick/plan_pick/dropped",
                                        lambda m: self.dropped.update(json.loads(m.data)), 10)
        self.errors: dict[str, int] = {}
        self.client.create_subscription(std_msgs.msg.String, "/binpick/plan_pick/errors",
                                        lambda m: self.errors.update(json.loads(m.data)), 10)
        self.shown = Shown()
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.client.create_subscription(visualization_msgs.msg.MarkerArray, "/binpick/plan_pick/markers", self.shown.on_markers, latched)
        self.client.create_subscription(geometry_msgs.msg.PoseArray, "/binpick/plan_pick/grasps", self.shown.on_poses, 10)
        self.client.create_subscription(geometry_msgs.msg.TransformStamped, "/binpick/plan_pick/camera_pose",
                                        lambda m: self.shown.counts["static_frames"].append(f"{m.header.frame_id}->{m.child_frame_id}"),
                                        latched)
        self.executor = rclpy.executors.SingleThreadedExecutor()
        self.executor.add_node(self.client)
        self.spinner = threading.Thread(target=self.executor.spin, daemon=True)
        self.spinner.start()
        deadline = time.monotonic() + timeout
        while (self.goal.get_subscription_count() == 0 or self.goal_photo.get_subscription_count() == 0
               or self.client.count_publishers("/binpick/plan_pick/result") == 0):
            if self.node.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the ROS 2 pick node did not come up: {self.output()}")
            time.sleep(0.1)
        self.requests = 0

    def output(self) -> str:
        if self.node.poll() is None:
            return "(still running)"
        return (self.node.stdout.read() or "")[-2000:]

    def publish(self, rgb, depth_mm, K, stamp: float) -> None:
        from builtin_interfaces.msg import Time

        now = Time(sec=int(stamp), nanosec=int(1e9 * (stamp % 1)))
        frame = "camera_color_optical_frame"
        info = self.msgs.CameraInfo(width=rgb.shape[1], height=rgb.shape[0], distortion_model="plumb_bob", d=[0.0] * 5,
                                    k=[float(v) for v in K.ravel()])
        info.header.stamp, info.header.frame_id = now, frame
        self.publishers["colour"].publish(self.image_message(rgb, "rgb8", now, frame))
        self.publishers["depth"].publish(self.image_message(depth_mm, "16UC1", now, frame))
        self.publishers["info"].publish(info)

    def plan(self, product_id: str, timeout: float, photo=None, size=None, query_box=None) -> dict:
        self.requests += 1
        request = f"r{self.requests}"
        if query_box is not None:
            self.goal.publish(self.std.String(data=json.dumps({"id": request, "query_box": list(query_box)})))
        elif photo is None:
            self.goal.publish(self.std.String(data=json.dumps({"id": request, "product_id": product_id})))
        else:
            header = json.dumps({"id": request, "size": list(size or [])})
            self.goal_photo.publish(self.image_message(photo, "rgba8" if photo.shape[2] == 4 else "rgb8", frame_id=header))
        with self.answered:
            if not self.answered.wait_for(lambda: request in self.answers, timeout):
                raise RuntimeError(f"no plan result within {timeout:g} s")
            answer = self.answers.pop(request)
        if answer["status"] != "succeeded":
            raise RuntimeError(f"plan failed: {answer['text']}")
        poses = [g["position"] + g["orientation"] for g in answer["grasps"]]
        return {"plans": answer["plans"], "poses": poses, "frame": answer["frame"]}

    def publish_raw(self, topic: str, fields: dict, stamp: float) -> None:
        """One camera message with the given fields, as a broken or hostile publisher would send it."""
        import array as array_

        from builtin_interfaces.msg import Time

        kind = self.msgs.CameraInfo if topic == "info" else self.msgs.Image
        values = dict(fields)
        if "data" in values:
            values["data"] = array_.array("B", values["data"])
        message = kind(**values)
        message.header.stamp, message.header.frame_id = Time(sec=int(stamp), nanosec=int(1e9 * (stamp % 1))), "camera_color_optical_frame"
        self.publishers[topic].publish(message)

    def raw_goal(self, fields: dict, timeout: float) -> dict:
        """Send a goal: ``{"json": text}`` on the goal topic or ``{"photo": Image fields, "frame_id": ...}``
        on the photo topic; the answer addressed to ``fields["id"]`` (or to no id)."""
        import array as array_

        request = fields.get("id", "")
        with self.answered:
            self.answers.pop(request, None)
        if "json" in fields:
            self.goal.publish(self.std.String(data=fields["json"]))
        else:
            photo = dict(fields["photo"])
            photo["data"] = array_.array("B", photo.get("data", b""))
            message = self.msgs.Image(**photo)
            message.header.frame_id = fields.get("frame_id", request)
            self.goal_photo.publish(message)
        with self.answered:
            if not self.answered.wait_for(lambda: request in self.answers, timeout):
                return {"status": "no answer", "text": ""}
            return self.answers.pop(request)

    def close(self) -> None:
        self.node.terminate()
        try:
            self.node.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.node.kill()
        self.executor.shutdown()
        self.client.destroy_node()
        self.rclpy.try_shutdown()


def hostile_camera_messages(width: int, height: int, K) -> list[tuple[str, str, dict]]:
    """(case, topic, fields) of camera messages a broken driver or an attacker sends: each must be
    dropped with a warning while the node keeps serving."""
    K = [float(v) for v in K.ravel()]
    good_info = {"width": width, "height": height, "distortion_model": "plumb_bob", "d": [0.0] * 5, "k": K}
    row = width * 3
    return [
        ("colour: unknown encoding", "colour", {"encoding": "yuv422", "height": height, "width": width, "step": width * 2,
                                                "data": bytes(width * 2 * height)}),
        ("colour: data shorter than height x step", "colour", {"encoding": "rgb8", "height": height, "width": width, "step": row,
                                                               "data": bytes(row)}),
        ("colour: zero size", "colour", {"encoding": "rgb8", "height": 0, "width": 0, "step": 0, "data": b""}),
        ("colour: step shorter than a row", "colour", {"encoding": "rgb8", "height": 2, "width": 4, "step": 3, "data": bytes(6)}),
        ("colour: 100000 x 100000 declared, 12 bytes sent", "colour", {"encoding": "rgb8", "height": 100_000, "width": 100_000,
                                                                       "step": 300_000, "data": bytes(12)}),
        ("colour: step 4 GB", "colour", {"encoding": "rgb8", "height": 1, "width": 1, "step": 4_000_000_000, "data": bytes(3)}),
        ("depth: a colour encoding", "depth", {"encoding": "rgb8", "height": height, "width": width, "step": row, "data": bytes(row * height)}),
        ("depth: unknown encoding", "depth", {"encoding": "16SC1", "height": height, "width": width, "step": width * 2,
                                              "data": bytes(width * 2 * height)}),
        ("camera_info: K all zero", "info", {**good_info, "k": [0.0] * 9}),
        ("camera_info: unknown distortion model", "info", {**good_info, "distortion_model": "kannala_brandt_9"}),
        ("camera_info: 3 distortion numbers for plumb_bob", "info", {**good_info, "d": [0.1, 0.0, 0.0]}),
        ("camera_info: width 0", "info", {**good_info, "width": 0}),
        ("camera_info: NaN in K", "info", {**good_info, "k": [float("nan")] + K[1:]}),
        ("camera_info: focal length 1e-6", "info", {**good_info, "k": [1e-6, 0.0, K[2], 0.0, 1e-6, K[5], 0.0, 0.0, 1.0]}),
        ("camera_info: last row of K not 0 0 1", "info", {**good_info, "k": K[:6] + [1.0, 1.0, 1.0]}),
        ("camera_info: infinite distortion", "info", {**good_info, "d": [float("inf"), 0.0, 0.0, 0.0, 0.0]}),
    ]


def hostile_goals(version: int, width: int, height: int) -> list[tuple[str, dict]]:
    """(case, goal) of goals that must each be answered with an aborted result naming the problem."""
    photo_ok = {"encoding": "rgb8", "height": 8, "width": 8, "step": 24, "data": bytes(192)}
    bad_photos = [("photo: unknown encoding", {**photo_ok, "encoding": "yuv422"}),
                  ("photo: data shorter than height x step", {**photo_ok, "data": bytes(20)}),
                  ("photo: 100000 x 100000 declared", {**photo_ok, "height": 100_000, "width": 100_000, "step": 300_000}),
                  ("photo: width 0 with data", {**photo_ok, "width": 0, "step": 0})]
    if version == 1:
        return [
            ("max_grasps -1", {"product_id": "robosuite/can", "max_grasps": -1}),
            ("max_grasps 2^31 - 1", {"product_id": "robosuite/can", "max_grasps": 2**31 - 1}),
            ("size NaN", {"product_id": "robosuite/can", "size": [float("nan")] * 3}),
            ("size infinite", {"product_id": "robosuite/can", "size": [float("inf"), 0.1, 0.1]}),
            ("size of 2 numbers", {"product_id": "robosuite/can", "size": [0.1, 0.1]}),
            ("size negative", {"product_id": "robosuite/can", "size": [-0.1, 0.1, 0.1]}),
            ("query_box NaN", {"query_box": [float("nan")] * 4}),
            ("query_box of 3 numbers", {"query_box": [1.0, 2.0, 3.0]}),
            ("query_box off the image", {"query_box": [width * 10.0, height * 10.0, 20.0, 20.0]}),
            ("query_box of zero size", {"query_box": [10.0, 10.0, 0.0, 0.0]}),
            ("query_box infinite", {"query_box": [0.0, 0.0, float("inf"), 10.0]}),
            ("product unknown", {"product_id": "no/such/product"}),
            ("nothing asked", {}),
            ("product id 10,000 characters", {"product_id": "x" * 10_000}),
            ("product id with a NUL", {"product_id": "robosuite/can\x00"}),
            *[(name, {"photo": photo}) for name, photo in bad_photos],
            ("photo and query box both", {"photo": photo_ok, "query_box": [1.0, 1.0, 5.0, 5.0]}),
        ]
    deep = "[" * 100_000 + "]" * 100_000
    cases = [
        ("not JSON", {"json": "plan the can please"}),
        ("a JSON list", {"json": "[1, 2]"}),
        ("nested 100,000 deep", {"json": deep}),
        ("nested 100,000 deep inside an object", {"json": '{"id": "d", "size": ' + deep + "}"}),  # too long to read its id
        ("max_grasps Infinity", {"json": '{"id": "h1", "product_id": "robosuite/can", "max_grasps": Infinity}', "id": "h1"}),
        ("max_grasps 1e400", {"json": '{"id": "h2", "product_id": "robosuite/can", "max_grasps": 1e400}', "id": "h2"}),
        ("max_grasps -1", {"json": '{"id": "h3", "product_id": "robosuite/can", "max_grasps": -1}', "id": "h3"}),
        ("max_grasps a string", {"json": '{"id": "h4", "product_id": "robosuite/can", "max_grasps": "5"}', "id": "h4"}),
        ("max_grasps true", {"json": '{"id": "h5", "product_id": "robosuite/can", "max_grasps": true}', "id": "h5"}),
        ("max_grasps a 5,000-digit number", {"json": '{"id": "h6", "product_id": "robosuite/can", "max_grasps": ' + "9" * 5000 + "}"}),
        ("size a string", {"json": '{"id": "h7", "product_id": "robosuite/can", "size": "123"}', "id": "h7"}),
        ("size NaN", {"json": '{"id": "h8", "product_id": "robosuite/can", "size": [NaN, 0.1, 0.1]}', "id": "h8"}),
        ("query_box of 2 numbers", {"json": '{"id": "h9", "query_box": [1, 2]}', "id": "h9"}),
        ("query_box NaN", {"json": '{"id": "h10", "query_box": [NaN, 1, 5, 5]}', "id": "h10"}),
        ("query_box off the image", {"json": json.dumps({"id": "h11", "query_box": [width * 10, height * 10, 20, 20]}), "id": "h11"}),
        ("copies_only a string", {"json": '{"id": "h12", "query_box": [10, 10, 50, 50], "copies_only": "yes"}', "id": "h12"}),
        ("product unknown", {"json": '{"id": "h13", "product_id": "no/such/product"}', "id": "h13"}),
        ("nothing asked", {"json": '{"id": "h14"}', "id": "h14"}),
        ("unknown field", {"json": '{"id": "h15", "product_id": "robosuite/can", "max_grasp": 3}', "id": "h15"}),
        ("id a number", {"json": '{"id": 7, "product_id": "robosuite/can", "max_grasps": -5}'}),
        ("a megabyte of text", {"json": '{"id": "' + "x" * 1_000_000 + '"}'}),
        *[(name, {"photo": photo, "id": f"p{i}"}) for i, (name, photo) in enumerate(bad_photos)],
        ("photo with a header that is not JSON", {"photo": photo_ok, "frame_id": "{not json", "id": ""}),
    ]
    return cases


def run_hostile(ros, version: int, rgb, K, stamp: float, timeout: float) -> dict:
    """Every hostile camera message, then every hostile goal, into the running node; what came back."""
    height, width = rgb.shape[:2]
    camera = hostile_camera_messages(width, height, K)

    def on_camera(counts: dict[str, int]) -> int:
        return sum(n for topic, n in dict(counts).items() if topic.startswith("/camera/"))  # (a copy: the subscriber updates it)

    def counted() -> int:
        return on_camera(ros.dropped) + on_camera(ros.errors)

    for index, (_, topic, fields) in enumerate(camera):
        # one message at a time, the next only once the node has counted this one (refused or failed): the sensor
        # topics are best effort with shallow queues, and on a loaded machine messages sent 0.2 s apart were lost
        # before the node's callback saw them. A message the node never counts stays uncounted (never sent again,
        # so that no count can stand for another message's)
        ros.publish_raw(topic, fields, stamp + 1000 + index)  # stamped away from the good frames: never matched with them
        # the node reports what it dropped twice a second, much later when starved: the next message waits for this
        # one's count (sent while this one still waits in the node's one-message queue, it would replace it)
        deadline = time.monotonic() + 30.0
        while counted() <= index and time.monotonic() < deadline:
            time.sleep(0.05)
    deadline = time.monotonic() + 30.0  # the last count may come late too
    while counted() < len(camera) and time.monotonic() < deadline:
        time.sleep(0.05)
    camera_dropped, camera_errors = on_camera(ros.dropped), on_camera(ros.errors)
    goals = []
    for name, fields in hostile_goals(version, width, height):
        answer = ros.raw_goal(dict(fields), min(timeout, 30.0))
        goals.append({"case": name, "status": answer["status"], "text": str(answer.get("text", ""))[:200]})
    # refused: binpick named what was wrong; internal errors: the node's own code raised (a bug, never a refusal)
    return {"camera_messages": len(camera), "camera_messages_dropped": camera_dropped, "camera_internal_errors": camera_errors,
            "goals": len(goals),
            # answered with binpick's own reason, not an exception's name (a crash caught at the last moment)
            "answered_with_reason": sum(g["status"] == "aborted" and bool(g["text"].strip())
                                        and not re.match(r"[A-Z]\w*(Error|Exception):", g["text"]) for g in goals),
            "node_alive": ros.node.poll() is None, "goal_answers": goals}


def transport(version: int, camera_yaml: Path, node_args: list[str], timeout: float, launch: bool = False):
    return (Ros1 if version == 1 else Ros2)(camera_yaml, node_args, timeout, launch)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ros", type=int, choices=(1, 2), required=True)
    parser.add_argument("--orders", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--products", default=",".join(PRODUCTS))
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds for the node to start and for each plan")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--node-args", default="", help="extra options for the node, e.g. '--grasp analytic'")
    parser.add_argument("--hostile", action="store_true",
                        help="before the first order's goal, send the node every hostile camera message and goal "
                             "(each bad goal must be answered with a reason, the node must keep serving)")
    parser.add_argument("--launch", action="store_true",
                        help="start the node as a user does (ROS 1: roslaunch; ROS 2: its parameter file), count its markers, "
                             "poses and tf, and ask for one more plan with the example client")
    parser.add_argument("--goal", default="photo",
                        help="what each goal gives, cycled over the orders (comma-separated): id (the product; the node "
                             "renders its catalogue photo, once per product), photo (its shop photo) or box (a query box on "
                             "its most visible instance, as a person pointing at it)")
    args = parser.parse_args()
    if args.ros == 2 and interfaces() != ["lo"]:  # before anything is loaded: refuse at once
        raise SystemExit(f"ROS 2 runs only inside a namespace with just loopback (unshare -n); here: {interfaces()}")

    import numpy as np

    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.grasping import GraspPlanner, PinholeCamera
    from binpick.picking import CameraInfo, GraspPlan, write_camera_info
    from binpick.sim import default_library
    from binpick.sim.products import product_dimensions
    from binpick.core.depth import depth_millimetres
    from binpick.warehouse.export import cut_out
    from binpick.warehouse.grasping import Reason
    from binpick.warehouse.orders import OrderResult
    from binpick.warehouse.pipeline import PickPipeline

    products = [p for p in args.products.split(",") if p]
    goals = [g for g in args.goal.split(",") if g]
    if not goals or any(g not in ("id", "photo", "box") for g in goals):
        raise SystemExit(f"--goal takes id, photo and box (comma-separated), got {args.goal!r}")
    # only the world building, settling and execution of the pipeline are used here: the node plans, and the
    # simulated hand carries the tools the node plans for (its --gripper; binpick's default: jaws and a cup)
    from binpick.cli.app import DEFAULT_GRIPPER

    node_args = args.node_args.split()
    gripper = node_args[node_args.index("--gripper") + 1] if "--gripper" in node_args[:-1] else DEFAULT_GRIPPER
    pipeline = PickPipeline(Detector.load(PICKING).network, default_library(), grasp=GraspPlanner("analytic", hand=gripper))
    work = Path(tempfile.mkdtemp(prefix="binpick-ros-loop-"))
    world, rng = pipeline.build_world(products[0], args.seed)
    scene = pipeline.settle(world, rng, args.seed)
    world.close()
    fixed_camera = PinholeCamera.from_record(scene.camera)  # the overhead camera is the same in every bin
    camera_yaml = write_camera_info(CameraInfo(fixed_camera, base_frame="world"), work / "camera.yaml")
    ros = transport(args.ros, camera_yaml, args.node_args.split(), args.timeout, args.launch)
    results, latencies, planning = [], [], []
    hostile = None
    try:
        for order in range(args.orders):
            product, seed = products[order % len(products)], args.seed + order
            world, rng = pipeline.build_world(product, seed)
            try:
                scene = pipeline.settle(world, rng, seed)
                assert np.allclose(PinholeCamera.from_record(scene.camera).camera_to_world, fixed_camera.camera_to_world)
                stamp = time.time()
                depth_mm = depth_millimetres(scene.depth)
                stop = threading.Event()

                def stream() -> None:  # a camera streams: the node matches the three topics by stamp
                    while not stop.is_set():
                        ros.publish(scene.rgb, depth_mm, fixed_camera.K, stamp)
                        stop.wait(0.1)

                streamer = threading.Thread(target=stream, daemon=True)
                streamer.start()
                goal = goals[order % len(goals)]
                if goal == "photo":
                    pipeline.photo(product)  # rendered before the clock starts: a shop system has its photos
                time.sleep(0.3)  # the first frame reaches the node before the goal
                if args.hostile and order == 0:
                    hostile = run_hostile(ros, args.ros, scene.rgb, fixed_camera.K, stamp, args.timeout)
                    print(f"hostile: {hostile['answered_with_reason']}/{hostile['goals']} bad goals answered with a reason, "
                          f"{hostile['camera_messages']} bad camera messages, node alive: {hostile['node_alive']}", file=sys.stderr)
                started = time.perf_counter()
                photo = cut_out(*pipeline.photos_and_masks(product)[0]) if goal == "photo" else None
                size = product_dimensions(pipeline.library[product]) if goal == "photo" else None  # id: the node's catalogue
                box = None
                if goal == "box":
                    pointed = max((i for i in scene.instances if i.product_id == product), key=lambda i: i.visible_fraction)
                    box = [float(v) for v in pointed.bbox]
                answer = ros.plan(product, args.timeout, photo, size, box)
                latencies.append(1000 * (time.perf_counter() - started))
                stop.set()
                streamer.join()
                planning.append(answer["plans"]["timing_ms"]["total"])
                plans = [GraspPlan(**p) for p in answer["plans"]["plans"]]
                for plan, pose in zip([p for p in plans if p.position is not None], answer["poses"]):
                    assert np.allclose(plan.position, pose[:3], atol=1e-5)  # the poses are the plans'
                result = OrderResult(order, product, seed, False, Reason.NO_DETECTION, detections=answer["plans"]["detections"])
                if answer["plans"]["detections"] and not plans:
                    result.reason = Reason.NOT_THE_PRODUCT
                pipeline.execute(world, scene, plans, result)
                results.append(result)
                print(f"order {order}: {product} {'placed' if result.success else result.reason} "
                      f"({latencies[-1]:.0f} ms round trip, {planning[-1]:.0f} ms planning)", file=sys.stderr, flush=True)
            finally:
                world.close()
        time.sleep(0.5)  # the last overlay follows the last result
        overlays = list(ros.overlays)
        example = None
        if args.launch:  # the example client plans once more on the last frame the node holds
            client = ROOT / "ros" / ("binpick/examples/plan_client.py" if args.ros == 1 else "ros2/plan_client.py")
            example = run_client([sys.executable, str(client), "--product", products[0], "--timeout", str(args.timeout)],
                                 getattr(ros, "environment", None), args.timeout)
            time.sleep(0.5)
        alive_at_end = ros.node.poll() is None
    finally:
        ros.close()
    node_log = (ros.node.stdout.read() or "") if ros.node.stdout is not None else ""
    if hostile is not None:
        hostile["tracebacks_in_node_log"] = node_log.count("Traceback")
        hostile["camera_warnings_in_node_log"] = node_log.count("dropped a message on")
        hostile["camera_messages_dropped_at_exit"] = sum(int(n) for n, topic in re.findall(r"binpick: dropped (\d+) messages on (\S+)",
                                                                                            node_log) if topic.startswith("/camera/"))
        first = node_log.find("Traceback")  # the first one, with what the node logged just before it
        print(node_log[max(0, first - 600):first + 2400] if first >= 0 else node_log[-400:], file=sys.stderr)
    summary = {"ros": args.ros, "goal": args.goal, "orders": len(results), "placed": sum(r.success for r in results),
               "pick_success": round(sum(r.success for r in results) / max(1, len(results)), 4),
               "latency_ms": {"median": round(float(np.median(latencies)), 1), "p95": round(float(np.percentile(latencies, 95)), 1)},
               "planning_ms": {"median": round(float(np.median(planning)), 1), "p95": round(float(np.percentile(planning, 95)), 1)},
               "frame": answer["frame"], "outcomes": [str(r.reason) for r in results], "interfaces": interfaces(),
               "overlays": len(overlays), "overlay_size": list(overlays[-1]) if overlays else None,
               **({"launched": True, "shown": ros.shown.counts, "example_client": example} if args.launch else {}),
               **({"hostile": {**hostile, "node_alive_at_end": alive_at_end}} if hostile is not None else {})}
    print(json.dumps(summary), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()

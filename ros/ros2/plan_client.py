#!/usr/bin/env python3
"""Ask binpick's ROS 2 pick node for grasps on a product and print them, best first, with the
pre-grasp pose 10 cm back along the approach.

    .venv-ros2/bin/python ros/ros2/plan_client.py --product robosuite/milk [--namespace /binpick/plan_pick]

The goal is a JSON std_msgs/String on <namespace>/goal, the answer one on <namespace>/result (ROS 2
interface types would need rosidl's build chain; see the node's docstring). Prints one JSON line:
{"frame", "grasps": [{"tool", "position", "orientation", "pre_grasp", "score", "quality", "width"}]};
exits 1 with the node's reason when the goal is aborted.
"""

import argparse
import json
import sys
import time
import uuid

import rclpy
import rclpy.node
import std_msgs.msg

BACK_OFF = 0.10  # m: the pre-grasp pose, back along the approach (the gripper's z)


def pre_grasp(position, orientation, back_off: float = BACK_OFF) -> list[float]:
    """The tool point ``back_off`` back along the gripper's z (its approach), same orientation."""
    x, y, z, w = orientation
    approach = (2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y))  # the rotation's third column
    return [p - back_off * a for p, a in zip(position, approach)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--product", required=True, help="a product id the node's catalogue knows")
    parser.add_argument("--namespace", default="/binpick/plan_pick")
    parser.add_argument("--max-grasps", type=int, default=3)
    parser.add_argument("--timeout", type=float, default=30.0)
    args = parser.parse_args()
    rclpy.init()
    node = rclpy.node.Node("binpick_plan_client")
    request_id = uuid.uuid4().hex[:8]
    answers = []
    node.create_subscription(std_msgs.msg.String, f"{args.namespace}/result",
                             lambda m: answers.extend(a for a in [json.loads(m.data)] if a.get("id") == request_id), 10)
    goals = node.create_publisher(std_msgs.msg.String, f"{args.namespace}/goal", 10)
    deadline = time.monotonic() + args.timeout
    try:
        while goals.get_subscription_count() == 0 or node.count_publishers(f"{args.namespace}/result") == 0:
            if time.monotonic() > deadline:
                print(f"no pick node at {args.namespace} within {args.timeout:g} s", file=sys.stderr)
                return 1
            rclpy.spin_once(node, timeout_sec=0.1)
        goals.publish(std_msgs.msg.String(data=json.dumps({"id": request_id, "product_id": args.product,
                                                           "max_grasps": args.max_grasps})))
        while not answers:
            if time.monotonic() > deadline:
                print(f"no result within {args.timeout:g} s", file=sys.stderr)
                return 1
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        node.destroy_node()
        rclpy.shutdown()
    answer = answers[0]
    if answer["status"] != "succeeded":
        print(f"PlanPick aborted: {answer['text']}", file=sys.stderr)
        return 1
    grasps = [{**{k: g[k] for k in ("tool", "position", "orientation", "score", "quality", "width")},
               "pre_grasp": pre_grasp(g["position"], g["orientation"])} for g in answer["grasps"]]
    print(json.dumps({"frame": answer["frame"], "grasps": grasps}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

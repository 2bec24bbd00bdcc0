#!/usr/bin/env python3
"""Ask binpick's ROS 1 pick node for grasps on a product and print them, best first, with the
pre-grasp pose 10 cm back along the approach: what you hand to MoveIt or franka_ros next.

    python ros/binpick/examples/plan_client.py --product robosuite/milk [--photo shop.png]
        [--namespace /binpick/plan_pick] [--timeout 30]

Prints one JSON line: {"frame", "grasps": [{"tool", "position", "orientation", "pre_grasp", "score",
"quality", "width"}]}; exits 1 with the node's reason when the goal is aborted.
"""

import argparse
import json
import sys

import actionlib
import rospy

from binpick.integrations.ros1.messages import plan_pick_action_types

BACK_OFF = 0.10  # m: the pre-grasp pose, back along the approach (the gripper's z)


def pre_grasp(position, orientation, back_off: float = BACK_OFF) -> list[float]:
    """The tool point ``back_off`` back along the gripper's z (its approach), same orientation."""
    x, y, z, w = orientation
    approach = (2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y))  # the rotation's third column
    return [p - back_off * a for p, a in zip(position, approach)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--product", default="", help="a product id the node's catalogue knows")
    parser.add_argument("--photo", default=None, help="the product's shop photo (PNG/JPEG) instead of an id")
    parser.add_argument("--namespace", default="/binpick/plan_pick")
    parser.add_argument("--max-grasps", type=int, default=3)
    parser.add_argument("--timeout", type=float, default=30.0)
    args = parser.parse_args(rospy.myargv()[1:])
    rospy.init_node("binpick_plan_client", anonymous=True)
    types = plan_pick_action_types()
    client = actionlib.SimpleActionClient(args.namespace, types["PlanPickAction"])
    if not client.wait_for_server(rospy.Duration(args.timeout)):
        print(f"no PlanPick server at {args.namespace} within {args.timeout:g} s", file=sys.stderr)
        return 1
    goal = types["PlanPickGoal"](product_id=args.product, max_grasps=args.max_grasps)
    if args.photo:
        import cv2

        from binpick.picking.node import image_fields

        photo = cv2.cvtColor(cv2.imread(args.photo, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        for key, value in image_fields(photo, "rgb8").items():
            setattr(goal.photo, key, value)
    client.send_goal(goal)
    if not client.wait_for_result(rospy.Duration(args.timeout)):
        print(f"no result within {args.timeout:g} s", file=sys.stderr)
        return 1
    if client.get_state() != actionlib.GoalStatus.SUCCEEDED:
        print(f"PlanPick aborted: {client.get_goal_status_text()}", file=sys.stderr)
        return 1
    result = client.get_result()
    grasps = []
    for pose, tool, score, quality, width in zip(result.grasps, result.tools, result.scores, result.qualities, result.widths):
        position = [pose.pose.position.x, pose.pose.position.y, pose.pose.position.z]
        o = pose.pose.orientation
        orientation = [o.x, o.y, o.z, o.w]
        grasps.append({"tool": tool, "position": position, "orientation": orientation,
                       "pre_grasp": pre_grasp(position, orientation), "score": score,
                       "quality": None if quality != quality else quality, "width": None if width != width else width})
    frame = result.grasps[0].header.frame_id if result.grasps else json.loads(result.plans_json)["frame"]
    print(json.dumps({"frame": frame, "grasps": grasps}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The bridge's ROS action types, ``binpick/Env`` and ``binpick/PlanPick``, generated with genpy at run
time (no catkin).

One action serves both calls a Gymnasium env needs: ``reset`` (with a seed) and ``step`` (an
end-effector delta + gripper command). The result carries the observation, reward and whether the
episode ended. An ``.action`` file expands into seven messages (goal, result and feedback, their
``Action*`` envelopes with header, goal id and status, and the action itself), written out here as
``genaction`` would.
"""

from __future__ import annotations

import functools

GOAL = """string command    # reset | step
int64 seed        # reset: seed of the episode (-1: none)
float32[] action  # step: end-effector delta (x, y, z) and gripper, in [-1, 1]
"""
RESULT = """float64[] observation
float64[] achieved_goal
float64[] desired_goal
float64 reward
bool terminated
bool truncated
string info_json
"""
FEEDBACK = """string state      # what the server is doing: resetting | stepping
"""
SEPARATOR = "=" * 80


PICK_GOAL = """string product_id       # a product in the node's catalogue (its shop photo), or empty
sensor_msgs/Image photo   # or the shop photo itself (rgb8/bgr8); empty: use product_id
int32 max_grasps          # plan this many grasps at most (0: the node's default)
float32[] size            # the product's catalogue dimensions (m, 3 numbers); empty: the catalogue's, or no check
float32[] query_box       # or x, y, w, h (pixels of the colour image) of the instance to pick; empty: none
bool copies_only          # with query_box: plan on the other copies only, not the instance pointed at
"""
PICK_RESULT = """geometry_msgs/PoseStamped[] grasps  # the tool's pose (z along the approach, x across the jaws), best first
string[] tools           # the tool each grasp is for: jaws or suction (the pose is the fingertips' midpoint or the cup's lip)
float32[] scores         # detector scores
float32[] qualities      # predicted success of each grasp
float32[] widths         # the instance's width across the jaws (m; NaN for suction)
float32 opening          # how far to open the jaws (m)
string plans_json        # everything: boxes, product check, rejected candidates, timing
"""
PICK_FEEDBACK = """string state      # planning
"""


def _generate(name: str, goal: str, result: str, feedback: str, dependencies: dict[str, str]) -> dict[str, type]:
    """An ``.action``'s seven messages, generated with genpy at run time (no catkin)."""
    import actionlib_msgs.msg
    import genpy.dynamic
    import std_msgs.msg

    package = "binpick"
    definitions = {
        f"{name}Goal": goal, f"{name}Result": result, f"{name}Feedback": feedback,
        f"{name}ActionGoal": f"Header header\nactionlib_msgs/GoalID goal_id\n{name}Goal goal\n",
        f"{name}ActionResult": f"Header header\nactionlib_msgs/GoalStatus status\n{name}Result result\n",
        f"{name}ActionFeedback": f"Header header\nactionlib_msgs/GoalStatus status\n{name}Feedback feedback\n",
    }
    dependencies = {"std_msgs/Header": std_msgs.msg.Header._full_text,
                    "actionlib_msgs/GoalID": actionlib_msgs.msg.GoalID._full_text,
                    "actionlib_msgs/GoalStatus": actionlib_msgs.msg.GoalStatus._full_text.split(SEPARATOR)[0], **dependencies}
    sections = [f"{SEPARATOR}\nMSG: {package}/{short}\n{text}" for short, text in definitions.items()]
    sections += [f"{SEPARATOR}\nMSG: {full}\n{text}" for full, text in dependencies.items()]
    core = (f"{name}ActionGoal action_goal\n{name}ActionResult action_result\n{name}ActionFeedback action_feedback\n")
    generated = genpy.dynamic.generate_dynamic(f"{package}/{name}Action", core + "\n".join(sections))
    return {full.split("/")[1]: cls for full, cls in generated.items() if full.startswith(f"{package}/")}


@functools.lru_cache(maxsize=1)
def env_action_types() -> dict[str, type]:
    """Message classes by short name: EnvAction, EnvGoal, EnvResult, EnvFeedback, EnvActionGoal, ..."""
    return _generate("Env", GOAL, RESULT, FEEDBACK, {})


@functools.lru_cache(maxsize=1)
def plan_pick_action_types() -> dict[str, type]:
    """``binpick/PlanPick``: goal a product (id or photo), result grasp poses with scores."""
    import geometry_msgs.msg
    import sensor_msgs.msg

    dependencies = {}
    for full, cls in (("sensor_msgs/Image", sensor_msgs.msg.Image), ("geometry_msgs/PoseStamped", geometry_msgs.msg.PoseStamped),
                      ("geometry_msgs/Pose", geometry_msgs.msg.Pose), ("geometry_msgs/Point", geometry_msgs.msg.Point),
                      ("geometry_msgs/Quaternion", geometry_msgs.msg.Quaternion)):
        dependencies[full] = cls._full_text.split(SEPARATOR)[0]
    return _generate("PlanPick", PICK_GOAL, PICK_RESULT, PICK_FEEDBACK, dependencies)

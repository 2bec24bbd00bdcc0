"""The bridge's ROS action type, ``binpick/Env``, generated with genpy at run time (no catkin).

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


@functools.lru_cache(maxsize=1)
def env_action_types() -> dict[str, type]:
    """Message classes by short name: EnvAction, EnvGoal, EnvResult, EnvFeedback, EnvActionGoal, ..."""
    import actionlib_msgs.msg
    import genpy.dynamic
    import std_msgs.msg

    package, name = "binpick", "Env"
    definitions = {
        f"{name}Goal": GOAL, f"{name}Result": RESULT, f"{name}Feedback": FEEDBACK,
        f"{name}ActionGoal": f"Header header\nactionlib_msgs/GoalID goal_id\n{name}Goal goal\n",
        f"{name}ActionResult": f"Header header\nactionlib_msgs/GoalStatus status\n{name}Result result\n",
        f"{name}ActionFeedback": f"Header header\nactionlib_msgs/GoalStatus status\n{name}Feedback feedback\n",
    }
    dependencies = {"std_msgs/Header": std_msgs.msg.Header._full_text,
                    "actionlib_msgs/GoalID": actionlib_msgs.msg.GoalID._full_text,
                    "actionlib_msgs/GoalStatus": actionlib_msgs.msg.GoalStatus._full_text.split(SEPARATOR)[0]}
    sections = [f"{SEPARATOR}\nMSG: {package}/{short}\n{text}" for short, text in definitions.items()]
    sections += [f"{SEPARATOR}\nMSG: {full}\n{text}" for full, text in dependencies.items()]
    core = (f"{name}ActionGoal action_goal\n{name}ActionResult action_result\n{name}ActionFeedback action_feedback\n")
    generated = genpy.dynamic.generate_dynamic(f"{package}/{name}Action", core + "\n".join(sections))
    return {full.split("/")[1]: cls for full, cls in generated.items() if full.startswith(f"{package}/")}

"""A robot arm executing binpick's picks: inverse kinematics with mink, jerk-limited timing with
Ruckig, the arm's controller in the simulator, and the reachability check the picker runs.

    from binpick.arm import MotionPlanner
    planner = MotionPlanner()                    # the Panda beside the bin (binpick.sim.robot_arm)
    reach = planner.reach(centre, yaw)           # reach.reason: None, or why the arm cannot take it
    motion = planner.pick(home, centre, yaw)     # segments approach ... return, each timed
"""

from binpick.arm.kinematics import ArmKinematics
from binpick.arm.motion import REACH_REASONS, MotionPlanner, PickMotion, Reach
from binpick.arm.trajectory import Segment

__all__ = ["ArmKinematics", "MotionPlanner", "PickMotion", "Reach", "REACH_REASONS", "Segment"]

"""Inverse kinematics of the arm in its cell, with mink (differential IK on the MuJoCo model).

Every solve is a sequence of small quadratic programmes (``mink.solve_ik``, solver DAQP): a frame task
puts the gripper at the target pose, a light posture task keeps the arm near a nominal posture (so
nearby targets get nearby solutions, no elbow or wrist flips between them), and the limits keep the
joints in their ranges, their steps within the joint velocity limits, and the links and gripper away
from the table, the bin and the order tote (``mink.CollisionAvoidanceLimit``). A solve that ends with
the gripper off target, or a posture that still touches an obstacle, is reported, not executed.
"""

from __future__ import annotations

from dataclasses import dataclass

import mink
import mujoco
import numpy as np

from binpick.sim.robot_arm import RobotArm, robot_cell_spec

OBSTACLES = ("table", "bin_floor", "bin_wall0", "bin_wall1", "bin_wall2", "bin_wall3",
             "order_floor", "order_wall0", "order_wall1", "order_wall2", "order_wall3")
POSITION_TOLERANCE = 0.002  # m
ORIENTATION_TOLERANCE = 0.02  # rad
# a planned posture nearer an obstacle than this counts as touching it: the arm tracks its targets
# within about 2 mm, so a plan that grazes a tote wall hits it when executed
CLEARANCE = 0.003  # m
STEP = 0.05  # the differential IK's integration step (s)


def top_down_quaternion(yaw: float) -> np.ndarray:
    """The gripper pointing down (its palm up), jaws closing along ``yaw`` about z: w, x, y, z."""
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


@dataclass
class Solution:
    q: np.ndarray  # the arm's joint positions (rad)
    reached: bool  # the gripper is on target within the tolerances
    touching: list[tuple[str, str]]  # (robot geom, obstacle geom) pairs within CLEARANCE at q
    iterations: int

    @property
    def ok(self) -> bool:
        return self.reached and not self.touching


class ArmKinematics:
    """The arm in its cell (arm, table, bin, order tote; no products): IK and collision checks.

    ``solve(position, yaw, start)`` -> :class:`Solution` for the gripper's centre (between the
    fingers) at ``position`` (world m), pointing down, jaws along ``yaw``."""

    def __init__(self, arm: RobotArm | None = None, tote_tilt: tuple[float, float] = (0.0, 0.0)) -> None:
        self.arm = arm or RobotArm()
        self.model = robot_cell_spec(self.arm, tote_tilt).compile()
        self.arm.bind(self.model)
        self.data = mujoco.MjData(self.model)
        self.configuration = mink.Configuration(self.model)
        self.obstacles = {self.model.geom(name).id for name in OBSTACLES}
        # contacts are made (and so seen by ``touching``) within CLEARANCE of the obstacles
        self.model.geom_margin[sorted(self.obstacles)] = CLEARANCE
        # the base stands on the table: its own contact with it is no collision
        self.robot = {int(g) for g in self.arm.geoms if self.model.geom(int(g)).name != self.arm.model.base_geom}
        self.extend = None  # (qpos address, stroke) of a both-hand's cup rod
        if mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, "cup_extend") >= 0:
            joint = self.model.joint("cup_extend")
            self.extend = (int(self.model.jnt_qposadr[joint.id]), float(joint.range[1]))
        self.fingers = [(int(self.model.jnt_qposadr[self.model.joint(name).id]), float(self.model.joint(name).range[1]))
                        for name in ("finger_a", "finger_b") if mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, name) >= 0]
        self.tool = "jaws"
        self.frame = mink.FrameTask("gripper", "body", position_cost=1.0, orientation_cost=1.0)
        self.posture = mink.PostureTask(self.model, cost=1e-3)
        self.nominal = self.full(self.arm.model.nominal)  # the posture solutions stay near it
        self.posture.set_target(self.nominal)
        limits = self.arm.limits
        self.limits = [mink.ConfigurationLimit(self.model),
                       mink.VelocityLimit(self.model, dict(zip(self.arm.joints, limits.velocity))),
                       mink.CollisionAvoidanceLimit(self.model, [(sorted(self.robot), sorted(self.obstacles))],
                                                    minimum_distance_from_collisions=0.005,
                                                    collision_detection_distance=0.03)]

    def use(self, tool: str) -> None:
        """Check collisions with the hand as ``tool`` needs it: on a hand with both tools, the cup pushed
        out below the fingertips for suction, drawn in for the jaws; ``push``: the jaws closed."""
        if tool != getattr(self, "tool", None):
            self.tool = tool
            self.nominal = self.full(self.arm.model.nominal)  # the IK's posture keeps the fingers as the tool holds them
            self.posture.set_target(self.nominal)

    def full(self, q) -> np.ndarray:
        """The cell's configuration vector for arm joints ``q`` (fingers open, closed for a push; the cup rod as the tool
        in use needs it)."""
        vector = np.zeros(self.model.nq)
        vector[self.arm.qpos] = q
        if self.extend is not None and getattr(self, "tool", "jaws") == "suction":
            vector[self.extend[0]] = self.extend[1]
        if getattr(self, "tool", "jaws") == "push":
            for address, closed in self.fingers:
                vector[address] = closed
        return vector

    def solve(self, position, yaw: float, start=None, iterations: int = 150, avoid: bool = True) -> Solution:
        start = self.nominal if start is None else self.full(start)
        self.configuration.update(start)
        target = mink.SE3.from_rotation_and_translation(mink.SO3(top_down_quaternion(yaw)), np.asarray(position, dtype=float))
        self.frame.set_target(target)
        limits = self.limits if avoid else self.limits[:2]
        error = np.full(6, np.inf)
        step = 0
        for step in range(iterations):
            try:
                velocity = mink.solve_ik(self.configuration, [self.frame, self.posture], STEP, "daqp", damping=1e-4, limits=limits)
            except mink.exceptions.NoSolutionFound:  # no step keeps every limit from here (e.g. a start already too near
                break  # an obstacle): the pose is not reached, as when the steps run out, and the caller tries another
            self.configuration.integrate_inplace(velocity, STEP)
            error = self.frame.compute_error(self.configuration)
            if np.linalg.norm(error[:3]) < POSITION_TOLERANCE and np.linalg.norm(error[3:]) < ORIENTATION_TOLERANCE:
                break
        q = self.configuration.q[self.arm.qpos].copy()
        reached = bool(np.linalg.norm(error[:3]) < POSITION_TOLERANCE and np.linalg.norm(error[3:]) < ORIENTATION_TOLERANCE)
        return Solution(q, reached, self.touching(q), step + 1)

    def touching(self, q) -> list[tuple[str, str]]:
        """(robot geom, obstacle geom) pairs nearer each other than :data:`CLEARANCE` at joint positions ``q``."""
        self.data.qpos[:] = self.full(q)
        mujoco.mj_forward(self.model, self.data)
        pairs = set()
        for contact in self.data.contact[:self.data.ncon]:
            a, b = int(contact.geom1), int(contact.geom2)
            if a in self.obstacles:
                a, b = b, a
            if a in self.robot and b in self.obstacles and contact.dist < CLEARANCE:
                pairs.add((self.model.geom(a).name, self.model.geom(b).name))
        return sorted(pairs)

    def gripper_pose(self, q) -> tuple[np.ndarray, np.ndarray]:
        """The gripper's centre (world m) and its rotation matrix at joint positions ``q``."""
        self.data.qpos[:] = self.full(q)
        mujoco.mj_kinematics(self.model, self.data)
        body = self.arm.gripper_body
        return self.data.xpos[body].copy(), self.data.xmat[body].reshape(3, 3).copy()

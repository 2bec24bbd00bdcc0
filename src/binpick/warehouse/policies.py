"""Grasp policies that label pickability (thesis §5.4.4, §6.3: "pickable" is always pickable *by a
policy*): the scripted top-down grasps x and y of :mod:`binpick.sim.gripper`, and the grasp planner's
policies (``analytic``, ``learnt``; :mod:`binpick.grasping`) that choose each grasp from depth alone,
as the pick pipeline does. A planned attempt must hold the product through a carry at the pipeline's
speed, the way the pipeline's picks are judged.
"""

from __future__ import annotations

from dataclasses import replace

from binpick.core.config import did_you_mean
from binpick.core.errors import ConfigError
from binpick.grasping import GraspPlanner, GraspPolicyName, PinholeCamera
from binpick.sim.gripper import POLICIES as SCRIPTED

PLANNED = (GraspPolicyName.ANALYTIC.value, GraspPolicyName.LEARNT.value)


def policy_names() -> list[str]:
    return [*SCRIPTED, *PLANNED]


def check_policies(names: list[str]) -> None:
    unknown = [n for n in names if n not in policy_names()]
    if unknown:
        raise ConfigError(f"unknown grasp policy {unknown[0]!r}{did_you_mean(unknown[0], policy_names())}; "
                          f"choose from {', '.join(policy_names())}")


def make_policies(names: list[str], robot: str = "floating", arm=None, jaws=None) -> list:
    """The labelling policies; with ``robot="panda"`` each policy's grasp is made by the arm (``arm``: the
    :class:`binpick.sim.robot_arm.RobotArm` whose hand the world has; default binpick's own). Planned
    policies plan for ``jaws`` (the hand's; default binpick's own)."""
    check_policies(names)
    policies = [PlannedGrasp(n, jaws) if n in PLANNED else SCRIPTED[n]() for n in names]
    if robot == "floating" or not policies:
        return policies
    from binpick.arm import ArmKinematics, MotionPlanner
    from binpick.sim.gripper import TRIAL_TIMESTEP

    # one cell model for all the policies, with the world's arm and hand (a copy: the kinematics bind it to their own model)
    motion = MotionPlanner(ArmKinematics(replace(arm)) if arm is not None else None, period=TRIAL_TIMESTEP)
    return [ArmGrasp(policy, motion) for policy in policies]


class ArmGrasp:
    """A labelling policy's grasp made by the arm: the policy chooses where (``grasp``), the arm goes
    there from home, descends, closes, lifts and carries (:func:`binpick.warehouse.grasping.arm_lift_test`).
    A grasp the arm cannot reach is not pickable by it."""

    def __init__(self, policy, motion) -> None:
        self.policy, self.motion, self.name = policy, motion, policy.name

    def prepare(self, scene) -> None:
        if hasattr(self.policy, "prepare"):
            self.policy.prepare(scene)

    def attempt(self, world, slot: int, offset: tuple[float, float] = (0.0, 0.0)) -> bool:
        from binpick.warehouse.grasping import arm_lift_test

        grasp = self.policy.grasp(world, slot, offset)
        return grasp is not None and arm_lift_test(world, self.motion, slot, grasp[0], grasp[1])


class PlannedGrasp:
    """The grasp planner as a labelling policy: ``prepare(scene)`` once per scene (depth -> points),
    then ``attempt(world, slot, offset)`` plans the instance's grasp from its box and executes it."""

    def __init__(self, name: str, jaws=None) -> None:
        self.name = name
        self.planner = GraspPlanner.load(name) if jaws is None else GraspPlanner.load(name, gripper=jaws)
        self._scene = None

    def prepare(self, scene) -> None:
        frame = self.planner.frame(scene.depth, PinholeCamera.from_record(scene.camera))
        self._scene = (frame, {i.slot: i.bbox for i in scene.instances})

    def grasp(self, world, slot: int, offset: tuple[float, float] = (0.0, 0.0)):
        """(fingertips' midpoint, jaw yaw, the instance's top) of the planner's grasp from depth, or
        None when nothing is feasible (the pipeline would not try it either)."""
        if self._scene is None:
            raise RuntimeError("PlannedGrasp.prepare(scene) comes before attempt()")
        frame, boxes = self._scene
        chosen = self.planner.choose(frame, boxes[slot]).chosen
        if chosen is None:
            return None
        x, y, z = chosen.position
        return (float(x + offset[0]), float(y + offset[1]), float(z)), float(chosen.yaw), float(chosen.top)

    def attempt(self, world, slot: int, offset: tuple[float, float] = (0.0, 0.0)) -> bool:
        from binpick.sim.gripper import lift_test, trial_timestep

        grasp = self.grasp(world, slot, offset)
        if grasp is None:
            return False
        with trial_timestep(world.model):
            return lift_test(world, slot, *grasp, carry=True)

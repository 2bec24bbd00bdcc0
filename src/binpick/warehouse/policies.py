"""Grasp policies that label pickability (thesis §5.4.4, §6.3: "pickable" is always pickable *by a
policy*): the scripted top-down grasps x and y of :mod:`binpick.sim.gripper`, and the grasp planner's
policies (``analytic``, ``learnt``; :mod:`binpick.grasping`) that choose each grasp from depth alone,
as the pick pipeline does. A planned attempt must hold the product through a carry at the pipeline's
speed, the way the pipeline's picks are judged.
"""

from __future__ import annotations

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


def make_policies(names: list[str]) -> list:
    check_policies(names)
    return [PlannedGrasp(n) if n in PLANNED else SCRIPTED[n]() for n in names]


class PlannedGrasp:
    """The grasp planner as a labelling policy: ``prepare(scene)`` once per scene (depth -> points),
    then ``attempt(world, slot, offset)`` plans the instance's grasp from its box and executes it."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.planner = GraspPlanner.load(name)
        self._scene = None

    def prepare(self, scene) -> None:
        frame = self.planner.frame(scene.depth, PinholeCamera.from_record(scene.camera))
        self._scene = (frame, {i.slot: i.bbox for i in scene.instances})

    def attempt(self, world, slot: int, offset: tuple[float, float] = (0.0, 0.0)) -> bool:
        from binpick.sim.gripper import lift_test, trial_timestep

        if self._scene is None:
            raise RuntimeError("PlannedGrasp.prepare(scene) comes before attempt()")
        frame, boxes = self._scene
        chosen = self.planner.choose(frame, boxes[slot]).chosen
        if chosen is None:
            return False  # nothing feasible: the pipeline would not try it either
        with trial_timestep(world.model):
            x, y, z = chosen.position
            return lift_test(world, slot, (x + offset[0], y + offset[1], z), chosen.yaw, chosen.top, carry=True)

"""A parallel-jaw gripper and the trial grasps that label pickability (thesis §5.4.4, §6.3.1).

The gripper floats free and follows a mocap body through a weld, as the Fetch end effector does in
Gymnasium-Robotics; two slide-jointed fingers are position-controlled. :class:`TopDownGrasp` is
the scripted policy: above the instance's centre, down, close, lift 15 cm, hold 1 s. With jaws
closing along the robot's x-axis it is the thesis's Policy 2, along the y-axis its Policy 1; the
same object can be pickable by one and not the other, which is what ROD learns to prefer.

Any policy that implements :class:`GraspPolicy` (``name`` and ``attempt(world, slot, offset)``), such as a
learnt APRiL policy driving the mocap target, can label data the same way.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Protocol

import mujoco
import numpy as np

from binpick.grippers import Jaws, SuctionCup
from binpick.sim.hand import Hand
from binpick.sim.mjcf import FLOOR_TOP

PARK = (-3.0, 0.0, 0.5)  # the gripper waits out of the camera's view
OPENING = Jaws().opening  # jaw opening when open (m)
LIFT_SUCCESS = 0.10  # the object must rise this much ...
HOLD_SECONDS = 1.0  # ... and stay held this long
CARRY_TRIAL = (0.0, 0.2, 0.5)  # a grasp trial's carry: dx, dy (m) in seconds, the pick pipeline's 0.4 m/s
TRIAL_TIMESTEP = 0.004  # trials step at 4 ms (scenes settle at 2 ms): same pick rates, half the cost
SUCTION_PRESS = SuctionCup().press  # m: a suction pick drives the lip this far past the surface it aims at (the bellows give)



def floating_hand(gripper: str = "jaws", slots: int = 0, jaws: Jaws = Jaws(), cup: SuctionCup = SuctionCup()) -> tuple[str, str]:
    """(worldbody XML, other XML) of the floating hand carrying ``gripper`` (jaws, suction or both; ``jaws``
    and ``cup`` their geometry):
    a free body welded to a mocap target, its fingers' and cup rod's actuators, and, with a cup, one
    inactive suction weld per product slot (``slots`` of them)."""
    from binpick.sim.hand import hand_actuators, hand_contacts, hand_xml, suction_welds

    body = f"""
<body name="gripper_target" mocap="true" pos="{PARK[0]} {PARK[1]} {PARK[2]}"/>
<body name="gripper" pos="{PARK[0]} {PARK[1]} {PARK[2]}">
  <freejoint name="gripper_free"/>
  {hand_xml(gripper, jaws, cup)}
</body>"""
    extra = ('<equality><weld body1="gripper_target" body2="gripper" solref="0.02 1"/></equality>'
             + hand_actuators(gripper, jaws) + hand_contacts(gripper) + (suction_welds(slots) if gripper != "jaws" else ""))
    return body, extra


class GraspPolicy(Protocol):
    name: str

    def attempt(self, world, slot: int, offset: tuple[float, float] = (0.0, 0.0)) -> bool:
        """From the world's current (restored) state, try to pick instance ``slot``; True if held.
        ``offset`` (m, world x and y) shifts the jaws' centre from where the policy puts it."""


class Gripper(Hand):
    """The floating hand inside a :class:`~binpick.sim.bin_scene.BinWorld` model: a :class:`Hand`
    moved by its mocap target."""

    def __init__(self, model: mujoco.MjModel, gripper: str = "jaws", slot_bodies: list[int] | None = None,
                 cup: SuctionCup = SuctionCup()) -> None:
        super().__init__(model, gripper, slot_bodies, cup)
        self.mocap = model.body_mocapid[model.body("gripper_target").id]
        joint = model.joint("gripper_free")
        self.qpos, self.dof = model.jnt_qposadr[joint.id], model.jnt_dofadr[joint.id]

    def teleport(self, data: mujoco.MjData, position, yaw: float) -> None:
        quaternion = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
        data.mocap_pos[self.mocap] = position
        data.mocap_quat[self.mocap] = quaternion
        data.qpos[self.qpos:self.qpos + 3] = position
        data.qpos[self.qpos + 3:self.qpos + 7] = quaternion
        data.qvel[self.dof:self.dof + 6] = 0.0

    def move(self, data: mujoco.MjData, target, seconds: float, close: bool | None = None, on_step=None) -> None:
        """Move the mocap target in a straight line over ``seconds`` (grip on or off if ``close`` is given)."""
        start = data.mocap_pos[self.mocap].copy()
        steps = max(1, int(seconds / self.model.opt.timestep))
        for step in range(steps):
            data.mocap_pos[self.mocap] = start + (np.asarray(target) - start) * (step + 1) / steps
            if close is not None:
                self.command(data, close)
            mujoco.mj_step(self.model, data)
            self.after_step(data)
            if on_step is not None:
                on_step(step)


@contextmanager
def trial_timestep(model: mujoco.MjModel) -> Iterator[None]:
    """Trials step at TRIAL_TIMESTEP; the scene's own (settling) timestep comes back afterwards."""
    settle_timestep = model.opt.timestep
    model.opt.timestep = TRIAL_TIMESTEP
    try:
        yield
    finally:
        model.opt.timestep = settle_timestep


class TopDownGrasp:
    """Scripted top-down grasp with the jaws closing along the robot's ``axis`` ("x" or "y")."""

    def __init__(self, axis: str = "x") -> None:
        if axis not in ("x", "y"):
            raise ValueError(f"grasp axis must be 'x' or 'y', got {axis!r}")
        self.axis, self.name = axis, axis

    def attempt(self, world, slot: int, offset: tuple[float, float] = (0.0, 0.0)) -> bool:
        with trial_timestep(world.model):
            return self._attempt(world, slot, offset)

    def _attempt(self, world, slot: int, offset: tuple[float, float]) -> bool:
        tips, yaw, top = self.grasp(world, slot, offset)
        return lift_test(world, slot, tips, yaw, top)

    def grasp(self, world, slot: int, offset: tuple[float, float] = (0.0, 0.0)) -> tuple[tuple[float, float, float], float, float]:
        """(fingertips' midpoint, jaw yaw, the instance's top): above its centre, the tips a little
        below the centre (but above the floor), so the jaws close across it."""
        centre, top = world.instance_centre_and_top(slot)
        tips = max(FLOOR_TOP + 0.006, min(centre[2] - 0.01, top - 0.02))
        yaw = 0.0 if self.axis == "x" else np.pi / 2
        return (float(centre[0] + offset[0]), float(centre[1] + offset[1]), float(tips)), yaw, top


def lift_test(world, slot: int, tips, yaw: float, top: float | None = None, carry: bool = False,
              tool: str = "jaws") -> bool:
    """A top-down grasp from the world's current state with ``tool``: its point (the fingertips'
    midpoint, or the cup's lip) to ``tips`` (world xyz), jaws closing along ``yaw`` (radians about z),
    grip, lift 15 cm, hold; True if instance ``slot`` rose by LIFT_SUCCESS and stayed. With ``carry``,
    it must also stay through a sideways carry at the pick pipeline's speed (grasps that lift but slip
    on the way to the order tote fail). A suction cup is pressed SUCTION_PRESS into the surface (its
    bellows give). Call it inside ``with trial_timestep(world.model)``."""
    model, data, gripper = world.model, world.data, world.gripper
    body = world.body_ids[slot]
    start_height = data.xipos[body][2]
    gripper.use(data, tool)
    below = gripper.tool_point_below()
    x, y, z = (float(v) for v in tips)
    above = np.array([x, y, (top if top is not None else z) + below + 0.08])
    gripper.teleport(data, above, yaw)
    mujoco.mj_forward(model, data)
    grasp = [x, y, z + below - (SUCTION_PRESS if tool == "suction" else 0.0)]
    gripper.move(data, grasp, 0.3, close=False)
    gripper.move(data, grasp, 0.3, close=True)
    lifted_to = [x, y, z + below + 0.15]
    gripper.move(data, lifted_to, 0.5, close=True)
    try:
        if not data.xipos[body][2] - start_height >= LIFT_SUCCESS / 2:
            return False  # not even half-way up: no need to simulate the hold
        gripper.move(data, lifted_to, HOLD_SECONDS, close=True)
        if carry:
            gripper.move(data, [x + CARRY_TRIAL[0], y + CARRY_TRIAL[1], lifted_to[2]], CARRY_TRIAL[2], close=True)
            gripper.move(data, data.mocap_pos[gripper.mocap].copy(), 0.3, close=True)
        lifted = data.xipos[body][2] - start_height
        return bool(np.isfinite(lifted) and lifted >= LIFT_SUCCESS)
    finally:
        gripper.command(data, False)


POLICIES = {"x": lambda: TopDownGrasp("x"), "y": lambda: TopDownGrasp("y")}


def make_policies(names: list[str]) -> list[GraspPolicy]:
    from binpick.core.config import did_you_mean
    from binpick.core.errors import ConfigError

    unknown = [n for n in names if n not in POLICIES]
    if unknown:
        raise ConfigError(f"unknown grasp policy {unknown[0]!r}{did_you_mean(unknown[0], POLICIES)}; choose from {', '.join(POLICIES)}")
    return [POLICIES[n]() for n in names]

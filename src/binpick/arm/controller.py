"""The arm's controller in the simulator: joint targets (and the trajectory's velocities) every step.

The world steps at its own timestep, each step taking the next row of the segment; the hand grips
(fingers closed, or the vacuum on) through the segments that say so. Contacts between the arm (links, shaft, palm, fingers) and the cell's fixed
things (table, bin, order tote) are counted as collisions while it moves.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

from binpick.arm.kinematics import OBSTACLES
from binpick.arm.trajectory import Segment


class ArmController:
    """Drives ``world.arm`` (a bound :class:`binpick.sim.robot_arm.RobotArm`) along segments."""

    def __init__(self, world) -> None:
        self.world, self.model, self.data, self.arm = world, world.model, world.data, world.arm
        names = {self.model.geom(g).name for g in range(self.model.ngeom)}
        self.fixed = np.array([self.model.geom(n).id for n in OBSTACLES if n in names])
        self.robot = np.array([g for g in self.arm.geoms if self.model.geom(int(g)).name != self.arm.model.base_geom])
        self.collisions: list[tuple[str, str, str]] = []  # (robot geom, fixed geom, segment), once per segment and pair

    def run(self, segment: Segment, on_step: Callable[[], None] | None = None, check_every: int = 1) -> None:
        model, data, arm = self.model, self.data, self.arm
        hand = arm.hand
        seen: set[tuple[str, str]] = set()
        for step, (q, qd) in enumerate(zip(segment.q, segment.qd)):
            data.ctrl[arm.actuators] = q
            data.ctrl[arm.velocity_actuators] = qd
            hand.command(data, segment.closed)
            mujoco.mj_step(model, data)
            hand.after_step(data)
            if step % check_every == 0:
                seen.update(self.touching())
            if on_step is not None:
                on_step()
        self.collisions += [(robot, fixed, segment.name) for robot, fixed in sorted(seen)]

    def touching(self) -> set[tuple[str, str]]:
        count = self.data.ncon
        if not count:
            return set()
        pairs = self.data.contact.geom[:count]
        hits = (np.isin(pairs[:, 0], self.robot) & np.isin(pairs[:, 1], self.fixed)) | \
               (np.isin(pairs[:, 1], self.robot) & np.isin(pairs[:, 0], self.fixed))
        hits &= self.data.contact.dist[:count] < 0
        pairs = [(a, b) if a in self.robot else (b, a) for a, b in pairs[hits].tolist()]
        return {(self.model.geom(a).name, self.model.geom(b).name) for a, b in pairs}

    def tracking_error(self, q) -> float:
        """How far the arm is from posture ``q`` (largest joint error, rad)."""
        return float(np.abs(self.data.qpos[self.arm.qpos] - np.asarray(q)).max())

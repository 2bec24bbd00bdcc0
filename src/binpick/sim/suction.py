"""A suction cup's vacuum in MuJoCo: a seal made only where the lip's ring lies on one product's
surface that is flat enough, and a hold that breaks when the load leaves what the vacuum resists.

Why not MuJoCo's ``adhesion`` actuator: it pulls at whatever contacts the cup has, one point on a ball
or an edge as well as a whole face, so a cup on a sphere or on a box's corner would lift it as well as
on a face. Real cups fail there because no seal forms, and on heavy products held far from their
centre of mass because the seal peels. So the seal is tested geometrically, as Dex-Net 3.0 does on
meshes (rays from the lip's ring onto the product: one object, a ring within ``compliance`` of a
plane, no bulge into the cup, a tilt the bellows follow), and the hold is a weld whose constraint
wrench is checked against the vacuum's limits every step (:class:`binpick.grippers.SuctionCup`).
"""

from __future__ import annotations

import mujoco
import numpy as np

from binpick.grippers import RING, SuctionCup, ring_offsets, seal_test

REACH = 0.03  # m a ray travels from above the lip: it sees the surface from 1.5 cm above the lip to 1.5 cm below
RETRY_EVERY = 5  # steps between seal tests while the vacuum is on and nothing is sealed
OVERLOAD_STEPS = 5  # steps in a row over the vacuum's limits before the seal lets go (about 20 ms)


class Vacuum:
    """The cup's vacuum in a compiled model with :func:`binpick.sim.hand.suction_welds`: ``on`` seals
    where it can, ``step`` keeps the seal while the load stays within the limits (and seals when the
    cup comes onto a surface that seals), ``off`` releases. ``sealed`` is the product slot held."""

    def __init__(self, model: mujoco.MjModel, slot_bodies: list[int], cup: SuctionCup = SuctionCup()) -> None:
        self.model, self.cup = model, cup
        self.body = model.body("cup").id
        self.site = model.site("cup_lip").id
        self.slot_bodies = list(slot_bodies)
        self.welds = [model.equality(f"suction{i}").id for i in range(len(slot_bodies))]
        self.slot_of = {body: slot for slot, body in enumerate(self.slot_bodies)}
        self.groups = np.array([1, 1, 1, 0, 1, 1], np.uint8)  # the hand's own geoms (group 3) are not seen
        self.offsets = ring_offsets(cup.radius)
        self.sealed: int | None = None
        self.active = False
        self.why: str | None = None  # why the last seal test failed, or why the seal let go
        self.peak_load = 0.0  # the largest share of the limits the seal carried (1: at a limit)
        self._over = 0

    # ------------------------------------------------------------------ seal
    def on(self, data: mujoco.MjData) -> None:
        self.active, self._tries = True, 0
        self.seal(data)

    def off(self, data: mujoco.MjData) -> None:
        self.active = False
        if self.sealed is not None:
            data.eq_active[self.welds[self.sealed]] = 0
        self.sealed, self._over = None, 0

    def step(self, data: mujoco.MjData) -> None:
        if not self.active:
            return
        if self.sealed is None:
            self._tries += 1
            if self._tries % RETRY_EVERY == 0:  # the cup may come onto a surface that seals (it keeps the first reason)
                self.seal(data, quiet=True)
        elif self.overloaded(data):
            data.eq_active[self.welds[self.sealed]] = 0
            self.sealed = None
            self.active = False  # it does not seal again on the way (the product has peeled or fallen off)

    def probe(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, int | None]:
        """Heights of the surface under the lip's ring and inside it along the cup's axis (NaN: none
        within reach), whether each lies on the body under the centre, and that body's slot."""
        lip = data.site_xpos[self.site]
        frame = data.site_xmat[self.site].reshape(3, 3)
        axis = frame[:, 2]
        heights = np.full(len(self.offsets), np.nan)
        bodies = np.full(len(self.offsets), -1)
        geom = np.zeros((1, 1), np.int32)
        for i, (x, y) in enumerate(self.offsets):
            start = lip + frame[:, 0] * x + frame[:, 1] * y + axis * (REACH / 2)
            distance = mujoco.mj_ray(self.model, data, start, -axis, self.groups, 1, -1, geom)
            if 0 <= distance <= REACH:
                heights[i] = REACH / 2 - distance
                bodies[i] = self.model.geom_bodyid[geom[0, 0]]
        centre = bodies[RING]
        return heights, bodies == centre, self.slot_of.get(int(centre))

    def seal(self, data: mujoco.MjData, quiet: bool = False) -> bool:
        """Seal where the cup is now if its lip lies on a product that seals (``why`` says why not,
        unless ``quiet``)."""
        mujoco.mj_kinematics(self.model, data)  # positions after the last step's integration
        heights, same, slot = self.probe(data)
        why = "no product under the cup" if slot is None else seal_test(heights, same, self.cup)
        if why is not None:
            self.why = self.why if quiet else why
            return False
        self.why = None
        self.attach(data, slot)
        return True

    def attach(self, data: mujoco.MjData, slot: int) -> None:
        """Weld the cup to the slot's body where both are now (anchored at the lip's centre)."""
        weld = self.welds[slot]
        product = self.slot_bodies[slot]
        lip = data.site_xpos[self.site]
        anchor = data.xmat[product].reshape(3, 3).T @ (lip - data.xpos[product])  # the lip in the product's frame
        relative = data.xmat[self.body].reshape(3, 3).T @ (lip - data.xpos[self.body])  # ... in the cup's
        quaternion = np.zeros(4)
        inverse = np.zeros(4)
        mujoco.mju_negQuat(inverse, data.xquat[self.body])
        mujoco.mju_mulQuat(quaternion, inverse, data.xquat[product])
        self.model.eq_data[weld, 0:3] = anchor
        self.model.eq_data[weld, 3:6] = relative
        self.model.eq_data[weld, 6:10] = quaternion
        self.model.eq_data[weld, 10] = 1.0
        data.eq_active[weld] = 1
        self.sealed, self._over, self.peak_load = slot, 0, 0.0

    # ------------------------------------------------------------------ hold
    def wrench(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """The force and the moment (about the lip's centre, world frame) the seal applies to the
        product it holds, from the weld's constraint forces."""
        weld = self.welds[self.sealed]
        rows = (data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY) & (data.efc_id == weld)
        if not rows.any():
            return np.zeros(3), np.zeros(3)
        force = np.zeros(data.nefc)
        force[rows] = data.efc_force[rows]
        generalised = np.zeros(self.model.nv)
        mujoco.mj_mulJacTVec(self.model, data, generalised, force)
        body = self.slot_bodies[self.sealed]
        dof = self.model.jnt_dofadr[self.model.body_jntadr[body]]
        on_product = generalised[dof:dof + 3]  # world frame
        moment_origin = data.xmat[body].reshape(3, 3) @ generalised[dof + 3:dof + 6]  # about the body's origin
        lip = data.site_xpos[self.site]
        return on_product, moment_origin + np.cross(data.xpos[body] - lip, on_product)

    def load(self, data: mujoco.MjData) -> float:
        """The seal's load as a share of what the vacuum holds (the largest of the pull, shear, peel
        and twist ratios; 1 at the limit)."""
        force, moment = self.wrench(data)
        axis = data.site_xmat[self.site].reshape(3, 3)[:, 2]
        pull = float(force @ axis)  # towards the cup
        shear = float(np.linalg.norm(force - pull * axis))
        twist = float(moment @ axis)
        peel = float(np.linalg.norm(moment - twist * axis))
        cup = self.cup
        pressing = cup.vacuum_force - pull
        if pressing <= 0:
            return float("inf")
        return max(pull / cup.vacuum_force, shear / (cup.friction * pressing), peel / (pressing * cup.radius),
                   abs(twist) / (cup.friction * pressing * cup.radius))

    def overloaded(self, data: mujoco.MjData) -> bool:
        load = self.load(data)
        self.peak_load = max(self.peak_load, load if np.isfinite(load) else 10.0)
        self._over = self._over + 1 if load > 1.0 else 0
        if self._over >= OVERLOAD_STEPS:
            self.why = "the load exceeded the vacuum's hold"
            return True
        return False

"""The hand at the end of the floating gripper or an arm: a palm with two position-controlled
fingers (jaws), a suction cup, or both (the cup on a rod between the fingers, pushed out below the
fingertips for a suction pick and drawn back into the palm for a jaw pick).

The cup rides on a sprung bellows joint, so pressing it onto a surface compresses it rather than
pushing the product away. Its vacuum is :class:`binpick.sim.suction.Vacuum`: a weld to the product
made only when the lip's ring seals, broken when the load leaves what the vacuum holds. Every hand
body keeps the names the arm's kinematics and the picks use (``gripper``, ``finger_a``, ``finger_b``,
``cup``); hand geoms are in geom group 3, which the seal test's rays ignore.
"""

from __future__ import annotations

import mujoco
import numpy as np

from binpick.grippers import TIPS_BELOW, Jaws, SuctionCup, tool_point_below, tools_of

JAWS, CUP = Jaws(), SuctionCup()
HAND_GROUP = 3
PALM_Z = 0.05  # the palm's centre above the hand's origin (the fingers' centre)
PALM_HALF_HEIGHT = 0.012
CUP_HALF_HEIGHT = 0.005  # the cup's body above its lip
BELLOWS = 0.012  # m the bellows compress
RETRACTED = 0.034  # the lip above the hand's origin with the cup drawn into the palm (a hand with both tools): above
# the highest top a jaw grasp lets between the fingers (PALM_REACH under the top: 0.03 above the origin)
FINGER = ('type="box" size="{t} {w} {l}" pos="0 0 {z}" rgba="0.6 0.6 0.62 1" mass="0.04" friction="2 0.02 0.001" '
          'condim="6" priority="1" solref="0.004 1" solimp="0.95 0.99 0.001" group="3"')


def hand_xml(gripper: str, jaws: Jaws = JAWS, cup: SuctionCup = CUP) -> str:
    """The geoms and bodies inside the ``gripper`` body of a hand carrying ``gripper`` (jaws, suction
    or both): palm, fingers (``jaws``: their stroke and size), the cup (``cup``: its lip's radius and
    rubber) on its rod."""
    tools = tools_of(gripper)
    half = jaws.opening / 2
    palm_half_x = half + 0.012 if "jaws" in tools else cup.radius + 0.01
    parts = [f'<geom name="palm" type="box" size="{palm_half_x} 0.014 {PALM_HALF_HEIGHT}" pos="0 0 {PALM_Z}" '
             f'rgba="0.25 0.25 0.28 1" mass="0.4" group="{HAND_GROUP}"/>']
    if "jaws" in tools:
        # the tips at the tool point (TIPS_BELOW under the hand's origin) whatever the fingers' length
        finger = FINGER.format(t=jaws.finger_thickness / 2, w=jaws.finger_width / 2, l=jaws.finger_length / 2,
                               z=round(jaws.finger_length / 2 - TIPS_BELOW, 6))
        for name, sign in (("finger_a", 1), ("finger_b", -1)):
            parts.append(f'<body name="{name}" pos="{sign * (half + jaws.finger_thickness / 2)} 0 0">'
                         f'<joint name="{name}" type="slide" axis="{-sign} 0 0" range="0 {half}" damping="2"/>'
                         f'<geom name="{name}" {finger}/></body>')
    if "suction" in tools:
        extended = tool_point_below(gripper, "suction")
        palm_bottom = PALM_Z - PALM_HALF_HEIGHT
        if gripper == "both":  # the rod slides: lip at RETRACTED (drawn in) down to -extended (pushed out)
            mount, joint = RETRACTED, (f'<joint name="cup_extend" type="slide" axis="0 0 -1" range="0 {RETRACTED + extended}" '
                                       f'damping="20" armature="0.05"/>')
            rod = palm_bottom + extended + 0.02
        else:
            mount, joint, rod = -extended, "", palm_bottom + extended - 2 * CUP_HALF_HEIGHT
        parts.append(
            f'<body name="cup_mount" pos="0 0 {mount}">{joint}'
            f'<geom name="cup_rod" type="cylinder" size="0.006 {rod / 2}" pos="0 0 {2 * CUP_HALF_HEIGHT + rod / 2}" '
            f'rgba="0.5 0.5 0.52 1" mass="0.03" group="{HAND_GROUP}"/>'
            f'<body name="cup"><joint name="bellows" type="slide" axis="0 0 1" range="0 {BELLOWS}" stiffness="400" '
            f'damping="4" springref="0"/>'
            f'<geom name="cup" type="cylinder" size="{cup.radius} {CUP_HALF_HEIGHT}" pos="0 0 {CUP_HALF_HEIGHT}" '
            f'rgba="0.15 0.35 0.75 1" mass="0.02" friction="{cup.friction} 0.02 0.001" condim="4" group="{HAND_GROUP}"/>'
            f'<site name="cup_lip" pos="0 0 0" size="0.004" rgba="1 0 0 0"/></body></body>')
    return "".join(parts)


def hand_actuators(gripper: str, jaws: Jaws = JAWS) -> str:
    """The hand's actuators: each finger's position (over half the jaws' stroke), the cup rod's extension."""
    tools = tools_of(gripper)
    half = jaws.opening / 2
    parts = []
    if "jaws" in tools:
        parts += [f'<position name="{n}" joint="{n}" kp="200" ctrlrange="0 {half}" forcerange="-12 12"/>' for n in ("finger_a", "finger_b")]
    if gripper == "both":
        stroke = RETRACTED + tool_point_below(gripper, "suction")
        parts.append(f'<position name="cup_extend" joint="cup_extend" kp="400" ctrlrange="0 {stroke}" forcerange="-60 60"/>')
    return f"<actuator>{''.join(parts)}</actuator>" if parts else ""


def hand_contacts(gripper: str) -> str:
    """The cup and its rod pass between the fingers and into the palm (they do not touch them)."""
    if gripper != "both":
        return ""
    pairs = [("gripper", "cup"), ("finger_a", "cup"), ("finger_b", "cup"), ("finger_a", "cup_mount"), ("finger_b", "cup_mount")]
    return "<contact>" + "".join(f'<exclude body1="{a}" body2="{b}"/>' for a, b in pairs) + "</contact>"


def suction_welds(slots: int) -> str:
    """One inactive weld from the cup to each product slot: the vacuum turns one on when it seals."""
    welds = "".join(f'<weld name="suction{i}" body1="cup" body2="slot{i}" active="false" solref="0.01 1"/>' for i in range(slots))
    return f"<equality>{welds}</equality>"


class Hand:
    """Handles to a hand in a compiled model, and its commands: which tool a pick uses (the cup rod
    out or in), and grip on or off (fingers closed, or the vacuum on)."""

    def __init__(self, model: mujoco.MjModel, gripper: str, slot_bodies: list[int] | None = None, cup: SuctionCup = CUP) -> None:
        from binpick.sim.suction import Vacuum

        self.model, self.gripper, self.tools = model, gripper, tools_of(gripper)
        self.fingers = [model.actuator(n).id for n in ("finger_a", "finger_b")] if "jaws" in self.tools else []
        self.extend = model.actuator("cup_extend").id if gripper == "both" else None
        self.vacuum = Vacuum(model, slot_bodies or [], cup) if "suction" in self.tools else None
        self.tool = self.tools[0]
        self.closed = False

    def use(self, data: mujoco.MjData, tool: str) -> None:
        """Ready ``tool`` for the next pick: open, vacuum off, the cup pushed out for suction or drawn in."""
        if tool not in self.tools:
            raise ValueError(f"this hand carries {' and '.join(self.tools)}, not {tool}")
        self.command(data, False)  # let go with the tool in use first
        self.tool = tool
        if self.extend is not None:
            stroke = self.model.actuator_ctrlrange[self.extend][1]
            data.ctrl[self.extend] = stroke if tool == "suction" else 0.0
            joint = self.model.actuator_trnid[self.extend][0]
            data.qpos[self.model.jnt_qposadr[joint]] = data.ctrl[self.extend]  # (set, not driven: a pick starts ready)

    def tool_point_below(self) -> float:
        """The current tool's point below the hand's origin (m)."""
        return tool_point_below(self.gripper, self.tool)

    def command(self, data: mujoco.MjData, closed: bool) -> None:
        """Grip (True) or let go: the fingers close or open; the vacuum seals where it can, or releases."""
        if self.tool == "jaws":
            data.ctrl[self.fingers] = self.model.actuator_ctrlrange[self.fingers, 1] if closed else 0.0  # half the stroke: shut
        elif closed and not self.closed:
            self.vacuum.on(data)
        elif not closed and self.closed:
            self.vacuum.off(data)
        self.closed = closed

    def after_step(self, data: mujoco.MjData) -> None:
        """After each simulator step: a vacuum that is on seals where it now can, or lets go when overloaded."""
        if self.vacuum is not None and self.closed and self.tool == "suction":
            self.vacuum.step(data)

    def reset(self, data: mujoco.MjData) -> None:
        """Open, vacuum off and no seal (the state after a scene is restored)."""
        if self.vacuum is not None:
            self.vacuum.off(data)
        if self.fingers:
            data.ctrl[self.fingers] = 0.0
        self.closed = False

    @property
    def held(self) -> int | None:
        """The product slot the vacuum holds (None: none, or jaws)."""
        return self.vacuum.sealed if self.vacuum is not None else None

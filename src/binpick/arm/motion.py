"""A pick's motion for the arm: reachability of a grasp, then every segment from home to the order tote
and back, each solved by inverse kinematics (:mod:`binpick.arm.kinematics`) and timed by Ruckig
(:mod:`binpick.arm.trajectory`).

The segments: ``approach`` (home to 15 cm above the grasp, a free move), ``descend`` (straight down
to the grasp), ``close``, ``lift`` (straight up), ``carry`` (a free move to above the order tote),
``lower``, ``release`` and ``return`` (home, out of the camera's view). Free moves are checked against
the cell's obstacles along their whole sampled path; a free move that would touch one goes up to the
carry height first. The fingertips stop at least :data:`FLOOR_MARGIN` above the cell's bin floor (the
grasp is raised if it asks for less): the arm tracks its targets within about 2 mm, not exactly.

:meth:`MotionPlanner.reach` is the check the picker runs on every grasp before ranking it: a grasp
whose descent has no IK solution, whose arm would touch the tote on the way down, or that would need
the wrist turned over (the fifth joint, the Panda's joint 5 or the UR5e's wrist 2, more than a quarter
turn from the nominal posture: a flip the arm cannot make on the way down), is dropped with its reason.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from binpick.arm.kinematics import ArmKinematics
from binpick.core.errors import ConfigError
from binpick.arm.trajectory import Segment, joint_move, path_move
from binpick.sim.order_tote import ORDER_TOTE, RELEASE_HEIGHT, release_height
from binpick.sim.mjcf import BIN_WALL_HEIGHT, FLOOR_TOP
from binpick.grippers import SuctionCup, tool_point_below
from binpick.sim.robot_arm import RobotArm

BIN_CHECK_HEIGHT = 0.25  # m: a cell's arm must reach this far above the bin's centre, pointing down

NO_IK = "no IK solution"
COLLIDES = "arm collides on the way down"
WRIST_FLIP = "needs a wrist flip"
REACH_REASONS = (NO_IK, COLLIDES, WRIST_FLIP)

APPROACH_HEIGHT = 0.15  # the pre-grasp pose above the grasp (m), as the floating gripper's ...
WALLS_CLEARANCE = 0.05  # ... or higher: the tool's point 5 cm above the bin walls
ABOVE_WALLS = BIN_WALL_HEIGHT + FLOOR_TOP + WALLS_CLEARANCE + tool_point_below("jaws", "jaws")  # the jaws' hand origin there
LINE_STEP = 0.02  # IK points along straight segments (m)
LIFT_TO = 0.32  # the gripper's centre after the lift (at least 15 cm up): products clear the bin walls
CARRY_HEIGHT = 0.42  # the detour height when a free move would touch something
CLOSE_SECONDS, OPEN_SECONDS = 0.35, 0.3  # the fingers closing and opening (the arm stands still)
FLOOR_MARGIN = 0.008  # the tool's point stops at least this far above the cell's bin floor (the arm tracks within 2 mm)
WRIST_TURN = np.pi / 2 + 0.2  # joint 5 or 7 further than this from the nominal posture: a wrist flip


@dataclass
class Reach:
    """Whether the arm can take a grasp: the reason it cannot (None: it can), the jaw yaw it uses
    (the grasp's, or the same jaws turned half a turn), and the descent's postures."""

    reason: str | None
    yaw: float
    descent: list[np.ndarray] = field(default_factory=list)  # postures from the pre-grasp down to the grasp
    seconds: float = 0.0  # time spent solving

    @property
    def ok(self) -> bool:
        return self.reason is None


@dataclass
class PickMotion:
    segments: list[Segment]
    reach: Reach
    planning_s: float  # wall seconds of IK and timing

    def segment(self, name: str) -> Segment:
        return next(s for s in self.segments if s.name == name)

    @property
    def seconds(self) -> dict[str, float]:
        return {s.name: round(s.duration, 3) for s in self.segments}


def line(start, end, step: float = LINE_STEP) -> list[np.ndarray]:
    """Evenly spaced points from ``start`` to ``end`` (both included), about ``step`` apart."""
    start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    count = max(2, int(np.ceil(np.linalg.norm(end - start) / step)) + 1)
    return [start + (end - start) * k / (count - 1) for k in range(count)]


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


class MotionPlanner:
    """``MotionPlanner().reach(centre, yaw)`` and ``.pick(start, centre, yaw)`` for the hand's origin
    (the fingers' centre, world m) at a top-down grasp with the hand's x axis along ``yaw``; ``period``:
    the controller's (the simulator's) step; ``gripper``: the hand's tools (jaws, suction or both), whose
    points lie at their own depths below the origin (``tool`` of each call)."""

    def __init__(self, kinematics: ArmKinematics | None = None, period: float = 0.004, gripper: str = "jaws") -> None:
        self.gripper = gripper
        self.kinematics = kinematics or ArmKinematics(RobotArm(gripper=gripper))
        self.limits = self.kinematics.arm.limits
        self.period = period
        self.home = np.asarray(self.kinematics.arm.home, dtype=float)
        self.nominal = np.asarray(self.kinematics.arm.model.nominal, dtype=float)
        _, rotation = self.kinematics.gripper_pose(self.nominal)
        self.wrist_yaw = float(np.arctan2(rotation[1, 0], rotation[0, 0]))  # the jaws' yaw with the wrist mid-range
        self._answers: dict[tuple, Reach] = {}

    @classmethod
    def for_cell(cls, cell, gripper: str = "jaws", period: float = 0.004, arm: str | None = None) -> MotionPlanner:
        """``arm`` (panda or ur5e; None: the cell's, else the Panda) carrying the hand a cell file describes
        (:class:`binpick.cell.Cell`: its tools, jaws, cup and tool point; None: binpick's own hand carrying ``gripper``)."""
        from binpick.sim.robot_arm import arm_model

        if arm is None:
            arm = cell.arm if cell is not None and cell.arm != "none" else "panda"
        if cell is None:
            return cls(ArmKinematics(RobotArm(arm_model(arm), gripper=gripper)), period=period, gripper=gripper)
        cell.check_arm(arm)
        robot = RobotArm.carrying(arm_model(arm), cell.tools, cell.jaws, cell.cup, cell.tcp, cell.base)
        planner = cls(ArmKinematics(robot), period=period, gripper=cell.tools)
        if cell.base is not None and not planner.kinematics.solve([0.0, 0.0, BIN_CHECK_HEIGHT], 0.0).ok:
            raise ConfigError(f"cell {cell.name!r}: the {arm} with its base at {list(cell.base)} m does not reach {BIN_CHECK_HEIGHT} m "
                              "above the bin's centre, pointing down: move arm.base nearer the bin")
        return planner

    def below(self, tool: str) -> float:
        """The tool's point below the hand's origin."""
        return tool_point_below(self.gripper, tool)

    def reach(self, centre, yaw: float, tool: str = "jaws") -> Reach:
        """Can the arm go straight down onto this grasp? Both jaw directions (yaw and yaw + π close the
        same jaws) are tried, the one nearer the wrist's mid-range first; the answer's ``yaw`` is the
        one the arm takes. The last answers are kept: the picker asks before the pick is executed."""
        started = time.perf_counter()
        self.kinematics.use(tool)
        centre = self.clear_of_floor(np.asarray(centre, dtype=float), tool)
        key = (*np.round(centre, 4), round(float(yaw), 4), tool)
        if key in self._answers:
            return self._answers[key]
        yaws = sorted((yaw, yaw + np.pi), key=lambda y: abs(_wrap(y - self.wrist_yaw)))
        reasons = []
        for option in yaws:
            reach = self._descent(centre, _wrap(option), tool)
            if reach.ok:
                break
            reasons.append(reach.reason)
        else:
            reach = Reach(next(r for r in (COLLIDES, WRIST_FLIP, NO_IK) if r in reasons), yaw)  # the nearest miss
        reach.seconds = time.perf_counter() - started
        self._answers[key] = reach
        while len(self._answers) > 256:
            self._answers.pop(next(iter(self._answers)))
        return reach

    def reach_check(self, tips, yaw: float, tool: str = "jaws") -> tuple[str | None, float]:
        """The picker's check (:class:`binpick.picking.Picker` ``reach``) for a grasp with ``tool``'s
        point (the fingertips' midpoint, the cup's lip) at ``tips``: (None, the yaw the arm takes) if it
        can take it, else (why not, ``yaw``)."""
        press = SuctionCup().press if tool == "suction" else 0.0  # as execute_arm_pick sends it: the cup pressed on
        reach = self.reach(np.asarray(tips, dtype=float) + [0.0, 0.0, self.below(tool) - press], yaw, tool)
        return reach.reason, reach.yaw

    def _descent(self, centre: np.ndarray, yaw: float, tool: str = "jaws") -> Reach:
        above_walls = BIN_WALL_HEIGHT + FLOOR_TOP + WALLS_CLEARANCE + self.below(tool)
        above = np.array([centre[0], centre[1], max(centre[2] + APPROACH_HEIGHT, above_walls)])
        postures: list[np.ndarray] = []
        previous: np.ndarray | None = None
        for point in line(above, centre):
            solution = self.kinematics.solve(point, yaw, start=previous, iterations=150 if previous is None else 60)
            if not solution.reached:  # held back by the obstacles, or out of the arm's reach?
                free = self.kinematics.solve(point, yaw, start=previous, iterations=150, avoid=False)
                return Reach(COLLIDES if free.reached else NO_IK, yaw)
            if solution.touching:
                return Reach(COLLIDES, yaw)
            if previous is None and self._flipped(solution.q):
                return Reach(WRIST_FLIP, yaw)
            postures.append(solution.q)
            previous = solution.q
        return Reach(None, yaw, postures)

    def clear_of_floor(self, centre: np.ndarray, tool: str = "jaws") -> np.ndarray:
        """The grasp's centre, raised if the tool's point would come within FLOOR_MARGIN of the bin floor."""
        return np.array([centre[0], centre[1], max(float(centre[2]), FLOOR_TOP + FLOOR_MARGIN + self.below(tool))])

    def _flipped(self, q: np.ndarray) -> bool:
        """The fifth joint (Panda: joint 5; UR5e: wrist 2) more than a quarter turn from the nominal posture: the wrist turned over."""
        return bool(abs(q[4] - self.nominal[4]) > WRIST_TURN)

    def pick(self, start, centre, yaw: float, place=ORDER_TOTE, tool: str = "jaws") -> PickMotion:
        """Every segment of a pick from posture ``start``. An unreachable grasp raises nothing: the
        motion's ``reach.reason`` says why (and it has no segments), as for a lift, carry or lowering
        that has no IK solution or a free move that touches the cell on every way tried."""
        started = time.perf_counter()
        centre = self.clear_of_floor(np.asarray(centre, dtype=float), tool)
        reach = self.reach(centre, yaw, tool)  # (the kinematics now check the hand as the tool needs it)
        if not reach.ok:
            return PickMotion([], reach, time.perf_counter() - started)
        descent = reach.descent
        rise = self._along(line(centre, [centre[0], centre[1], max(centre[2] + APPROACH_HEIGHT, LIFT_TO)])[1:], reach.yaw, descent[-1])
        lift = None if rise is None else [descent[-1], *rise]  # from the very posture the fingers closed in
        above_tote = np.array([place[0], place[1], LIFT_TO])
        lowered = None
        for release in dict.fromkeys((release_height(centre[2], FLOOR_TOP), RELEASE_HEIGHT)) if lift else ():  # low, else as high as ever
            lowered = self._along(line(above_tote, [place[0], place[1], release]), reach.yaw, lift[-1])
            if lowered is not None:
                break
        if lift is None or lowered is None:
            return PickMotion([], Reach(NO_IK, reach.yaw), time.perf_counter() - started)
        period, limits = self.period, self.limits
        approach, carry, back = (self._free("approach", start, descent[0], closed=False),
                                 self._free("carry", lift[-1], lowered[0], closed=True),
                                 self._free("return", lowered[0], self.home, closed=False))  # from above the tote again
        if approach is None or carry is None or back is None:
            return PickMotion([], Reach(COLLIDES, reach.yaw), time.perf_counter() - started)
        segments = [*approach, path_move("descend", np.array(descent), limits, period),
                    Segment.dwell("close", descent[-1], CLOSE_SECONDS, period, closed=True),
                    path_move("lift", np.array(lift), limits, period, closed=True), *carry,
                    path_move("lower", np.array(lowered), limits, period, closed=True),
                    Segment.dwell("release", lowered[-1], OPEN_SECONDS, period),
                    # straight up out of the order tote the way it came down: a free move from the low release
                    # swung an open finger into the tote's wall
                    path_move("retreat", np.array(lowered[::-1]), limits, period), *back]
        return PickMotion(segments, reach, time.perf_counter() - started)

    def push(self, start, begin, end, yaw: float) -> PickMotion:
        """The arm's push (:class:`binpick.grasping.push.Push`, the closed fingertips' path ``begin`` to
        ``end``): from posture ``start`` over ``begin`` and straight down onto it, as a grasp's descent,
        along to ``end``, up, and home, the fingers closed throughout. Unreachable: no segments, and the
        motion's ``reach.reason`` says why."""
        started = time.perf_counter()
        below = self.below("jaws")
        first = np.asarray(begin, dtype=float) + [0.0, 0.0, below]
        last = np.asarray(end, dtype=float) + [0.0, 0.0, below]
        for option in (yaw, yaw + np.pi / 2):  # the palm along the push or across it: whichever clears the walls
            reach = self.reach(first, option, "push")  # the closed jaws down onto it: checked with the fingers shut
            if reach.ok:
                break
        if not reach.ok:
            self.kinematics.use("jaws")
            return PickMotion([], reach, time.perf_counter() - started)
        slide = self._along(line(first, last)[1:], reach.yaw, reach.descent[-1])
        rise = None if slide is None else self._along(line(last, [last[0], last[1], max(last[2] + APPROACH_HEIGHT, LIFT_TO)])[1:],
                                                       reach.yaw, slide[-1])
        approach = None if slide is None or rise is None else self._free("approach", start, reach.descent[0], closed=True)
        back = None if approach is None else self._free("return", rise[-1], self.home, closed=True)
        if approach is None or back is None:
            self.kinematics.use("jaws")
            return PickMotion([], Reach(NO_IK if slide is None or rise is None else COLLIDES, reach.yaw), time.perf_counter() - started)
        self.kinematics.use("jaws")
        period, limits = self.period, self.limits
        segments = [*approach, path_move("descend", np.array(reach.descent), limits, period, closed=True),
                    path_move("push", np.array([reach.descent[-1], *slide]), limits, period, closed=True),
                    path_move("lift", np.array([slide[-1], *rise]), limits, period, closed=True), *back]
        return PickMotion(segments, reach, time.perf_counter() - started)

    def back_home(self, start) -> list[Segment]:
        """After a missed grasp: open the fingers, then home (a free move, over the cell if it must;
        straight home if even that touches: the arm is already inside what it touched)."""
        back = self._free("return", start, self.home, closed=False)
        return [Segment.dwell("release", start, OPEN_SECONDS, self.period),
                *(back or [joint_move("return", start, self.home, self.limits, self.period)])]

    def _along(self, points: list[np.ndarray], yaw: float, start: np.ndarray) -> list[np.ndarray] | None:
        """Postures for the gripper at ``points`` (a straight line), each from the one before; None if
        any has no IK solution clear of the cell."""
        postures, previous = [], start
        for point in points:
            solution = self.kinematics.solve(point, yaw, start=previous, iterations=60)
            if not solution.ok:
                solution = self.kinematics.solve(point, yaw, start=previous, iterations=200)
                if not solution.ok:
                    return None
            previous = solution.q
            postures.append(previous)
        return postures

    def _free(self, name: str, start, end, closed: bool) -> list[Segment] | None:
        """A free move, checked along its path. When the direct one would touch the cell: up to the
        carry height, across at that height, and down onto ``end``, each piece checked; None if that
        touches too."""
        segment = joint_move(name, start, end, self.limits, self.period, closed=closed)
        if not self.touches(segment):
            return [segment]
        rise, drop = self._vertical(np.asarray(start)), self._vertical(np.asarray(end))
        if rise is None or drop is None:
            return None
        pieces = [joint_move(name, rise[-1], drop[-1], self.limits, self.period, closed=closed)]
        if len(rise) > 1:
            pieces.insert(0, path_move(f"{name} (up)", np.array(rise), self.limits, self.period, closed=closed))
        if len(drop) > 1:
            pieces.append(path_move(f"{name} (down)", np.array(drop[::-1]), self.limits, self.period, closed=closed))
        return None if any(self.touches(piece) for piece in pieces) else pieces

    def _vertical(self, q: np.ndarray) -> list[np.ndarray] | None:
        """Postures from ``q`` straight up to the carry height (just ``q`` if it is already higher)."""
        position, rotation = self.kinematics.gripper_pose(q)
        yaw = float(np.arctan2(rotation[1, 0], rotation[0, 0]))
        if position[2] >= CARRY_HEIGHT:
            return [q]
        rest = self._along(line(position, [position[0], position[1], CARRY_HEIGHT])[1:], yaw, q)  # from q itself
        return None if rest is None else [q, *rest]

    def touches(self, segment: Segment, every: int = 5) -> bool:
        """Does the arm touch an obstacle anywhere along ``segment`` (checked every ``every`` steps)?"""
        return any(self.kinematics.touching(q) for q in segment.q[::every])

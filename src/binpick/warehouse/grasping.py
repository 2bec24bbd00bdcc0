"""From a detection to a placed product: the 3D grasp point from depth and the camera's intrinsics,
a top-down grasp there, the carry to the order tote and the check of what happened (thesis Fig 1.1).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum

import mujoco
import numpy as np

from binpick.sim.bin_scene import Scene
from binpick.sim.gripper import LIFT_SUCCESS, PARK, SUCTION_PRESS, TRIAL_TIMESTEP
from binpick.sim.mjcf import FLOOR_TOP, CameraSpec
from binpick.sim.order_tote import ORDER_TOTE, in_order_tote, release_height

CARRY_HEIGHT = 0.42


def pixel_to_world(u: float, v: float, depth: float, camera: CameraSpec) -> np.ndarray:
    """A pixel (column u, row v) at ``depth`` metres along the overhead camera's axis -> world xyz.
    The camera looks straight down from (0, 0, height) with image x along world x and image rows
    running towards world -y."""
    fx, fy, cx, cy = camera.intrinsics()
    return np.array([(u - cx) * depth / fx, -(v - cy) * depth / fy, camera.height - depth])


def grasp_point(box_xywh, depth_image: np.ndarray, camera: CameraSpec) -> np.ndarray:
    """Where to grasp a detection: above the box centre, at the height of the nearest surface in
    the middle third of the box (the product's top, seen from above). The box centre is the
    silhouette's, so it is taken back to the world at the product's estimated middle, not at its
    top: off the camera's axis, the top's depth would pull the point several millimetres towards
    the axis, enough for the jaws to squeeze a ball out sideways."""
    x, y, w, h = box_xywh
    rows = slice(int(y + h / 3), max(int(y + h / 3) + 1, int(y + 2 * h / 3)))
    cols = slice(int(x + w / 3), max(int(x + w / 3) + 1, int(x + 2 * w / 3)))
    patch = depth_image[rows, cols]
    depth = float(np.percentile(patch, 20)) if patch.size else float(depth_image[int(y + h / 2), int(x + w / 2)])
    middle = pixel_to_world(x + w / 2, y + h / 2, depth + _half_height(box_xywh, depth, camera), camera)
    return np.array([middle[0], middle[1], camera.height - depth])


def half_height(box_xywh, point: np.ndarray, camera: CameraSpec) -> float:
    """How far below the seen top (``point``, from :func:`grasp_point`) the product's middle
    probably is: half its smaller side in metres. Products lie on their broad faces, so their height
    is close to their narrow width (a ball, a lying can or bottle); a lying box is flatter, and the
    jaws then stop on the floor's clearance."""
    return _half_height(box_xywh, camera.height - point[2], camera)


def _half_height(box_xywh, depth: float, camera: CameraSpec) -> float:
    fx, fy, _, _ = camera.intrinsics()
    narrow = min(box_xywh[2] * depth / fx, box_xywh[3] * depth / fy)
    return float(np.clip(narrow / 2, 0.01, 0.06))


class Reason(StrEnum):
    """Why an order ended as it did. A ``StrEnum``: it compares and prints as its text."""

    PLACED = "placed"
    NO_DETECTION = "no detection"
    NOT_THE_PRODUCT = "not the ordered product"  # every detection failed the product check
    NO_GRASP = "no feasible grasp"  # every grasp candidate was too wide or blocked
    WRONG_PRODUCT = "wrong product"
    MISSED = "missed"  # nothing came up with the gripper
    SLIPPED = "slipped"  # something came up and fell back
    DROPPED = "dropped outside the order tote"


@dataclass
class PickOutcome:
    lifted_slot: int | None  # the instance that came up with the gripper, if any
    placed: bool  # it ended inside the order tote
    reason: Reason  # PLACED, MISSED, SLIPPED or DROPPED
    motion_s: dict[str, float] = field(default_factory=dict)  # an arm's segments: simulated robot seconds each
    planning_ms: float | None = None  # an arm's motion planning (IK and timing), wall milliseconds
    collisions: list[list[str]] = field(default_factory=list)  # an arm's contacts with the table or totes: [arm part, fixed part, segment]
    unreachable: str | None = None  # why the arm could not take the grasp (it then did not move)
    grasp_error_mm: float | None = None  # an arm's gripper from the planned grasp when the fingers closed
    why: str | None = None  # a suction pick's failure in the vacuum's words: no seal (and why), or the seal let go


def fixed_tips(point: np.ndarray, depth_below_top: float) -> np.ndarray:
    """The fixed policy's fingertips under the grasp point (the product's top): a centimetre below
    the product's middle, ``depth_below_top`` under its top, at least 2 cm down, clear of the floor."""
    tips = max(FLOOR_TOP + 0.006, min(point[2] - depth_below_top - 0.01, point[2] - 0.02))
    return np.array([point[0], point[1], tips])


def execute_pick(world, tips: np.ndarray, yaw: float, on_frame: Callable[[], None] | None = None,
                 frame_every: float = 0.1, tool: str = "jaws") -> PickOutcome:
    """Top-down grasp with ``tool``'s point (the fingertips' midpoint, or the suction cup's lip) at
    ``tips`` (world xyz) and the jaws closing along ``yaw`` (radians about z), lift, carry to the order
    tote, release, and report what happened."""
    model, data, gripper = world.model, world.data, world.gripper
    settle_timestep = model.opt.timestep
    model.opt.timestep = TRIAL_TIMESTEP
    every = max(1, int(frame_every / TRIAL_TIMESTEP))

    def move(target, seconds: float, grip: bool) -> None:
        gripper.move(data, target, seconds, close=grip,
                     on_step=None if on_frame is None else lambda step: on_frame() if step % every == 0 else None)

    try:
        heights = np.array([data.xipos[b][2] for b in world.body_ids])
        gripper.use(data, tool)
        below = gripper.tool_point_below()
        point = np.asarray(tips, dtype=float)
        grasp = np.array([point[0], point[1], point[2] + below])
        reach = grasp - [0, 0, SUCTION_PRESS if tool == "suction" else 0.0]  # a cup is pressed on (its bellows give)
        gripper.teleport(data, grasp + [0, 0, 0.15], yaw)
        mujoco.mj_forward(model, data)
        move(reach, 0.4, False)
        move(reach, 0.3, True)
        move(grasp + [0, 0, 0.15], 0.5, True)
        move(grasp + [0, 0, 0.15], 0.5, True)  # hold: does it stay in the jaws, on the cup?
        rise = np.array([data.xipos[b][2] for b in world.body_ids]) - heights
        slot = int(np.argmax(rise))
        if rise[slot] < LIFT_SUCCESS:
            return PickOutcome(None, False, Reason.MISSED if rise.max() < 0.02 else Reason.SLIPPED,
                               why=suction_why(gripper, tool))
        carry = np.array([point[0], point[1], CARRY_HEIGHT])
        move(carry, 0.5, True)
        above_order = np.array([ORDER_TOTE[0], ORDER_TOTE[1], CARRY_HEIGHT])
        move(above_order, 1.0, True)
        if data.xipos[world.body_ids[slot]][2] < above_order[2] - (0.15 if tool == "jaws" else below + 0.15):
            return PickOutcome(slot, False, Reason.SLIPPED, why=suction_why(gripper, tool))  # fell on the way
        lowered = np.array([ORDER_TOTE[0], ORDER_TOTE[1], release_height(grasp[2], FLOOR_TOP)])
        move(lowered, 0.5, True)
        move(lowered, 0.4, False)  # let go
        move(above_order, 0.3, False)
        move(above_order, 0.6, False)  # let it settle
        inside = in_order_tote(data, world.body_ids[slot])
        return PickOutcome(slot, inside, Reason.PLACED if inside else Reason.DROPPED)
    finally:
        model.opt.timestep = settle_timestep
        gripper.reset(data)
        gripper.teleport(data, PARK, 0.0)  # park out of view
        mujoco.mj_forward(model, data)


def execute_push(world, start: np.ndarray, end: np.ndarray, yaw: float, on_frame: Callable[[], None] | None = None,
                 frame_every: float = 0.1) -> float:
    """A push (:class:`binpick.grasping.push.Push`) by the floating gripper: the jaws closed, their
    tips down onto ``start`` (world xyz), slid to ``end`` and lifted; then parked. Returns how far
    the pushed things moved (m, the most any product moved: 0 when the push met nothing)."""
    model, data, gripper = world.model, world.data, world.gripper
    settle_timestep = model.opt.timestep
    model.opt.timestep = TRIAL_TIMESTEP
    every = max(1, int(frame_every / TRIAL_TIMESTEP))

    def move(target, seconds: float) -> None:
        gripper.move(data, target, seconds, close=True,
                     on_step=None if on_frame is None else lambda step: on_frame() if step % every == 0 else None)

    try:
        before = np.array([data.xipos[b].copy() for b in world.body_ids])
        gripper.use(data, "jaws")
        below = gripper.tool_point_below()
        start, end = np.asarray(start, dtype=float) + [0, 0, below], np.asarray(end, dtype=float) + [0, 0, below]
        gripper.teleport(data, start + [0, 0, 0.12], yaw)
        mujoco.mj_forward(model, data)
        move(start + [0, 0, 0.12], 0.3)  # close the fingers above it
        move(start + [0, 0, 0.03], 0.3)
        move(start, 0.4)  # slowly onto it: fast, a ball squirts out from under the fingers
        move(end, 1.2)  # slowly: a ball pushed fast rolls on across the bin
        move(end + [0, 0, 0.12], 0.3)
        for _ in range(20):  # let what was pushed come to rest (a ball rolls on): at most 2 s
            move(end + [0, 0, 0.12], 0.1)
            if max(np.abs(data.qvel[adr:adr + 6]).max() for adr in world.dof_adr) < 0.02:
                break
        after = np.array([data.xipos[b] for b in world.body_ids])
        return float(np.linalg.norm((after - before)[:, :2], axis=1).max())
    finally:
        model.opt.timestep = settle_timestep
        gripper.reset(data)
        gripper.teleport(data, PARK, 0.0)
        mujoco.mj_forward(model, data)


def execute_arm_push(world, planner, start: np.ndarray, end: np.ndarray, yaw: float,
                     on_frame: Callable[[], None] | None = None, frame_every: float = 0.1) -> tuple[float, str | None]:
    """The same push by the arm (:meth:`binpick.arm.MotionPlanner.push`); (how far the pushed things
    had moved when the arm was home, in m; why the arm could not push: None if it did)."""
    from binpick.arm.controller import ArmController

    model, data = world.model, world.data
    settle_timestep = model.opt.timestep
    model.opt.timestep = TRIAL_TIMESTEP
    every = max(1, int(frame_every / TRIAL_TIMESTEP))
    steps = [0]

    def on_step() -> None:
        steps[0] += 1
        if on_frame is not None and steps[0] % every == 0:
            on_frame()

    try:
        before = np.array([data.xipos[b].copy() for b in world.body_ids])
        world.arm.hand.use(data, "jaws")
        motion = planner.push(world.arm.joint_positions(data), start, end, yaw)
        if not motion.reach.ok:
            return 0.0, motion.reach.reason
        controller = ArmController(world)
        for segment in motion.segments:
            controller.run(segment, on_step=on_step)
        after = np.array([data.xipos[b] for b in world.body_ids])
        return float(np.linalg.norm((after - before)[:, :2], axis=1).max()), None
    finally:
        world.arm.hand.reset(data)
        model.opt.timestep = settle_timestep


def suction_why(hand, tool: str) -> str | None:
    """Why a suction pick failed, in the vacuum's words (no seal, or the seal let go); None for jaws."""
    return hand.vacuum.why if tool == "suction" and hand.vacuum is not None else None


def execute_arm_pick(world, planner, tips: np.ndarray, yaw: float, on_frame: Callable[[], None] | None = None,
                     frame_every: float = 0.1, tool: str = "jaws") -> PickOutcome:
    """The same pick by the arm in ``world`` (``world.arm``): every segment from its current posture
    (home) to the order tote and back home, planned by ``planner`` (a :class:`binpick.arm.MotionPlanner`)
    and executed by joint position targets at the simulator's step (the planner's ``period`` must be
    the trial timestep: the robot seconds reported are its segments' durations). The lift is judged after the
    lift segment (after a miss the arm opens and goes home); a product lower than the fingers by more
    than the lift test's margin when the arm has lowered it over the order tote fell on the way. A
    grasp the arm cannot reach is not executed (``unreachable`` says why). ``tool``: which of the hand's
    tools takes the grasp (its point at ``tips``)."""
    from binpick.arm.controller import ArmController

    if abs(planner.period - TRIAL_TIMESTEP) > 1e-9:
        raise ValueError(f"the arm's planner steps at {planner.period} s, the simulator at {TRIAL_TIMESTEP} s: make them equal")
    model, data = world.model, world.data
    settle_timestep = model.opt.timestep
    model.opt.timestep = TRIAL_TIMESTEP
    every = max(1, int(frame_every / TRIAL_TIMESTEP))
    controller, steps = ArmController(world), [0]

    def on_step() -> None:
        steps[0] += 1
        if on_frame is not None and steps[0] % every == 0:
            on_frame()

    def run(segments) -> None:
        for segment in segments:
            controller.run(segment, on_step=on_step)
            outcome.motion_s[segment.name] = round(outcome.motion_s.get(segment.name, 0.0) + segment.duration, 3)

    hand = world.arm.hand
    try:
        heights = np.array([data.xipos[b][2] for b in world.body_ids])
        hand.use(data, tool)
        below = hand.tool_point_below()
        press = SUCTION_PRESS if tool == "suction" else 0.0
        motion = planner.pick(world.arm.joint_positions(data), np.asarray(tips, dtype=float) + [0.0, 0.0, below - press], yaw,
                              tool=tool)
        outcome = PickOutcome(None, False, Reason.MISSED, planning_ms=round(1000 * motion.planning_s, 1))
        if not motion.reach.ok:
            outcome.unreachable = motion.reach.reason
            return outcome
        names = [segment.name for segment in motion.segments]
        closing, lifted = names.index("close"), names.index("lift") + 1
        run(motion.segments[:closing])
        planned, _ = planner.kinematics.gripper_pose(motion.segments[closing].q[-1])
        outcome.grasp_error_mm = round(1000 * float(np.linalg.norm(data.xpos[world.arm.gripper_body] - planned)), 2)
        run(motion.segments[closing:lifted])
        rise = np.array([data.xipos[b][2] for b in world.body_ids]) - heights
        slot = int(np.argmax(rise))
        if rise[slot] < LIFT_SUCCESS:
            outcome.reason = Reason.MISSED if rise.max() < 0.02 else Reason.SLIPPED
            outcome.why = suction_why(hand, tool)
            run(planner.back_home(world.arm.joint_positions(data)))
        else:
            lowering, lowered = names.index("lower"), names.index("lower") + 1
            run(motion.segments[lifted:lowering])  # carried to above the order tote: still held? (judged before the low release)
            fell = data.xipos[world.body_ids[slot]][2] < data.xpos[world.arm.gripper_body][2] - below - 0.15
            run(motion.segments[lowering:lowered])
            outcome.why = suction_why(hand, tool) if fell else None
            run(motion.segments[lowered:])
            inside = in_order_tote(data, world.body_ids[slot])
            outcome.lifted_slot, outcome.placed = slot, bool(inside and not fell)
            outcome.reason = Reason.SLIPPED if fell else Reason.PLACED if inside else Reason.DROPPED
        outcome.collisions = [list(pair) for pair in controller.collisions]
        return outcome
    finally:
        hand.reset(data)
        model.opt.timestep = settle_timestep


def arm_lift_test(world, planner, slot: int, tips, yaw: float, tool: str = "jaws") -> bool:
    """A label grasp made by the arm (``data generate`` with ``robot: panda``): from home to the grasp,
    close, lift, and carry to above the order tote, as the pipeline's picks go; True if instance
    ``slot`` rose by LIFT_SUCCESS and is still in the jaws there. A grasp the arm cannot reach is no."""
    from binpick.arm.controller import ArmController

    model, data = world.model, world.data
    settle_timestep = model.opt.timestep
    model.opt.timestep = TRIAL_TIMESTEP
    try:
        body = world.body_ids[slot]
        start = float(data.xipos[body][2])
        hand = world.arm.hand
        hand.use(data, tool)
        below = hand.tool_point_below()
        press = SUCTION_PRESS if tool == "suction" else 0.0
        motion = planner.pick(world.arm.joint_positions(data), np.asarray(tips, dtype=float) + [0.0, 0.0, below - press], yaw,
                              tool=tool)
        if not motion.reach.ok:
            return False
        controller = ArmController(world)
        for segment in motion.segments:
            if segment.name == "lower":  # carried to above the order tote: judged there
                break
            controller.run(segment)
            if segment.name == "lift" and data.xipos[body][2] - start < LIFT_SUCCESS:
                return False
        held = data.xpos[world.arm.gripper_body][2] - data.xipos[body][2] < below + 0.11  # still hanging in the jaws, on the cup
        return bool(np.isfinite(data.xipos[body][2]) and data.xipos[body][2] - start >= LIFT_SUCCESS and held)
    finally:
        world.arm.hand.reset(data)
        model.opt.timestep = settle_timestep


def legacy_view(scene: Scene) -> bool:
    """Perfect depth from a camera straight above the tote: what the fixed policy's own grasp point
    (:func:`fixed_policy_tips`) was made for. Elsewhere it takes its candidate's fingertips."""
    pose = np.asarray(scene.camera.get("camera_to_world", np.eye(4)), dtype=float)
    return not scene.sensor and bool(pose[2, 2] < -0.9999)


def fixed_policy_tips(box, depth: np.ndarray, overhead: CameraSpec) -> np.ndarray:
    """The fixed policy's fingertips: the grasp point and depth it had before the planner existed
    (from the overhead camera), so its rows stay comparable."""
    point = grasp_point(box, depth, overhead)
    return fixed_tips(point, half_height(box, point, overhead))

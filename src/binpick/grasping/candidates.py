"""Grasp candidates for one detection, from depth alone (no simulator): the instance's surface as
the depth image shows it (:mod:`binpick.grasping.instance`), a set of yaws (evenly over 180° plus the surface's principal minor axis), the
jaws centred on the instance and shifted either way along the closing direction, the fingertips'
depth, the width across the jaws, and a check that each finger can descend beside it.

A top-down parallel-jaw grasp (Dex-Net 2.0's and GG-CNN's setting): the jaws close along the
direction ``yaw`` (radians about the world's vertical), their centre at ``position`` (world xyz of
the fingertips' midpoint). Every candidate keeps the reason it was rejected, so a pick attempt can
say why the others were not tried. Depth comes as a :class:`~binpick.grasping.frame.DepthFrame`:
holes filled, and a finger's path judged on the pixels the sensor read.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from binpick.grasping.frame import DepthFrame
from binpick.grasping.instance import PALM_REACH, Surface, instance_surface, on_instance, points_on_instance, surface_heights
from binpick.grippers import Jaws

MIN_GRIP = 0.015  # fingertips at least this far under the instance's top
# A finger may land on a surface this far above its tips: it pushes what is there aside. In 3,402
# simulated trials, grasps whose fingers met surfaces 0.5-3 cm above the tips still held 65-68% of
# the time (80% with clear fingers); beyond 3 cm, 39%.
BLOCK_TOLERANCE = 0.03
ON_TOP = 0.01  # m: another object this far above the instance's top, between the open jaws, is taken instead of it
ON_TOP_REASON = "another object on it, between the jaws"
TOO_WIDE = "too wide across the jaws"
SHIFT = 0.01  # m: candidates also move the jaws' centre this far either way along the closing direction
ON_INSTANCE_SPACING, ON_INSTANCE_POINTS = 0.012, 13  # the instance's centre and 12 points on it: where an off-centre one straddles it
YAWS = 12  # even yaws over 180 degrees (15 degrees apart), plus the minor axis


JawGripper = Jaws  # the parallel-jaw gripper's geometry (binpick.grippers.Jaws)


@dataclass
class GraspCandidate:
    position: np.ndarray  # world xyz of the fingertips' midpoint
    yaw: float  # closing direction, radians about world z, in [0, pi)
    width: float  # the instance's extent across the jaws (m)
    clearance: float  # tips height minus the highest surface under either finger (m; < 0: blocked)
    top: float
    support: float
    rejected: str | None = None  # why it is not tried (None: feasible)
    quality: float | None = None  # the policy's score, where it scored it
    kind: str = "even"  # even (jaws centred on the instance), shifted, raised (tips lifted clear), on instance, given; suction
    tool: str = "jaws"  # jaws, or suction (position: the cup's lip on the surface; width 0)
    seal: object | None = None  # a suction grasp's binpick.grasping.suction.SuctionFeatures

    def to_json(self) -> dict:
        return {"tool": self.tool, "position": [round(float(v), 4) for v in self.position], "yaw": round(float(self.yaw), 4),
                "width": round(float(self.width), 4),
                "clearance": round(float(self.clearance), 4) if np.isfinite(self.clearance) else None,
                "quality": None if self.quality is None else round(float(self.quality), 4), "rejected": self.rejected}


def finger_heights(frame: DepthFrame, centres: np.ndarray, yaws: np.ndarray, gripper: JawGripper, z_ref: float,
                   samples: tuple[int, int] = (3, 5)) -> tuple[np.ndarray, np.ndarray]:
    """For N grasps (jaws' centres (N, 2), yaws (N,)): the highest surface under each open finger,
    (N, 2), judged on the pixels the sensor read where it read most of a finger's footprint (on the
    filled depth as well where it did not), and whether both fingers are inside the camera's view (N,)."""
    d = np.stack([np.cos(yaws), np.sin(yaws)], axis=1)
    j = np.stack([-d[:, 1], d[:, 0]], axis=1)
    reach = gripper.opening / 2 + gripper.finger_thickness / 2
    a = np.linspace(-gripper.finger_thickness / 2, gripper.finger_thickness / 2, samples[0])
    b = np.linspace(-gripper.finger_width / 2, gripper.finger_width / 2, samples[1])
    offsets_a = np.stack([-reach + a, reach + a])  # (2 fingers, sa)
    grid = (centres[:, None, None, None, :] + offsets_a[None, :, :, None, None] * d[:, None, None, None, :]
            + b[None, None, None, :, None] * j[:, None, None, None, :])  # (N, 2, sa, sb, 2)
    heights, read = surface_heights(frame, grid.reshape(-1, 2), z_ref)
    heights = heights.reshape(len(centres), 2, -1)
    read = read.reshape(len(centres), 2, -1)
    seen = np.isfinite(heights).all(axis=(1, 2))
    # read pixels where at least half the footprint was read (a shadow's edge beside it says nothing
    # of what the finger meets); a footprint mostly unread (a dark or shiny neighbour) on the filled depth
    mostly_read = read.mean(axis=2, keepdims=True) >= 0.5
    judged = np.where(read | ~mostly_read, heights, -np.inf)
    return np.max(judged, axis=2), seen


def something_on_top(frame: DepthFrame, surface: Surface, centres: np.ndarray, yaws: np.ndarray, gripper: JawGripper) -> np.ndarray:
    """For N grasps: whether another object lies between the open jaws above the instance's top (read
    pixels off the instance, ON_TOP higher than its top): the jaws would close on it, not the instance
    under it, and carry the wrong product to the customer."""
    d = np.stack([np.cos(yaws), np.sin(yaws)], axis=1)
    j = np.stack([-d[:, 1], d[:, 0]], axis=1)
    inner = gripper.opening / 2 - gripper.finger_thickness
    a = np.linspace(-inner, inner, 9)
    b = np.linspace(-gripper.finger_width / 2, gripper.finger_width / 2, 3)
    grid = centres[:, None, None, :] + a[None, :, None, None] * d[:, None, None, :] + b[None, None, :, None] * j[:, None, None, :]
    pixels: list = []
    heights, read = surface_heights(frame, grid.reshape(-1, 2), surface.top, pixels)
    other = ~surface.on_instance(pixels[0])
    above = read & other & np.isfinite(heights) & (heights > surface.top + ON_TOP)
    return above.reshape(len(centres), -1).sum(axis=1) >= 2


def palm_reach(gripper: JawGripper) -> float:
    """How far under an instance's top the fingertips may go with ``gripper``'s fingers: their length
    less a centimetre, so the palm stays clear (PALM_REACH for binpick's 8 cm fingers)."""
    return max(MIN_GRIP, min(PALM_REACH, gripper.finger_length - (JawGripper().finger_length - PALM_REACH)))


def widths_across(surface: Surface, centres: np.ndarray, yaws: np.ndarray, gripper: JawGripper) -> tuple[np.ndarray, np.ndarray]:
    """For N grasps: the instance's extent along each closing direction within the fingers' band,
    and the offset of that extent's midpoint from the centre (where the jaws squeeze evenly)."""
    d = np.stack([np.cos(yaws), np.sin(yaws)], axis=1)  # (N, 2)
    rel = surface.xy[None, :, :] - centres[:, None, :]  # (N, M, 2)
    along = np.einsum("nmk,nk->nm", rel, d)
    across = rel[..., 0] * -d[:, None, 1] + rel[..., 1] * d[:, None, 0]
    band = np.abs(across) <= gripper.finger_width / 2 + 0.004
    empty = ~band.any(axis=1)
    low = np.where(band, along, np.inf).min(axis=1)
    high = np.where(band, along, -np.inf).max(axis=1)
    low, high = np.where(empty, 0.0, low), np.where(empty, 0.0, high)  # nothing in the band: no width
    return high - low, (high + low) / 2


def yaws(count: int = YAWS, surface: Surface | None = None) -> list[float]:
    """``count`` yaws evenly over 180°, and the surface's principal minor axis first where given."""
    even = [np.pi * k / count for k in range(count)]
    return ([surface.minor_yaw] if surface is not None else []) + even


def describe_many(frame: DepthFrame, surface: Surface, centres, yaws_, tips=None, gripper: JawGripper = JawGripper(),
                  kinds=None, raise_blocked: bool = False, widths: np.ndarray | None = None) -> list[GraspCandidate]:
    """Grasps with the jaws' centres at world ``centres`` (N, 2), closing along ``yaws_`` (N,): their
    fingertips' height (``tips`` (N,), or as deep as :meth:`Surface.tips_range` and the surfaces under
    the fingers allow), the instance's width across the jaws there, the fingers' clearance, and the
    reason each would be rejected (None: feasible). With ``raise_blocked``, a grasp whose fingers
    would land on something above its deepest tips also comes with its tips lifted clear of it (kind
    ``raised``), as long as they stay MIN_GRIP under the top. ``widths``: the widths across the jaws,
    where the caller knows them already."""
    centres = np.asarray(centres, dtype=float).reshape(-1, 2)
    yaws_ = np.mod(np.asarray(yaws_, dtype=float).reshape(-1), np.pi)
    kinds = list(kinds) if kinds is not None else ["even"] * len(centres)
    width = widths_across(surface, centres, yaws_, gripper)[0] if widths is None else np.asarray(widths, dtype=float)
    under, seen = finger_heights(frame, centres, yaws_, gripper, surface.top)
    highest = under.max(axis=1)
    deepest, shallowest = surface.tips_range(palm_reach(gripper))
    given = tips is not None
    if given:
        tip_z = np.asarray(tips, dtype=float).reshape(-1)
    else:
        tip_z = np.where(seen, np.clip(highest + 0.003, deepest, shallowest), deepest)
    candidates = [_candidate(centres[i], yaws_[i], tip_z[i], width[i], highest[i], seen[i], surface, gripper, kinds[i])
                  for i in range(len(centres))]
    # something else lying on the instance, between the jaws: they would take it instead
    covered = something_on_top(frame, surface, centres, yaws_, gripper) if surface.mask is not None else np.zeros(len(centres), bool)
    for i in np.flatnonzero(covered):
        if candidates[i].rejected is None:
            candidates[i].rejected = ON_TOP_REASON
    if raise_blocked and not given:
        limit = max(shallowest, surface.top - MIN_GRIP)
        for i in np.flatnonzero(seen & (highest + 0.003 > shallowest + 0.005) & (highest + 0.003 <= limit)):
            candidates.append(_candidate(centres[i], yaws_[i], highest[i] + 0.003, width[i], highest[i], True, surface, gripper, "raised"))
            if covered[i] and candidates[-1].rejected is None:
                candidates[-1].rejected = ON_TOP_REASON
    return candidates


def _candidate(centre, yaw: float, tips: float, width: float, highest: float, seen: bool, surface: Surface,
               gripper: JawGripper, kind: str) -> GraspCandidate:
    clearance = float(tips - highest) if seen else float("nan")
    candidate = GraspCandidate(np.array([centre[0], centre[1], tips]), float(yaw), float(width), clearance,
                               surface.top, surface.support, kind=kind)
    if not seen:
        candidate.rejected = "finger outside the camera's view"
    elif width > gripper.opening - gripper.margin:
        candidate.rejected = f"{TOO_WIDE} ({width * 100:.1f} cm)"
    elif clearance < -BLOCK_TOLERANCE:
        candidate.rejected = f"finger blocked ({-clearance * 100:.1f} cm above the tips)"
    return candidate


def describe(frame: DepthFrame, surface: Surface, centre, yaw: float, tips: float | None = None,
             gripper: JawGripper = JawGripper()) -> GraspCandidate:
    """One grasp (:func:`describe_many`): the jaws' centre at world ``centre`` (x, y), closing along ``yaw``."""
    return describe_many(frame, surface, np.asarray(centre, dtype=float)[None, :2], [yaw],
                         None if tips is None else [tips], gripper, ["given"])[0]


def grasp_candidates(frame: DepthFrame, box, gripper: JawGripper = JawGripper(), count: int = YAWS,
                     offsets: np.ndarray | None = None, surface: Surface | None = None) -> tuple[Surface | None, list[GraspCandidate]]:
    """Candidates for the instance in ``box``: per yaw (:func:`yaws`), the jaws centred on the
    instance's extent across them and shifted SHIFT either way along the closing direction (and at
    ``offsets``, (K, 2) world xy shifts from the instance's centre, if given), each with its width,
    clearance and the reason it is rejected; blocked ones also with their tips lifted clear. The
    first candidate is the even grasp across the minor axis. Empty when depth shows nothing in the box.
    ``surface``: the instance's, where the caller found it already."""
    surface = surface if surface is not None else instance_surface(frame, box)
    if surface is None:
        return None, []
    directions = np.array(yaws(count, surface))
    unit = np.stack([np.cos(directions), np.sin(directions)], axis=1)
    width, middle = widths_across(surface, np.repeat(surface.centre[None], len(directions), axis=0), directions, gripper)
    even = surface.centre + middle[:, None] * unit
    # shifting the jaws along their closing direction keeps the band between them: the same width
    centres, angles, widths, kinds = [even], [directions], [width], ["even"] * len(directions)
    for sign in (-1, 1):
        centres.append(even + sign * SHIFT * unit)
        angles.append(directions)
        widths.append(width)
        kinds += ["shifted"] * len(directions)
    # a thin, curved or coiled instance (a cable, a ring, a U) has its centre off its own pixels: the jaws
    # then also straddle points on it, where a finger's band may cross it alone
    centred = bool(on_instance(frame, surface, surface.centre[None])[0])
    if not centred:
        for point in points_on_instance(surface, ON_INSTANCE_SPACING, ON_INSTANCE_POINTS)[1:]:
            at = np.repeat(point[None], len(directions), axis=0)
            centres.append(at)
            angles.append(directions)
            widths.append(widths_across(surface, at, directions, gripper)[0])
            kinds += ["on instance"] * len(directions)
    for offset in ([] if offsets is None else np.asarray(offsets, dtype=float).reshape(-1, 2)):
        shifted = np.repeat((surface.centre + offset)[None], len(directions), axis=0)
        centres.append(shifted)
        angles.append(directions)
        widths.append(widths_across(surface, shifted, directions, gripper)[0])
        kinds += ["offset"] * len(directions)
    candidates = describe_many(frame, surface, np.concatenate(centres), np.concatenate(angles), gripper=gripper,
                               kinds=kinds, raise_blocked=True, widths=np.concatenate(widths))
    if not centred:  # jaws centred on background inside or beside the instance are not tried
        centre_on = on_instance(frame, surface, np.array([c.position[:2] for c in candidates]))
        for candidate, on in zip(candidates, centre_on):
            if not on and candidate.rejected is None:
                candidate.rejected = "centre off the instance"
    return surface, candidates

"""Grasp candidates for one detection, from depth alone (no simulator): the instance's surface as
the depth image shows it (a height watershed above the support plane, the region matching its box,
kept inside the box), a set of yaws (evenly over 180° plus the surface's principal minor axis), the
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

import cv2
import numpy as np

from binpick.grasping.frame import DepthFrame
from binpick.grippers import Jaws

FLOOR_CLEARANCE = 0.006  # fingertips stop this far above the surface the instance rests on
PALM_REACH = 0.07  # fingertips at most this far under the instance's top (8 cm fingers, the palm above them)
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
class Surface:
    """What the depth image says about one instance: its visible top surface's points."""

    xy: np.ndarray  # (N, 2) world xy of the instance's pixels
    centre: np.ndarray  # (2,) their centroid
    top: float  # world z of its top (at its centre)
    support: float  # world z of what it rests on (at its centre)
    minor_yaw: float  # closing across the surface's narrow direction (principal minor axis)
    elongation: float  # major / minor standard deviation (1: round)
    mask: np.ndarray | None = None  # the instance's pixels in the crop round its box (bool)
    origin: tuple[int, int] = (0, 0)  # the crop's first row and column in the frame

    def on_instance(self, pixels: np.ndarray) -> np.ndarray:
        """Whether each pixel (..., 2) as (u, v) lies on the instance's pixels."""
        if self.mask is None:
            return np.ones(pixels.shape[:-1], bool)
        u = np.rint(pixels[..., 0]) - self.origin[1]
        v = np.rint(pixels[..., 1]) - self.origin[0]
        inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u < self.mask.shape[1]) & (v < self.mask.shape[0])
        result = np.zeros(pixels.shape[:-1], bool)
        result[inside] = self.mask[v[inside].astype(int), u[inside].astype(int)]
        return result

    @property
    def height(self) -> float:
        return self.top - self.support

    def extents(self) -> tuple[float, float]:
        """The visible top's length along its principal major and minor axes (m; 2nd-98th percentile,
        so a few stray pixels do not count)."""
        across = np.array([np.cos(self.minor_yaw), np.sin(self.minor_yaw)])
        along = np.array([-across[1], across[0]])
        relative = self.xy - self.centre
        span = lambda values: float(np.percentile(values, 98) - np.percentile(values, 2))  # noqa: E731
        return span(relative @ along), span(relative @ across)

    def tips_range(self, reach: float = PALM_REACH) -> tuple[float, float]:
        """How deep the fingertips may go: at most ``reach`` under the top (PALM_REACH for binpick's 8 cm
        fingers: the palm stays above it) and clear of what it rests on; at least 1.5 cm under its
        middle, so the jaws close across its widest part. In the simulator a lying can held with the
        tips 1 cm under its middle slipped on the carry, 2 cm under it held: as deep as the fingers
        have room for is best."""
        deepest = max(self.support + FLOOR_CLEARANCE, self.top - reach)
        return deepest, max(deepest, self.support + self.height / 2 - 0.015)


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


LEVEL_STEP = 0.0015  # the watershed floods the box's heights in steps of this many metres
JUMP = 0.01  # heights that change more than this within a pixel's 3x3 neighbourhood: an occluding edge


def watershed_labels(z: np.ndarray, floor: float, top: float) -> np.ndarray:
    """A watershed of the heights ``z`` above ``floor``, flooded from the top down: every local top
    (a ridge of a lying bottle, a box's face) starts a region, regions grow as the level falls and
    meet in the valleys between touching products. Occluding edges (a product lying over another,
    a bottle's neck against a taller box) belong to no region, so the flood cannot cross them.
    Returns int32 labels (0: below ``floor`` or on an edge)."""
    z = np.nan_to_num(np.asarray(z, dtype=np.float32), nan=-1.0)
    kernel = np.ones((3, 3), np.uint8)
    smooth = cv2.dilate(z, kernel) - cv2.erode(z, kernel) <= JUMP
    labels = np.zeros(z.shape, np.float32)  # float: cv2.dilate spreads labels (the larger wins a tie)
    min_seed = max(4, z.size // 400)
    count = 0
    for level in np.arange(top, floor, -LEVEL_STEP):
        region = (z >= level) & smooth
        for _ in range(z.shape[0] + z.shape[1]):
            grown = cv2.dilate(labels, kernel)
            new = region & (labels == 0) & (grown > 0)
            if not new.any():
                break
            labels[new] = grown[new]
        fresh = region & (labels == 0)
        if fresh.any():
            parts, components = cv2.connectedComponents(fresh.astype(np.uint8), connectivity=8)
            sizes = np.bincount(components.ravel(), minlength=parts)
            for part in range(1, parts):
                if sizes[part] >= min_seed:
                    count += 1
                    labels[components == part] = count
    return claim_edges(z, labels.astype(np.int32), floor)


def claim_edges(z: np.ndarray, labels: np.ndarray, floor: float, passes: int = 2) -> np.ndarray:
    """Edge pixels join the neighbouring region closest to them in height, if within JUMP: a
    product's own rim goes back to it (its width stays whole), the floor beside it does not."""
    padded_z = np.pad(z, 1, constant_values=-np.inf)
    for _ in range(passes):
        padded = np.pad(labels, 1)
        best_gap = np.full(z.shape, np.inf)
        best_label = np.zeros_like(labels)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                neighbour = padded[1 + dr:1 + dr + z.shape[0], 1 + dc:1 + dc + z.shape[1]]
                gap = np.abs(padded_z[1 + dr:1 + dr + z.shape[0], 1 + dc:1 + dc + z.shape[1]] - z)
                better = (neighbour > 0) & (gap < best_gap) & (gap <= JUMP)
                best_gap, best_label = np.where(better, gap, best_gap), np.where(better, neighbour, best_label)
        claim = (labels == 0) & (z >= floor) & (best_label > 0)
        if not claim.any():
            break
        labels = np.where(claim, best_label, labels)
    return labels


def instance_mask(z: np.ndarray, support: float, top: float, box_in_crop) -> np.ndarray | None:
    """The instance's pixels among the watershed's regions (``box_in_crop``: its detection box, x, y,
    w, h in the crop's pixels): the region whose extent best matches the box, joined by the regions
    touching it that lie wholly inside the box (the arms of a jack-like product below its top bar),
    and cut to the box: a detection's box is its instance's extent, so a touching neighbour the
    flood could not tell apart (two boxes side by side at one height) stays outside it."""
    height = top - support
    labels = watershed_labels(z, support + max(0.004, 0.3 * height), top)
    x, y, w, h = box_in_crop
    regions = []
    for label in range(1, int(labels.max()) + 1):
        rows, cols = np.nonzero(labels == label)
        if len(rows):
            inside = np.mean((cols >= x - 1) & (cols <= x + w) & (rows >= y - 1) & (rows <= y + h))
            regions.append((label, (cols.min(), rows.min(), cols.max() + 1, rows.max() + 1), float(inside)))

    def iou(extent) -> float:
        x0, y0, x1, y1 = extent
        overlap = max(0.0, min(x1, x + w) - max(x0, x)) * max(0.0, min(y1, y + h) - max(y0, y))
        return overlap / ((x1 - x0) * (y1 - y0) + w * h - overlap)

    if not regions:
        return None
    label, extent, _ = max(regions, key=lambda r: iou(r[1]))
    if iou(extent) <= 0:
        return None
    chosen = [label]
    mask = labels == label
    kernel = np.ones((5, 5), np.uint8)
    while True:  # join neighbouring regions that lie (almost) wholly inside the box
        near = cv2.dilate(mask.astype(np.uint8), kernel).astype(bool)
        joining = [other for other, _, inside in regions if other not in chosen and inside >= 0.9 and near[labels == other].any()]
        if not joining:
            break
        chosen += joining
        mask = np.isin(labels, chosen)
    margin = 2  # pixels: a box drawn tight, or by a detector a little off
    rows, cols = np.indices(mask.shape)
    inside_box = (cols >= x - margin) & (cols < x + w + margin) & (rows >= y - margin) & (rows < y + h + margin)
    return mask & inside_box


def instance_surface(frame: DepthFrame, box) -> Surface | None:
    """The instance inside ``box`` (x, y, w, h pixels) of the frame: the region of a height watershed
    (:func:`instance_mask`, on heights above the support plane) that matches the box; what it rests on
    is the low end of the heights around the box. None when depth shows nothing standing out there."""
    points, heights = frame.points, frame.heights
    height_px, width_px = heights.shape
    x, y, w, h = (float(v) for v in box)
    pad = max(6.0, 0.25 * max(w, h))
    r0, r1 = int(max(0, y - pad)), int(min(height_px, y + h + pad))
    c0, c1 = int(max(0, x - pad)), int(min(width_px, x + w + pad))
    b0, b1 = int(max(0, y)), int(min(height_px, np.ceil(y + h)))
    a0, a1 = int(max(0, x)), int(min(width_px, np.ceil(x + w)))
    if b1 - b0 < 2 or a1 - a0 < 2:
        return None
    z = heights[b0:b1, a0:a1]
    inner = z[int(0.2 * (b1 - b0)):max(int(0.2 * (b1 - b0)) + 1, int(0.8 * (b1 - b0))),
              int(0.2 * (a1 - a0)):max(int(0.2 * (a1 - a0)) + 1, int(0.8 * (a1 - a0)))]
    if not np.isfinite(inner).any():
        return None
    top = float(np.nanpercentile(inner, 95))
    around = heights[r0:r1, c0:c1]
    support = float(np.nanpercentile(around, 5))
    if top - support < 0.005 and np.isfinite(z).any():  # a ring or a U: the box's middle is background
        top = float(np.nanpercentile(z, 95))
    if top - support < 0.005:
        return None
    mask = instance_mask(around, support, top, (x - c0, y - r0, w, h))
    if mask is None:
        return None
    xy = points[r0:r1, c0:c1, :2][mask]
    xy = xy[np.isfinite(xy).all(axis=1)]
    if len(xy) < 5:
        return None
    top = float(np.nanpercentile(around[mask], 95))  # its own top, not a neighbour's lying over the box's centre
    centre = xy.mean(axis=0)
    values, vectors = np.linalg.eigh(np.cov((xy - centre).T))
    major = vectors[:, 1]
    minor_yaw = float(np.mod(np.arctan2(major[1], major[0]) + np.pi / 2, np.pi))
    elongation = float(np.sqrt(max(values[1], 1e-12) / max(values[0], 1e-12)))
    base = float(frame.support_z(centre))  # heights above the plane back to world z, at the instance
    return Surface(xy, centre, top + base, support + base, minor_yaw, elongation, mask, (r0, c0))


def points_on_instance(surface: Surface, spacing: float = 0.01, limit: int = 48) -> np.ndarray:
    """World xy points on the instance ``spacing`` apart (one per cell of a grid over its pixels, the
    cell's mean), its centre first, then nearest the centre first; at most ``limit``."""
    cells = np.floor((surface.xy - surface.centre) / spacing).astype(int)
    _, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((counts.size, 2))
    np.add.at(sums, inverse, surface.xy)
    centres = sums / counts[:, None]
    centres = centres[counts >= max(1, int(np.median(counts) * 0.3))]  # cells the instance barely touches go
    order = np.argsort(np.linalg.norm(centres - surface.centre, axis=1))
    return np.concatenate([surface.centre[None], centres[order]])[:limit]


def on_instance(frame: DepthFrame, surface: Surface, xy: np.ndarray) -> np.ndarray:
    """Whether each world point (N, 2) at the instance's top lies on the instance's own pixels."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    pixels, _ = frame.camera.project(np.concatenate([xy, np.full((len(xy), 1), surface.top)], axis=1))
    return surface.on_instance(pixels)


def surface_heights(frame: DepthFrame, xy: np.ndarray, z_ref, pixels_out: list | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World z of the surface seen at world ``xy`` (N, 2): the pixel where (x, y, z_ref) projects,
    its back-projected height (holes filled), and whether the sensor read that pixel. NaN (and not
    read) outside the image. ``pixels_out`` (a list) receives the (N, 2) pixels."""
    xy = np.asarray(xy, dtype=float)
    world = np.concatenate([xy, np.broadcast_to(np.asarray(z_ref, dtype=float), (len(xy),))[:, None]], axis=1)
    pixels, _ = frame.camera.project(world)
    if pixels_out is not None:
        pixels_out.append(pixels)
    u, v = np.rint(pixels[:, 0]), np.rint(pixels[:, 1])
    points = frame.points
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u < points.shape[1]) & (v < points.shape[0])
    heights, read = np.full(len(xy), np.nan), np.zeros(len(xy), bool)
    rows, cols = v[inside].astype(int), u[inside].astype(int)
    heights[inside] = points[rows, cols, 2]
    read[inside] = frame.valid[rows, cols]
    return heights, read


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

"""Grasp candidates for one detection, from depth alone (no simulator): the instance's surface as
the depth image shows it (a height watershed, the region matching its box), a set of yaws (evenly over 180° plus the surface's principal minor axis), the
fingertips' depth, the width across the jaws, and a check that each finger can descend beside it.

A top-down parallel-jaw grasp (Dex-Net 2.0's and GG-CNN's setting): the jaws close along the
direction ``yaw`` (radians about the world's vertical), their centre at ``position`` (world xyz of
the fingertips' midpoint). Every candidate keeps the reason it was rejected, so a pick attempt can
say why the others were not tried.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from binpick.grasping.camera import PinholeCamera

FLOOR_CLEARANCE = 0.006  # fingertips stop this far above the surface the instance rests on
PALM_REACH = 0.07  # fingertips at most this far under the instance's top (8 cm fingers, the palm above them)
# A finger may land on a surface this far above its tips: it pushes what is there aside. In 3,402
# simulated trials, grasps whose fingers met surfaces 0.5-3 cm above the tips still held 65-68% of
# the time (80% with clear fingers); beyond 3 cm, 39%.
BLOCK_TOLERANCE = 0.03


@dataclass(frozen=True)
class JawGripper:
    """The parallel-jaw gripper's geometry, metres (binpick's simulated one by default)."""

    opening: float = 0.11  # distance between the open fingers' inner faces
    finger_thickness: float = 0.012  # along the closing direction
    finger_width: float = 0.028  # across it
    margin: float = 0.008  # the widest object it takes is opening - margin


@dataclass
class Surface:
    """What the depth image says about one instance: its visible top surface's points."""

    xy: np.ndarray  # (N, 2) world xy of the instance's pixels
    centre: np.ndarray  # (2,) their centroid
    top: float  # height of its top (world z)
    support: float  # height of what it rests on
    minor_yaw: float  # closing across the surface's narrow direction (principal minor axis)
    elongation: float  # major / minor standard deviation (1: round)

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

    def tips_range(self) -> tuple[float, float]:
        """How deep the fingertips may go: at most PALM_REACH under the top (the palm stays above it)
        and clear of what it rests on; at least 1.5 cm under its middle, so the jaws close across its
        widest part. In the simulator a lying can held with the tips 1 cm under its middle slipped on
        the carry, 2 cm under it held: as deep as the fingers have room for is best."""
        deepest = max(self.support + FLOOR_CLEARANCE, self.top - PALM_REACH)
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

    def to_json(self) -> dict:
        return {"position": [round(float(v), 4) for v in self.position], "yaw": round(float(self.yaw), 4),
                "width": round(float(self.width), 4), "clearance": round(float(self.clearance), 4),
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
    touching it that lie wholly inside the box (the arms of a jack-like product below its top bar).
    A detection's box is its instance's extent; a touching neighbour's region reaches outside it."""
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
    return mask


def instance_surface(points: np.ndarray, box) -> Surface | None:
    """The instance inside ``box`` (x, y, w, h pixels) from the frame's world points (H, W, 3): the
    region of a height watershed (:func:`instance_mask`) that matches the box; what it rests on is the
    low end of the heights around the box."""
    height_px, width_px = points.shape[:2]
    x, y, w, h = (float(v) for v in box)
    pad = max(6.0, 0.25 * max(w, h))
    r0, r1 = int(max(0, y - pad)), int(min(height_px, y + h + pad))
    c0, c1 = int(max(0, x - pad)), int(min(width_px, x + w + pad))
    b0, b1 = int(max(0, y)), int(min(height_px, np.ceil(y + h)))
    a0, a1 = int(max(0, x)), int(min(width_px, np.ceil(x + w)))
    if b1 - b0 < 2 or a1 - a0 < 2:
        return None
    z = points[b0:b1, a0:a1, 2]
    inner = z[int(0.2 * (b1 - b0)):max(int(0.2 * (b1 - b0)) + 1, int(0.8 * (b1 - b0))),
              int(0.2 * (a1 - a0)):max(int(0.2 * (a1 - a0)) + 1, int(0.8 * (a1 - a0)))]
    if not np.isfinite(inner).any():
        return None
    top = float(np.nanpercentile(inner, 95))
    around = points[r0:r1, c0:c1, 2]
    support = float(np.nanpercentile(around, 5))
    height = top - support
    if height < 0.005:
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
    return Surface(xy, centre, top, support, minor_yaw, elongation)


def footprint_heights(points: np.ndarray, camera: PinholeCamera, centre: np.ndarray, yaw: float, along: float,
                      gripper: JawGripper, z_ref: float, samples: tuple[int, int] = (3, 5)) -> np.ndarray:
    """Heights of the surfaces under one open finger (centre + ``along`` metres in the closing
    direction): a grid over the finger's footprint, each point looked up through the camera.
    NaN where the camera does not see the spot."""
    d = np.array([np.cos(yaw), np.sin(yaw)])
    j = np.array([-d[1], d[0]])
    a = np.linspace(-gripper.finger_thickness / 2, gripper.finger_thickness / 2, samples[0])
    b = np.linspace(-gripper.finger_width / 2, gripper.finger_width / 2, samples[1])
    grid = centre + (along + a)[:, None, None] * d + b[None, :, None] * j
    return surface_heights(points, camera, grid.reshape(-1, 2), z_ref)


def surface_heights(points: np.ndarray, camera: PinholeCamera, xy: np.ndarray, z_ref: float) -> np.ndarray:
    """World z of the surface seen at world ``xy`` (N, 2): the pixel where (x, y, z_ref) projects,
    its back-projected height. NaN outside the image or without a depth reading."""
    xy = np.asarray(xy, dtype=float)
    world = np.concatenate([xy, np.full((len(xy), 1), z_ref)], axis=1)
    pixels, _ = camera.project(world)
    u = np.rint(pixels[:, 0])
    v = np.rint(pixels[:, 1])
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u < points.shape[1]) & (v < points.shape[0])
    heights = np.full(len(xy), np.nan)
    heights[inside] = points[v[inside].astype(int), u[inside].astype(int), 2]
    return heights


def width_across(surface: Surface, centre: np.ndarray, yaw: float, gripper: JawGripper) -> tuple[float, float]:
    """The instance's extent along the closing direction within the fingers' band, and the offset of
    that extent's midpoint from ``centre`` (where the jaws should centre to squeeze evenly)."""
    d = np.array([np.cos(yaw), np.sin(yaw)])
    rel = surface.xy - centre
    along, across = rel @ d, rel @ np.array([-d[1], d[0]])
    band = np.abs(across) <= gripper.finger_width / 2 + 0.004
    if not band.any():
        return 0.0, 0.0
    low, high = float(along[band].min()), float(along[band].max())
    return high - low, (high + low) / 2


def yaws(count: int = 8, surface: Surface | None = None) -> list[float]:
    """``count`` yaws evenly over 180°, and the surface's principal minor axis first where given."""
    even = [np.pi * k / count for k in range(count)]
    return ([surface.minor_yaw] if surface is not None else []) + even


def describe(points: np.ndarray, camera: PinholeCamera, surface: Surface, centre, yaw: float, tips: float | None = None,
             gripper: JawGripper = JawGripper()) -> GraspCandidate:
    """The grasp with the jaws' centre at world ``centre`` (x, y), closing along ``yaw``: its fingertips'
    height (``tips``, or as deep as :meth:`Surface.tips_range` and the surfaces under the fingers
    allow), the instance's width across the jaws there, the fingers' clearance, and the reason it
    would be rejected (None: feasible)."""
    centre = np.asarray(centre, dtype=float)[:2]
    width, _ = width_across(surface, centre, yaw, gripper)
    reach = gripper.opening / 2 + gripper.finger_thickness / 2
    under = np.concatenate([footprint_heights(points, camera, centre, yaw, s * reach, gripper, surface.top) for s in (-1, 1)])
    seen = bool(np.isfinite(under).all())
    if tips is None:
        deepest, shallowest = surface.tips_range()
        tips = float(np.clip(np.max(under) + 0.003, deepest, shallowest)) if seen else deepest
    clearance = float(tips - np.max(under)) if seen else float("nan")
    candidate = GraspCandidate(np.array([centre[0], centre[1], tips]), float(np.mod(yaw, np.pi)), width, clearance,
                               surface.top, surface.support)
    if not seen:
        candidate.rejected = "finger outside the camera's view"
    elif width > gripper.opening - gripper.margin:
        candidate.rejected = f"too wide across the jaws ({width * 100:.1f} cm)"
    elif clearance < -BLOCK_TOLERANCE:
        candidate.rejected = f"finger blocked ({-clearance * 100:.1f} cm above the tips)"
    return candidate


def grasp_candidates(points: np.ndarray, camera: PinholeCamera, box, gripper: JawGripper = JawGripper(),
                     count: int = 8, offsets: np.ndarray | None = None) -> tuple[Surface | None, list[GraspCandidate]]:
    """Candidates for the instance in ``box``: per yaw (:func:`yaws`), the jaws centred on the
    instance's extent across them (and at ``offsets``, (K, 2) world xy shifts, if given), each with
    its width, clearance and the reason it is rejected. Empty when depth shows nothing in the box."""
    surface = instance_surface(points, box)
    if surface is None:
        return None, []
    shifts = [np.asarray(o, dtype=float) for o in offsets] if offsets is not None else []
    candidates = []
    for yaw in yaws(count, surface):
        _, middle = width_across(surface, surface.centre, yaw, gripper)
        even = surface.centre + middle * np.array([np.cos(yaw), np.sin(yaw)])  # both fingers meet it together
        for centre in [even] + [surface.centre + shift for shift in shifts]:
            candidates.append(describe(points, camera, surface, centre, yaw, gripper=gripper))
    return surface, candidates

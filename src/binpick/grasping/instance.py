"""The instance a detection points at, as the depth image shows it: a height watershed above the
support plane, the region matching its box (kept inside it, edges claimed by the nearest height), its
own pixels, top, the surface it rests on and its principal axes; points on it; heights seen at world
points. Both tools' candidates start from it (:mod:`binpick.grasping.candidates`, :mod:`binpick.grasping.suction`)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from binpick.grasping.frame import DepthFrame

FLOOR_CLEARANCE = 0.006  # fingertips stop this far above the surface the instance rests on
PALM_REACH = 0.07  # fingertips at most this far under the instance's top (8 cm fingers, the palm above them)
LEVEL_STEP = 0.0015  # the watershed floods the box's heights in steps of this many metres
JUMP = 0.01  # heights that change more than this within a pixel's 3x3 neighbourhood: an occluding edge


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

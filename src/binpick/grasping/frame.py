"""A depth frame made ready for grasp planning: holes filled, noise smoothed, the support surface found.

A real sensor's depth has no reading in shadows beside tall edges, on dark or shiny surfaces and at
the image border, and its readings are noisy. A pixel without a reading is *unknown*, not an obstacle
and not "outside the view": :meth:`DepthFrame.from_depth` fills the holes by inpainting (at half
resolution, as Dex-Net's GQ-CNN pipeline does) and remembers which pixels were read, so that a
finger's path is judged on the readings that exist. The surface the products rest on (the tote's
floor, or a table) is a plane fitted robustly in the base frame (RANSAC among near-level planes),
so a tilted camera or a tote that is not level changes nothing: the planner works with heights above
that plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from binpick.grasping.camera import PinholeCamera

MAX_PLANE_TILT = 25.0  # degrees: a support surface steeper than this is not one the planner expects
PLANE_TOLERANCE = 0.004  # m: points this close to a plane are on it
MIN_PLANE_SHARE = 0.05  # of the sampled points in the central window: less, and no plane is trusted


@dataclass
class DepthFrame:
    """World points of every pixel (holes filled), which pixels the sensor read, and the support plane."""

    camera: PinholeCamera
    points: np.ndarray  # (H, W, 3) float32 world xyz; NaN only where depth could not be filled
    valid: np.ndarray  # (H, W) bool: the sensor read this pixel
    plane: np.ndarray | None  # (a, b, c): the support surface z = a x + b y + c (None: none found)
    heights: np.ndarray  # (H, W) float32: height above the support plane (world z where there is none)
    filled: np.ndarray  # (H, W) float32: the depth (m along the optical axis) with its holes filled and smoothed

    @classmethod
    def from_depth(cls, depth: np.ndarray, camera: PinholeCamera, inpaint: bool = True, smooth: bool = True,
                   fit_plane: bool = True) -> DepthFrame:
        """``depth`` in metres along the optical axis (0 or non-finite: no reading)."""
        depth = np.asarray(depth, dtype=np.float32)
        valid = np.isfinite(depth) & (depth > 0)
        filled = np.where(valid, depth, np.float32(0.0))
        if inpaint and not valid.all() and valid.any():
            filled = fill_holes(filled, valid)
        if smooth:
            known = filled > 0
            smoothed = cv2.medianBlur(filled, 5)  # noise and flying pixels; edges stay where they are
            filled = np.where(known & (smoothed > 0), smoothed, filled)
        points = camera.points(filled)
        plane = support_plane(points, valid) if fit_plane else None
        heights = points[..., 2] - plane_z(plane, points[..., 0], points[..., 1]) if plane is not None else points[..., 2].copy()
        return cls(camera, points, valid, plane, heights.astype(np.float32), filled)

    @property
    def missing(self) -> float:
        """The share of pixels the sensor did not read."""
        return float(1.0 - self.valid.mean())

    def support_z(self, xy) -> np.ndarray | float:
        """World z of the support plane under world ``xy`` (..., 2); 0 where there is no plane."""
        xy = np.asarray(xy, dtype=float)
        return plane_z(self.plane, xy[..., 0], xy[..., 1]) if self.plane is not None else np.zeros(xy.shape[:-1])


def plane_z(plane: np.ndarray | None, x, y):
    a, b, c = plane
    return a * x + b * y + c


def fill_holes(depth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Depth with every pixel lacking a reading filled from its surroundings: OpenCV's inpainting
    (Navier-Stokes) at half resolution (holes of a few pixels to a few centimetres), upsampled into
    the holes only.
    It inpaints whole millimetres in 16 bits: on float images OpenCV's inpainting leaves values far
    outside the surrounding depths."""
    height, width = depth.shape
    small_size = (max(1, width // 2), max(1, height // 2))
    millimetres = np.clip(np.round(np.where(valid, depth, 0) * 1000.0), 0, 65535).astype(np.uint16)
    small = cv2.resize(millimetres, small_size, interpolation=cv2.INTER_NEAREST)
    holes = (small == 0).astype(np.uint8)
    if holes.all():
        return depth
    if holes.any():
        small = cv2.inpaint(small, holes, 3, cv2.INPAINT_NS)
    up = cv2.resize(small.astype(np.float32) / 1000.0, (width, height), interpolation=cv2.INTER_LINEAR)
    return np.where(valid, depth, up).astype(np.float32)


def support_plane(points: np.ndarray, valid: np.ndarray, samples: int = 1500, iterations: int = 300,
                  seed: int = 0) -> np.ndarray | None:
    """The surface the products rest on, (a, b, c) with z = a x + b y + c in the base frame: among
    near-level planes (within MAX_PLANE_TILT of level) through sampled read points of the image's
    central window (where a camera aimed at a bin sees its floor), the one with most points on it,
    preferring the lowest of those with nearly as many (a product's broad top is a plane too), refit
    by least squares on its points. None when no plane holds enough of them (a bin filled to the top)."""
    height, width = valid.shape
    rng = np.random.default_rng(seed)
    rows = rng.integers(height // 6, height - height // 6, size=4 * samples)  # pixels of the central window
    cols = rng.integers(width // 6, width - width // 6, size=4 * samples)
    cloud = points[rows, cols][valid[rows, cols]].astype(np.float64)
    cloud = cloud[np.isfinite(cloud).all(axis=1)][:samples]
    if len(cloud) < 50:
        return None
    # half the triples drawn anywhere, half from one neighbourhood of the image (three pixels within
    # 20 of each other): in a full bin a patch of visible floor gives whole triples, where three
    # points drawn anywhere rarely all land on it
    local = iterations // 2
    r = rng.integers(height // 6, height - height // 6, size=local)[:, None] + np.concatenate(
        [np.zeros((local, 1), int), rng.integers(-20, 21, size=(local, 2))], axis=1)
    c = rng.integers(width // 6, width - width // 6, size=local)[:, None] + np.concatenate(
        [np.zeros((local, 1), int), rng.integers(-20, 21, size=(local, 2))], axis=1)
    r, c = np.clip(r, 0, height - 1), np.clip(c, 0, width - 1)
    near = points[r, c].astype(np.float64)[valid[r, c].all(axis=1)]
    triples = np.concatenate([near[np.isfinite(near).all(axis=(1, 2))],
                              cloud[rng.integers(0, len(cloud), size=(iterations - local, 3))]])
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    lengths = np.linalg.norm(normals, axis=1)
    usable = lengths > 1e-9
    normals, triples = normals[usable] / lengths[usable, None], triples[usable]
    normals *= np.sign(normals[:, 2:3] + 1e-12)
    level = normals[:, 2] >= np.cos(np.radians(MAX_PLANE_TILT))
    normals, triples = normals[level], triples[level]
    if not len(normals):
        return None
    offsets = -np.sum(normals * triples[:, 0], axis=1)
    distances = np.abs(cloud @ normals.T + offsets)  # (points, planes)
    counts = (distances < PLANE_TOLERANCE).sum(axis=0)
    if counts.max() < MIN_PLANE_SHARE * len(cloud):
        return None
    centre = cloud[:, :2].mean(axis=0)
    z_at_centre = -(offsets + normals[:, :2] @ centre) / normals[:, 2]
    strong = counts >= 0.5 * counts.max()  # the lowest of the well-supported planes: the floor, not a product's top
    best = int(np.flatnonzero(strong)[np.argmin(z_at_centre[strong])])
    inliers = distances[:, best] < PLANE_TOLERANCE
    design = np.column_stack([cloud[:, 0], cloud[:, 1], np.ones(len(cloud))])
    for _ in range(3):  # refit on the plane's points, then take the points of the refit plane
        coefficients, *_ = np.linalg.lstsq(design[inliers], cloud[inliers, 2], rcond=None)
        inliers = np.abs(design @ coefficients - cloud[:, 2]) < PLANE_TOLERANCE
    return coefficients

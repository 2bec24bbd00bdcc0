"""Before a grasp: does the detection look like the ordered product? A colour check between the
shop photo's product pixels and the detection's product pixels (those standing above what the
products rest on, from depth), by hue-saturation histogram intersection (Swain & Ballard 1991).
Brightness is left out: the studio and the bin are lit differently, and on tuning bins it cost
held-out products (a white brick) their right detections. The detector ranks instances by shape and
pickability; this catches the confident detections of a product of another colour, which would
otherwise end up in the customer's tote.

It holds where both sides share a light: a query box and its copies in one frame. Between a studio
photo and a warehouse bin it does not (AUC 0.97 in binpick's own light, 0.72 under a warm hard one:
``experiments/verify.py``); there the learnt :mod:`binpick.detection.verifier` checks instead.

Camera-agnostic: the product pixels come from the frame's world points (any calibrated camera,
any pose), not from a simulator's floor height.
"""

from __future__ import annotations

import cv2
import numpy as np

BINS = [12, 4]  # hue, saturation
RANGES = [0, 180, 0, 256]
ABOVE_SUPPORT = 0.005  # metres: pixels this far above what the products rest on are product pixels


def colour_histogram(rgb: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """L1-normalised hue-saturation histogram of the masked pixels (all pixels without a mask)."""
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    mask = None if mask is None else mask.astype(np.uint8)
    hist = cv2.calcHist([hsv], [0, 1], mask, BINS, RANGES).ravel()
    return hist / max(float(hist.sum()), 1.0)


def detection_mask(points: np.ndarray, box_xywh, support: float | None = None) -> np.ndarray:
    """The box's pixels standing above what the products rest on: ``support`` (the bin floor's
    height, where known), else the low end (5th percentile) of the heights in and around the box,
    as the grasp planner estimates it. ``points``: the frame's world xyz (H, W, 3), or its heights
    (H, W), e.g. above the support plane (:attr:`binpick.grasping.DepthFrame.heights`)."""
    points = points[..., None] if points.ndim == 2 else points[..., 2:3]
    height_px, width_px = points.shape[:2]
    mask = np.zeros((height_px, width_px), bool)
    x, y, w, h = (float(v) for v in box_xywh)
    y0, y1 = int(max(0, round(y))), int(min(height_px, round(y + h)))
    x0, x1 = int(max(0, round(x))), int(min(width_px, round(x + w)))
    if y1 <= y0 or x1 <= x0:
        return mask
    if support is None:
        pad = max(6.0, 0.25 * max(w, h))
        around = points[int(max(0, y - pad)):int(min(height_px, y + h + pad)), int(max(0, x - pad)):int(min(width_px, x + w + pad)), 0]
        if not np.isfinite(around).any():
            return mask
        support = float(np.nanpercentile(around, 5))
    with np.errstate(invalid="ignore"):
        mask[y0:y1, x0:x1] = points[y0:y1, x0:x1, 0] > support + ABOVE_SUPPORT  # NaN (no reading): not a product pixel
    return mask


def colour_similarity(photo_hist: np.ndarray, rgb: np.ndarray, points: np.ndarray, box_xywh, support: float | None = None) -> float:
    """Histogram intersection in [0, 1] between the photo's product and the detection's."""
    mask = detection_mask(points, box_xywh, support)
    if not mask.any():
        return 0.0
    return float(np.minimum(photo_hist, colour_histogram(rgb, mask)).sum())

"""Before a grasp: does the detection look like the ordered product? A colour check between the
shop photo's product pixels and the detection's product pixels (those standing above the bin floor
in the depth image), by hue-saturation histogram intersection (Swain & Ballard 1991). Brightness is
left out: the studio and the bin are lit differently, and on tuning bins it cost held-out products
(a white brick) their right detections. The
detector ranks instances by shape and pickability; this catches the confident detections of a
product of another colour, which would otherwise end up in the customer's tote.
"""

from __future__ import annotations

import cv2
import numpy as np

from binpick.sim.mjcf import FLOOR_TOP, CameraSpec

BINS = [12, 4]  # hue, saturation
RANGES = [0, 180, 0, 256]


def colour_histogram(rgb: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """L1-normalised hue-saturation histogram of the masked pixels (all pixels without a mask)."""
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    mask = None if mask is None else mask.astype(np.uint8)
    hist = cv2.calcHist([hsv], [0, 1], mask, BINS, RANGES).ravel()
    return hist / max(float(hist.sum()), 1.0)


def photo_mask(photo: np.ndarray) -> np.ndarray:
    """The product's pixels in a user's photo on a light, plain background: what is not bright and grey."""
    hsv = cv2.cvtColor(np.ascontiguousarray(photo), cv2.COLOR_RGB2HSV)
    return ~((hsv[..., 1] < 30) & (hsv[..., 2] > 150))


def detection_mask(depth: np.ndarray, box_xywh, camera: CameraSpec, above_floor: float = 0.005) -> np.ndarray:
    """The box's pixels that stand above the bin floor (the products, not the floor between them)."""
    mask = np.zeros(depth.shape, bool)
    x, y, w, h = (int(round(v)) for v in box_xywh)
    x0, y0 = max(0, x), max(0, y)
    region = depth[y0:max(y0, y + h), x0:max(x0, x + w)]
    mask[y0:y0 + region.shape[0], x0:x0 + region.shape[1]] = region < camera.height - FLOOR_TOP - above_floor
    return mask


def colour_similarity(photo_hist: np.ndarray, rgb: np.ndarray, depth: np.ndarray, box_xywh, camera: CameraSpec) -> float:
    """Histogram intersection in [0, 1] between the photo's product and the detection's."""
    mask = detection_mask(depth, box_xywh, camera)
    if not mask.any():
        return 0.0
    return float(np.minimum(photo_hist, colour_histogram(rgb, mask)).sum())

"""Shop photos as queries (§6.3): the product's own pixels, framed tightly.

A shop photo shows the product small on a plain studio background, seen from the side; in the bin the
same product is a few dozen pixels seen from above. Matched whole, the photo's features are mostly
background, and at the photo's scale the backbone sees the product far larger than in the bin (the
crop-trained weights scored AP50 0.35 with whole photos and 0.59 with framed ones matched at four
sizes around an instance's, on binpick's own seen products, before any training on photos). So a photo query is cropped to its product first,
then matched at a few sizes relative to the scene image (``ModelSpec.photo_sizes``).
"""

from __future__ import annotations

import cv2
import numpy as np

MARGIN = 0.04  # of the product's width and height, kept around it when framing


def photo_mask(photo: np.ndarray) -> np.ndarray:
    """The product's pixels in a shop photo: the alpha channel of a cut-out RGBA photo, else what is
    not bright and grey (a light, plain background)."""
    photo = np.asarray(photo)
    if photo.ndim == 3 and photo.shape[2] == 4:
        return photo[..., 3] > 127
    hsv = cv2.cvtColor(np.ascontiguousarray(photo[..., :3]), cv2.COLOR_RGB2HSV)
    return ~((hsv[..., 1] < 30) & (hsv[..., 2] > 150))


def product_box(photo: np.ndarray) -> tuple[int, int, int, int] | None:
    """(x1, y1, x2, y2) around the product's pixels plus a small margin; None when the mask is
    empty or covers the whole photo (nothing to frame: a photo that is all product, or all white)."""
    mask = photo_mask(photo)
    if mask.all() or mask.sum() < 16:
        return None
    ys, xs = np.nonzero(mask)
    x1, x2 = np.percentile(xs, [0.5, 99.5])  # a few stray pixels (noise, a shadow's edge) do not widen it
    y1, y2 = np.percentile(ys, [0.5, 99.5])
    dx, dy = MARGIN * (x2 - x1) + 1, MARGIN * (y2 - y1) + 1
    height, width = mask.shape
    return (int(max(0, x1 - dx)), int(max(0, y1 - dy)), int(min(width, x2 + dx + 1)), int(min(height, y2 + dy + 1)))


def framed_on_product(photo: np.ndarray) -> np.ndarray:
    """The photo's RGB cropped to its product (the whole photo when no product can be told apart)."""
    photo = np.asarray(photo)
    box = product_box(photo)
    rgb = photo[..., :3]
    if box is None:
        return np.ascontiguousarray(rgb)
    x1, y1, x2, y2 = box
    return np.ascontiguousarray(rgb[y1:y2, x1:x2])

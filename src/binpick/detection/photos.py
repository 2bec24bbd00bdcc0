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
    """The product's pixels in a shop photo: the alpha channel of a cut-out RGBA photo; on a light plain
    background (most of the border light), what is not bright and grey; on another background, what
    differs from the photo's border (a plain one: by colour distance; a textured one: GrabCut, the
    border as probable background). A photo in which nothing differs from its border is a crop of
    the product itself: all of it (an empty mask would describe no product)."""
    photo = np.asarray(photo)
    if photo.ndim == 3 and photo.shape[2] == 4:
        return photo[..., 3] > 127
    rgb = np.ascontiguousarray(photo[..., :3], dtype=np.uint8)
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    light = (hsv[..., 1] < 30) & (hsv[..., 2] > 150)
    edge = max(2, min(rgb.shape[:2]) // 40)
    border = np.ones(rgb.shape[:2], bool)
    border[edge:-edge, edge:-edge] = False
    if light[border].mean() > 0.5 and not light.all():  # a studio's white: the product may touch the frame (a tight crop)
        return ~light
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
    lab[..., 0] *= 0.5  # a shadow on the background differs from it mostly in lightness
    reference = np.median(lab[border], axis=0)
    distance = np.linalg.norm(lab - reference, axis=2)
    spread = float(np.percentile(distance[border], 90))
    plain = distance > max(18.0, 2.0 * spread)
    if spread < 12.0:  # a plain background
        return plain if plain.any() else np.ones_like(plain)  # nothing differs from the border: the product fills it
    found = _grabcut(rgb, border)
    found = found if found.mean() > 0.01 else plain
    return found if found.any() else np.ones_like(found)


def _grabcut(rgb: np.ndarray, border: np.ndarray) -> np.ndarray:
    """Foreground by GrabCut: the border probably background, the rest probably the product."""
    height, width = rgb.shape[:2]
    if min(height, width) < 16:
        return np.ones((height, width), bool)
    scale = 96.0 / max(height, width)
    if scale < 1.0:  # at most 96 px a side: a tenth of the time, and the framing box is all that is used
        size = (max(16, round(width * scale)), max(16, round(height * scale)))
        small = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
        small_border = cv2.resize(border.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
        found = _grabcut(small, small_border).astype(np.uint8)
        return cv2.resize(found, (width, height), interpolation=cv2.INTER_NEAREST) > 0
    mask = np.where(border, cv2.GC_PR_BGD, cv2.GC_PR_FGD).astype(np.uint8)
    background, foreground = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    try:
        cv2.grabCut(rgb, mask, None, background, foreground, 3, cv2.GC_INIT_WITH_MASK)
    except cv2.error:
        return np.ones((height, width), bool)
    return (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)


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

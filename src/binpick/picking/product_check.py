"""Is this detection the ordered product? The picker's product check: against shop photos the learnt
verifier (:mod:`binpick.detection.verifier`, a calibrated probability) or the older colour check;
against a query box, colours in the frame's own light, instance pixels to instance pixels."""

from __future__ import annotations

import numpy as np

from binpick.detection.photos import photo_mask
from binpick.grasping import DepthFrame
from binpick.picking.colour import colour_histogram, colour_similarity
from binpick.picking.find_again import instance_pixels, instance_similarity

VERIFIERS = ("learnt", "colour")
# the learnt check's is a probability (calibrated on randomised bins): detections it gives under 20% are
# dropped and the rest ranked by detector score times it. On tuning bins (40 orders each, seeds apart from
# the benchmarks') 0.2 put a right instance first in 31 of 40 shifted-light orders against 25 at 0.5, the
# wrong-first orders staying 2 of 40, and changed nothing in binpick's own light (36 right first at every
# threshold from 0.1 to 0.5). The colour check's is a histogram intersection, tuned in binpick's own light.
THRESHOLDS = {"learnt": 0.2, "colour": 0.15}
# Against a query box the check compares colours in one frame, one light, instance pixels to instance
# pixels: on 42 bins (seeds apart from the benchmarks', 1-5 copies) the other copies of a pointed
# instance scored 0.91 at the median and 92% of them at least 0.5; 5% of other products' instances
# reached 0.5 (13% passed the shop-photo colour threshold of 0.15). Lifting another product is worse
# than leaving a copy, so detections under 0.5 are not its copies.
QUERY_CHECK = 0.5


def frame_windows(verifier, rgb: np.ndarray, depth: np.ndarray, photos):
    """The learnt ``verifier``'s windows of this frame, read once per plan for the check against the
    photos and the detections' agreement; None where no learnt check reads them (no check, the colour
    check, a query box instead of photos)."""
    if not photos or verifier is None or isinstance(verifier, str):
        return None
    return verifier.windows(rgb, depth) if hasattr(verifier, "windows") else None


def product_scores(verifier, rgb: np.ndarray, depth: np.ndarray, frame: DepthFrame, boxes: np.ndarray,
                   photos: list[tuple[np.ndarray, np.ndarray | None]], query_box, windows=None) -> list[float | None]:
    """The product check's score of each box (``verifier``: None, ``"colour"`` or a learnt one): against
    a query box, colour similarity to the pointed instance's pixels (same frame, same light); against
    photos, the verifier's (best over the photos; on depth as read, holes as holes, as it was trained;
    ``windows``: :func:`frame_windows`)."""
    if verifier is None or not len(boxes):
        return [None] * len(boxes)
    if query_box is not None:
        mask = instance_pixels(frame, query_box)
        histogram = colour_histogram(rgb, mask if mask.any() else None)
        return [instance_similarity(histogram, rgb, frame, box) for box in boxes]
    if verifier == "colour":
        histograms = [colour_histogram(image, photo_mask(image) if mask is None else mask) for image, mask in photos]
        return [max(colour_similarity(h, rgb, frame.heights, box) for h in histograms) for box in boxes]
    images, masks = [image for image, _ in photos], [mask for _, mask in photos]
    probabilities = (verifier.probabilities(images, masks, rgb, depth, boxes, windows=windows) if windows is not None
                     else verifier.probabilities(images, masks, rgb, depth, boxes))
    return [float(p) for p in probabilities]

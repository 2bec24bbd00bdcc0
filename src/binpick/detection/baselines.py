"""Classical baselines a user would try first.

Template matching: the query's crop is matched (normalised cross-correlation, ``TM_CCOEFF_NORMED``)
at several scales and the four right-angle rotations; local maxima above a threshold become boxes
of the template's size, scored by the match.

Colour histogram back-projection (Swain & Ballard): the ratio of the query's hue-saturation
histogram to the image's, projected back onto the pixels, gives how query-coloured each pixel is;
a box scores the mean of that inside it minus the mean in a ring around it (centre-surround), at
several sizes and both orientations.

Both suppress overlapping boxes and drop boxes on the query itself, which is known.
"""

from __future__ import annotations

import numpy as np
import torch

from binpick.detection.ops import box_iou, nms

SCALES = (0.7, 0.85, 1.0, 1.2, 1.4)


def _pixel_bounds(box: np.ndarray, width: int, height: int) -> tuple[int, int, int, int]:
    """Integer pixel bounds of a float xyxy box inside the image, at least 2 pixels a side."""
    x1, y1 = int(np.clip(np.floor(box[0]), 0, width - 2)), int(np.clip(np.floor(box[1]), 0, height - 2))
    return x1, y1, int(np.clip(np.ceil(box[2]), x1 + 2, width)), int(np.clip(np.ceil(box[3]), y1 + 2, height))


def template_matches(image: np.ndarray, query_box: np.ndarray, scales=SCALES, threshold: float = 0.2,
                     iou_threshold: float = 0.3, max_detections: int = 100) -> dict[str, torch.Tensor]:
    """Boxes (xyxy) and scores for one RGB uint8 image and its query box."""
    import cv2

    height, width = image.shape[:2]
    x1, y1, x2, y2 = _pixel_bounds(query_box, width, height)
    template = image[y1:y2, x1:x2]
    boxes, scores = [], []
    for scale in scales:
        resized = cv2.resize(template, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
        for turns in range(4):
            kernel = np.ascontiguousarray(np.rot90(resized, turns))
            kh, kw = kernel.shape[:2]
            if kh < 4 or kw < 4 or kh >= height or kw >= width:
                continue
            response = cv2.matchTemplate(image, kernel, cv2.TM_CCOEFF_NORMED)
            peaks = (response >= threshold) & (response == cv2.dilate(response, np.ones((5, 5), np.uint8)))
            ys, xs = np.nonzero(peaks)
            for y, x in zip(ys, xs):
                boxes.append([x, y, x + kw, y + kh])
                scores.append(float(response[y, x]))
    return _finish(boxes, scores, query_box, iou_threshold, max_detections)


def _finish(boxes: list, scores: list, query_box: np.ndarray, iou_threshold: float, max_detections: int) -> dict[str, torch.Tensor]:
    """Drop boxes on the query, keep the best 2000 (NMS is quadratic), suppress overlaps."""
    if not boxes:
        return {"boxes": torch.zeros(0, 4), "scores": torch.zeros(0)}
    boxes_t, scores_t = torch.tensor(boxes, dtype=torch.float32), torch.tensor(scores, dtype=torch.float32)
    not_query = box_iou(boxes_t, torch.tensor(query_box, dtype=torch.float32)[None])[:, 0] < 0.5
    boxes_t, scores_t = boxes_t[not_query], scores_t[not_query]
    best = scores_t.argsort(descending=True)[:2000]
    boxes_t, scores_t = boxes_t[best], scores_t[best]
    keep = nms(boxes_t, scores_t, iou_threshold)[:max_detections]
    return {"boxes": boxes_t[keep], "scores": scores_t[keep]}


def histogram_matches(image: np.ndarray, query_box: np.ndarray, scales=SCALES, iou_threshold: float = 0.3,
                      max_detections: int = 100) -> dict[str, torch.Tensor]:
    """Boxes (xyxy) and scores by hue-saturation histogram back-projection with a centre-surround score."""
    import cv2

    height, width = image.shape[:2]
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
    x1, y1, x2, y2 = _pixel_bounds(query_box, width, height)
    bins, ranges = [12, 6], [0, 180, 0, 256]
    query_hist = cv2.calcHist([hsv[y1:y2, x1:x2]], [0, 1], None, bins, ranges)
    image_hist = cv2.calcHist([hsv], [0, 1], None, bins, ranges)
    ratio = np.minimum(query_hist / query_hist.sum() / np.maximum(image_hist / image_hist.sum(), 1e-9), 1.0)
    hue, saturation = (hsv[..., 0].astype(int) * bins[0]) // 180, (hsv[..., 1].astype(int) * bins[1]) // 256
    belief = ratio[hue, saturation].astype(np.float64)
    integral = cv2.integral(belief)

    def box_sum(xa, ya, xb, yb):
        return integral[yb, xb] - integral[ya, xb] - integral[yb, xa] + integral[ya, xa]

    boxes, scores = [], []
    qw, qh = x2 - x1, y2 - y1
    for scale in scales:
        for w, h in {(int(qw * scale), int(qh * scale)), (int(qh * scale), int(qw * scale))}:
            if w < 4 or h < 4 or w >= width or h >= height:
                continue
            step = max(2, min(w, h) // 6)
            ys, xs = np.mgrid[0:height - h:step, 0:width - w:step]
            xs, ys = xs.ravel(), ys.ravel()
            inside = box_sum(xs, ys, xs + w, ys + h) / (w * h)
            mx, my = w // 4, h // 4  # the ring: a quarter of the box on each side, clipped to the image
            ox1, oy1 = np.maximum(xs - mx, 0), np.maximum(ys - my, 0)
            ox2, oy2 = np.minimum(xs + w + mx, width), np.minimum(ys + h + my, height)
            ring_area = (ox2 - ox1) * (oy2 - oy1) - w * h
            ring = (box_sum(ox1, oy1, ox2, oy2) - inside * w * h) / np.maximum(ring_area, 1)
            score = inside - ring
            top = np.argsort(-score)[:300]
            boxes += [[float(xs[i]), float(ys[i]), float(xs[i] + w), float(ys[i] + h)] for i in top if score[i] > 0.05]
            scores += [float(score[i]) for i in top if score[i] > 0.05]
    return _finish(boxes, scores, query_box, iou_threshold, max_detections)


def _per_image(match):
    """The evaluation interface (:func:`binpick.detection.evaluate.collect`) for a per-image matcher."""
    def detect(batch: dict) -> list[dict[str, torch.Tensor]]:
        images = (batch["image"].permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8)
        return [match(image, box.numpy()) for image, box in zip(images, batch["query_box"])]
    return detect


histogram_detect = _per_image(histogram_matches)
template_detect = _per_image(template_matches)

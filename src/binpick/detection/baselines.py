"""The classical baseline a user would try first: OpenCV multi-scale template matching of the query.

The query's crop is matched (normalised cross-correlation, ``TM_CCOEFF_NORMED``) at several scales
and the four right-angle rotations; local maxima above a threshold become boxes of the template's
size, scored by the match, and overlapping boxes are suppressed. The query itself is known, so boxes
on it are dropped.
"""

from __future__ import annotations

import numpy as np
import torch

from binpick.detection.ops import box_iou, nms

SCALES = (0.7, 0.85, 1.0, 1.2, 1.4)


def template_matches(image: np.ndarray, query_box: np.ndarray, scales=SCALES, threshold: float = 0.2,
                     iou_threshold: float = 0.3, max_detections: int = 100) -> dict[str, torch.Tensor]:
    """Boxes (xyxy) and scores for one RGB uint8 image and its query box."""
    import cv2

    height, width = image.shape[:2]
    x1, y1 = int(max(0, np.floor(query_box[0]))), int(max(0, np.floor(query_box[1])))
    x2, y2 = int(min(width, np.ceil(query_box[2]))), int(min(height, np.ceil(query_box[3])))
    template = image[y1:max(y2, y1 + 2), x1:max(x2, x1 + 2)]
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
    if not boxes:
        return {"boxes": torch.zeros(0, 4), "scores": torch.zeros(0)}
    boxes_t, scores_t = torch.tensor(boxes, dtype=torch.float32), torch.tensor(scores, dtype=torch.float32)
    not_query = box_iou(boxes_t, torch.tensor(query_box, dtype=torch.float32)[None])[:, 0] < 0.5
    boxes_t, scores_t = boxes_t[not_query], scores_t[not_query]
    best = scores_t.argsort(descending=True)[:2000]  # NMS is quadratic
    boxes_t, scores_t = boxes_t[best], scores_t[best]
    keep = nms(boxes_t, scores_t, iou_threshold)[:max_detections]
    return {"boxes": boxes_t[keep], "scores": scores_t[keep]}


def template_detect(batch: dict) -> list[dict[str, torch.Tensor]]:
    """The evaluation interface (:func:`binpick.detection.evaluate.collect`) for template matching."""
    images = (batch["image"].permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8)
    return [template_matches(image, box.numpy()) for image, box in zip(images, batch["query_box"])]

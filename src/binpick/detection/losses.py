"""The ROD losses (thesis Eq 5.13-5.15, 5.20-5.24): L_ROD = L_bbox + L_obj + L_h.

Responsibility (Eq 5.21): each ground-truth box is predicted by the cell-anchor pair whose decoded
box has the highest GIoU with it. We search the cells that contain the box's centre at each level
(3 levels × 3 anchors), because a cell's box centre is ``σ(t) + c`` and can only reach its own
cell; a pair already taken by another box goes to that box's next best.

L_bbox (Eq 5.22) is the squared error of the responsible pair's box in the parameters the head
predicts — centre within the cell (σ(t_x), σ(t_y)) and log-size relative to the anchor (t_w, t_h) —
so errors of large and small boxes weigh alike. L_obj (Eq 5.23, whose printed minus sign before β
is a typo for a plus) pushes responsible objectness to 1 and the others to 0, weighted by β; as in
YOLOv3, pairs whose box already overlaps a ground truth by more than ``ignore_iou`` are left out of
the negatives. L_h (Eq 5.15) is the mean squared error between each ROD module's max heatmap and
Gaussians (Eq 5.13-5.14, σ in cells) at the target boxes' centres; the Gaussians peak at 1, the
value a perfect match reaches with our normalised correlation.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from binpick.detection.model import STRIDES, DetectorNetwork
from binpick.detection.ops import box_iou, generalized_box_iou, xyxy_to_cxcywh


@dataclass(frozen=True)
class LossWeights:
    """The ``loss:`` section of a detector config."""

    bbox: float = 1.0
    obj: float = 1.0
    heatmap: float = 1.0  # 0: "ROD without L_h"
    beta: float = 0.5  # weight of the no-object term (Eq 5.23)
    sigma: float = 1.0  # Gaussian width in feature cells (Eq 5.14)
    ignore_iou: float = 0.5

    def __post_init__(self) -> None:
        from binpick.config import check_range

        for name in ("bbox", "obj", "heatmap", "beta"):
            check_range(f"loss.{name}", getattr(self, name), 0, 1000)
        check_range("loss.sigma", self.sigma, 0, 100, low_inclusive=False)
        check_range("loss.ignore_iou", self.ignore_iou, 0, 1)


def assign(model: DetectorNetwork, raw: list[torch.Tensor], boxes: torch.Tensor, targets: torch.Tensor
           ) -> list[tuple[int, int, int, int, int]]:
    """Eq 5.21 for one image: (target index, level, anchor, row, column) of each responsible pair.
    ``boxes`` are the image's decoded predictions (N, 4), in the order :meth:`DetectorNetwork.decode` gives."""
    if len(targets) == 0:
        return []
    offsets, offset = [], 0
    for r in raw:
        offsets.append(offset)
        offset += r.shape[1] * r.shape[3] * r.shape[4]
    centres = xyxy_to_cxcywh(targets)
    pairs, taken = [], set()
    for t in range(len(targets)):
        candidates = []  # (level, anchor, row, col, flat index into boxes)
        for level, (r, stride) in enumerate(zip(raw, STRIDES)):
            _, anchors, _, height, width = r.shape
            col = int(torch.clamp(centres[t, 0] // stride, 0, width - 1))
            row = int(torch.clamp(centres[t, 1] // stride, 0, height - 1))
            for a in range(anchors):
                candidates.append((level, a, row, col, offsets[level] + (a * height + row) * width + col))
        flat = torch.tensor([c[4] for c in candidates])
        giou = generalized_box_iou(targets[t:t + 1], boxes[flat])[0]
        for choice in giou.argsort(descending=True).tolist():
            key = candidates[choice][:4]
            if key not in taken:
                taken.add(key)
                pairs.append((t, *key))
                break
    return pairs


def gaussian_targets(boxes: torch.Tensor, height: int, width: int, stride: int, sigma: float) -> torch.Tensor:
    """Eq 5.13-5.14: a sum of Gaussians (peak 1) at the boxes' centres on an H × W feature grid."""
    ys = torch.arange(height, dtype=torch.float32)[:, None] + 0.5
    xs = torch.arange(width, dtype=torch.float32)[None, :] + 0.5
    target = torch.zeros(height, width)
    for cx, cy, _, _ in xyxy_to_cxcywh(boxes).tolist():
        target += torch.exp(-((xs - cx / stride) ** 2 + (ys - cy / stride) ** 2) / (2 * sigma ** 2))
    return target


def rod_loss(model: DetectorNetwork, out: dict, targets: list[torch.Tensor], weights: LossWeights) -> dict[str, torch.Tensor]:
    """Batch mean of L_bbox, L_obj and L_h, and their weighted sum ``total``."""
    raw = out["raw"]
    boxes, _ = model.decode([r.detach() for r in raw])
    batch = raw[0].shape[0]
    l_bbox = raw[0].new_zeros(())
    positives = [torch.zeros(r.shape[0], r.shape[1], r.shape[3], r.shape[4], dtype=torch.bool) for r in raw]
    for b in range(batch):
        for t, level, a, row, col in assign(model, raw, boxes[b], targets[b]):
            stride = STRIDES[level]
            cx, cy, w, h = xyxy_to_cxcywh(targets[b][t:t + 1])[0]
            anchor = model.anchors[level, a]
            predicted = raw[level][b, a, :4, row, col]
            goal_xy = torch.stack([cx / stride - col, cy / stride - row]).clamp(1e-4, 1 - 1e-4)
            goal_wh = torch.log(torch.stack([w, h]).clamp(min=1.0) / anchor)
            l_bbox = l_bbox + ((torch.sigmoid(predicted[:2]) - goal_xy) ** 2).sum() + ((predicted[2:] - goal_wh) ** 2).sum()
            positives[level][b, a, row, col] = True
    l_obj = raw[0].new_zeros(())
    offset = 0
    for level, r in enumerate(raw):
        objectness = torch.sigmoid(r[:, :, 4])
        count = r.shape[1] * r.shape[3] * r.shape[4]
        ignore = torch.zeros_like(positives[level])
        for b in range(batch):
            if len(targets[b]):
                best = box_iou(boxes[b, offset:offset + count], targets[b]).amax(1)
                ignore[b] = (best > weights.ignore_iou).view(ignore[b].shape)
        positive = positives[level]
        negative = ~positive & ~ignore
        l_obj = l_obj + ((1 - objectness[positive]) ** 2).sum() + weights.beta * (objectness[negative] ** 2).sum()
        offset += count
    l_h = raw[0].new_zeros(())
    modules = 0
    for level, heatmap in enumerate(out["heatmaps"]):
        if heatmap is None:
            continue
        modules += 1
        _, _, height, width = heatmap.shape
        goal = torch.stack([gaussian_targets(targets[b], height, width, STRIDES[level], weights.sigma) for b in range(batch)])
        l_h = l_h + ((heatmap[:, 0] - goal.to(heatmap)) ** 2).mean()
    l_bbox, l_obj = l_bbox / batch, l_obj / batch
    total = weights.bbox * l_bbox + weights.obj * l_obj + weights.heatmap * l_h
    return {"total": total, "bbox": l_bbox.detach(), "obj": l_obj.detach(), "heatmap": l_h.detach()}

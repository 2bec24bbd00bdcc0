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
from binpick.detection.ops import generalized_box_iou, xyxy_to_cxcywh


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
        from binpick.core.config import check_range

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


def _elementwise_giou(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """GIoU of boxes ``a`` (..., 4) with ``b`` (..., 4), pair by pair (xyxy)."""
    lt, rb = torch.maximum(a[..., :2], b[..., :2]), torch.minimum(a[..., 2:], b[..., 2:])
    inter = (rb - lt).clamp(min=0).prod(-1)
    area_a, area_b = (a[..., 2:] - a[..., :2]).clamp(min=0).prod(-1), (b[..., 2:] - b[..., :2]).clamp(min=0).prod(-1)
    union = area_a + area_b - inter
    hull = (torch.maximum(a[..., 2:], b[..., 2:]) - torch.minimum(a[..., :2], b[..., :2])).clamp(min=0).prod(-1)
    return inter / union.clamp(min=1e-9) - (hull - union) / hull.clamp(min=1e-9)


def assign_batch(raw: list[torch.Tensor], boxes: torch.Tensor, targets: list[torch.Tensor]) -> tuple[torch.Tensor, ...]:
    """:func:`assign` for a whole batch at once (same pairs, same tie rules): every target's nine
    candidates (3 levels × 3 anchors at the cells holding its centre) are scored in one GIoU call,
    and only the choice of the best untaken candidate runs in Python, on small CPU arrays.
    Returns index tensors (batch, target row in ``torch.cat(targets)``, level, anchor, row, col)."""
    device = boxes.device
    counts = [len(t) for t in targets]
    empty = torch.zeros(0, dtype=torch.long)
    if sum(counts) == 0:
        return (empty,) * 6
    every = torch.cat([t.to(device) for t in targets])
    image = torch.repeat_interleave(torch.arange(len(targets), device=device), torch.tensor(counts, device=device))
    centres = xyxy_to_cxcywh(every)
    levels, anchors, rows, cols, flats = [], [], [], [], []
    offset = 0
    for level, (r, stride) in enumerate(zip(raw, STRIDES)):
        _, count, _, height, width = r.shape
        col = torch.clamp(torch.div(centres[:, 0], stride, rounding_mode="floor"), 0, width - 1).long()
        row = torch.clamp(torch.div(centres[:, 1], stride, rounding_mode="floor"), 0, height - 1).long()
        for a in range(count):
            levels.append(torch.full_like(col, level))
            anchors.append(torch.full_like(col, a))
            rows.append(row)
            cols.append(col)
            flats.append(offset + (a * height + row) * width + col)
        offset += count * height * width
    flat = torch.stack(flats, 1)  # (T, 9), in assign's candidate order
    giou = _elementwise_giou(every[:, None, :], boxes[image[:, None], flat])
    order = torch.argsort(giou, dim=1, descending=True, stable=True).cpu().numpy()
    keys = torch.stack([torch.stack(v, 1) for v in (levels, anchors, rows, cols)], -1).cpu().numpy()  # (T, 9, 4)
    image_cpu = image.cpu().numpy()
    chosen = []
    taken: set[tuple[int, ...]] = set()
    for t in range(len(every)):
        if t == 0 or image_cpu[t] != image_cpu[t - 1]:
            taken = set()  # keys are per image
        for choice in order[t]:
            key = tuple(int(v) for v in keys[t, choice])
            if key not in taken:
                taken.add(key)
                chosen.append((int(image_cpu[t]), t, *key))
                break
    columns = torch.tensor(chosen, dtype=torch.long).T
    return tuple(columns)


def heatmap_targets(targets: list[torch.Tensor], height: int, width: int, stride: int, sigma: float,
                    device: torch.device) -> torch.Tensor:
    """:func:`gaussian_targets` for a batch: (B, H, W), boxes padded so that one call does all."""
    most = max((len(t) for t in targets), default=0)
    if most == 0:
        return torch.zeros(len(targets), height, width, device=device)
    centres = torch.zeros(len(targets), most, 2, device=device)
    valid = torch.zeros(len(targets), most, device=device)
    for b, t in enumerate(targets):
        if len(t):
            centres[b, :len(t)] = xyxy_to_cxcywh(t.to(device))[:, :2] / stride
            valid[b, :len(t)] = 1.0
    ys = torch.arange(height, dtype=torch.float32, device=device)[:, None] + 0.5
    xs = torch.arange(width, dtype=torch.float32, device=device)[None, :] + 0.5
    squared = (xs[None, None] - centres[..., 0, None, None]) ** 2 + (ys[None, None] - centres[..., 1, None, None]) ** 2
    return (torch.exp(-squared / (2 * sigma ** 2)) * valid[..., None, None]).sum(1)


def rod_loss(model: DetectorNetwork, out: dict, targets: list[torch.Tensor], weights: LossWeights) -> dict[str, torch.Tensor]:
    """Batch mean of L_bbox, L_obj and L_h, and their weighted sum ``total`` (Eq 5.21-5.23)."""
    raw = out["raw"]
    device = raw[0].device
    boxes, _ = model.decode([r.detach() for r in raw])
    batch = raw[0].shape[0]
    targets = [t.to(device) for t in targets]
    image, target, level, anchor, row, col = (v.to(device) for v in assign_batch(raw, boxes, targets))
    every = torch.cat(targets) if targets else torch.zeros(0, 4, device=device)
    l_bbox = raw[0].new_zeros(())
    positives = [torch.zeros(r.shape[0], r.shape[1], r.shape[3], r.shape[4], dtype=torch.bool, device=device) for r in raw]
    for lvl, (r, stride) in enumerate(zip(raw, STRIDES)):
        pick = level == lvl
        if not bool(pick.any()):
            continue
        b, a, y, x = image[pick], anchor[pick], row[pick], col[pick]
        predicted = r[b, a, :4, y, x]  # (P, 4)
        cx, cy, w, h = xyxy_to_cxcywh(every[target[pick]]).unbind(1)
        goal_xy = torch.stack([cx / stride - x, cy / stride - y], 1).clamp(1e-4, 1 - 1e-4)
        goal_wh = torch.log(torch.stack([w, h], 1).clamp(min=1.0) / model.anchors[lvl, a])
        l_bbox = l_bbox + ((torch.sigmoid(predicted[:, :2]) - goal_xy) ** 2).sum() + ((predicted[:, 2:] - goal_wh) ** 2).sum()
        positives[lvl][b, a, y, x] = True
    # the best IoU of every prediction with any target of its image (padded targets: IoU 0)
    most = max((len(t) for t in targets), default=0)
    if most:
        padded = torch.zeros(batch, most, 4, device=device)
        for b, t in enumerate(targets):
            padded[b, :len(t)] = t
        lt = torch.maximum(boxes[:, :, None, :2], padded[:, None, :, :2])
        rb = torch.minimum(boxes[:, :, None, 2:], padded[:, None, :, 2:])
        inter = (rb - lt).clamp(min=0).prod(-1)
        area_p = (boxes[..., 2:] - boxes[..., :2]).clamp(min=0).prod(-1)[:, :, None]
        area_t = (padded[..., 2:] - padded[..., :2]).clamp(min=0).prod(-1)[:, None, :]
        best = (inter / (area_p + area_t - inter).clamp(min=1e-9)).amax(2)  # (B, N)
    else:
        best = torch.zeros(boxes.shape[:2], device=device)
    l_obj = raw[0].new_zeros(())
    offset = 0
    for lvl, r in enumerate(raw):
        objectness = torch.sigmoid(r[:, :, 4])
        count = r.shape[1] * r.shape[3] * r.shape[4]
        ignore = (best[:, offset:offset + count] > weights.ignore_iou).view(positives[lvl].shape)
        positive = positives[lvl]
        negative = ~positive & ~ignore
        l_obj = l_obj + ((1 - objectness[positive]) ** 2).sum() + weights.beta * (objectness[negative] ** 2).sum()
        offset += count
    l_h = raw[0].new_zeros(())
    for lvl, heatmap in enumerate(out["heatmaps"]):
        if heatmap is None:
            continue
        _, _, height, width = heatmap.shape
        goal = heatmap_targets(targets, height, width, STRIDES[lvl], weights.sigma, device)
        l_h = l_h + ((heatmap[:, 0] - goal.to(heatmap)) ** 2).mean()
    l_bbox, l_obj = l_bbox / batch, l_obj / batch
    total = weights.bbox * l_bbox + weights.obj * l_obj + weights.heatmap * l_h
    return {"total": total, "bbox": l_bbox.detach(), "obj": l_obj.detach(), "heatmap": l_h.detach()}

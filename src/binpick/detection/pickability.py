"""A second look at each detection: will the policy pick this copy? (thesis §5.4.4, §6.3)

ROD finds the copies of a product well but ranks pickable against unpickable ones less well (the
figures: docs/notes.md, "Tuning notes"): whether Policy 1's jaws can close on a copy turns on its outline
and pose and on its neighbours, details a 320 px one-stage detector shares with everything else it must do. So, as two-stage detectors re-score their proposals,
a small network looks again at each detection: a window around it (its neighbours and where the fingers
go, a fixed share of the image so widths keep their meaning), colour and the height map, the box drawn
as a mask; it says how likely the policy is to pick that copy, and the detection's score is multiplied
by it. It learns from the same one-grasp labels the detector learns from
(:class:`~binpick.detection.pickability_training.PickabilityTrainer`).

A head that also sees the query (``query=True``: the query's crop, or the shop photo, beside the
window) answers a sharper question -- is this a copy *of the ordered product* that the policy picks? --
and so also lowers the detector's confident boxes on other products and on background, which cost
the shipped detector as much AP50 as its boxes on unpickable copies (``experiments/rod_pickability.py``).
It learns that from the detector's own detections on the training images (``proposals``, labelled 1
where they cover a copy the policy picked) and from a window on every other product in each image
(``distractors``, 0), where only the query can tell. The head only re-ranks: which boxes exist is the
detector's decision (its score threshold), so a copy it is unsure of still counts towards recall.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from binpick.core.data_parallel import ALONE, Group
from binpick.core.metrics import roc_auc

WINDOW = 0.31  # the window's side as a share of the image's side (about 13 cm of binpick's default bin)
CROP = 64  # the window resampled to CROP x CROP pixels
JITTER = 0.12  # training boxes moved and resized by up to this share of their size: detections are not exact


def roi_windows(images: torch.Tensor, heights: torch.Tensor | None, boxes: torch.Tensor, owner: torch.Tensor,
                crop: int = CROP) -> torch.Tensor:
    """(N, C, crop, crop) windows centred on ``boxes`` (x1, y1, x2, y2 in the images' pixels) of
    ``images[owner]`` (B, 3, S, S in [0, 1]): RGB, the height map where given, then the box as a 0/1 mask.
    Outside the image reads as zero."""
    size = images.shape[-1]
    planes = images if heights is None else torch.cat([images, heights.to(images.dtype)], 1)
    n = len(boxes)
    if n == 0:
        return planes.new_zeros((0, planes.shape[1] + 1, crop, crop))
    centre = (boxes[:, :2] + boxes[:, 2:]) / 2
    half = WINDOW * size / 2
    # affine_grid's output spans [-1, 1]; the window spans centre ± half, in normalised input coordinates
    theta = planes.new_zeros((n, 2, 3))
    theta[:, 0, 0] = theta[:, 1, 1] = half / (size / 2)
    theta[:, :, 2] = centre / (size / 2) - 1
    grid = F.affine_grid(theta, [n, 1, crop, crop], align_corners=False)
    # per image, its planes expanded (a view) rather than indexed (a copy of the whole image per box: 30x slower)
    windows = planes.new_zeros((n, planes.shape[1], crop, crop))
    for image in owner.unique().tolist():
        mine = (owner == image).nonzero()[:, 0]
        source = planes[image:image + 1].expand(len(mine), -1, -1, -1)
        windows[mine] = F.grid_sample(source, grid[mine], mode="bilinear", padding_mode="zeros", align_corners=False)
    pixels = (grid + 1) * (size / 2)  # (N, crop, crop, 2): each output pixel's x, y in the image
    inside = ((pixels[..., 0] >= boxes[:, None, None, 0]) & (pixels[..., 0] <= boxes[:, None, None, 2])
              & (pixels[..., 1] >= boxes[:, None, None, 1]) & (pixels[..., 1] <= boxes[:, None, None, 3]))
    return torch.cat([windows, inside[:, None].to(windows.dtype)], 1)


def query_crops(images: torch.Tensor, query_boxes: torch.Tensor | None, query_images: torch.Tensor | None,
                crop: int = CROP) -> torch.Tensor:
    """(B, 3, crop, crop): what the head compares each window with -- the shop photo where the
    detector is queried with one, else the query box cut from its image."""
    if query_images is not None:
        return F.interpolate(query_images.float(), size=(crop, crop), mode="bilinear", align_corners=False)
    size = images.shape[-1]
    boxes = query_boxes.float()
    theta = images.new_zeros((len(boxes), 2, 3)).float()
    theta[:, 0, 0] = (boxes[:, 2] - boxes[:, 0]) / size
    theta[:, 1, 1] = (boxes[:, 3] - boxes[:, 1]) / size
    theta[:, :, 2] = (boxes[:, :2] + boxes[:, 2:]) / size - 1
    grid = F.affine_grid(theta, [len(boxes), 3, crop, crop], align_corners=False)
    return F.grid_sample(images.float(), grid, mode="bilinear", padding_mode="zeros", align_corners=False)


def _block(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, 2, 1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
                         nn.Conv2d(c_out, c_out, 3, 1, 1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True))


def _encoder(channels: int, width: int) -> nn.Sequential:
    return nn.Sequential(_block(channels, width), _block(width, 2 * width), _block(2 * width, 4 * width),
                         _block(4 * width, 4 * width))


def _classifier(inputs: int) -> nn.Sequential:
    return nn.Sequential(nn.Flatten(), nn.Linear(inputs, 128), nn.ReLU(inplace=True), nn.Dropout(0.2), nn.Linear(128, 1))


def product_logit(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The logit of σ(a)·σ(b), computed in log space (stable where both are near 0 or 1)."""
    log_p = (F.logsigmoid(a) + F.logsigmoid(b)).clamp(max=-1e-7)
    return log_p - torch.log(-torch.expm1(log_p))


def factorised_loss(pick: torch.Tensor, same: torch.Tensor, labels: torch.Tensor, same_labels: torch.Tensor) -> torch.Tensor:
    """A factorised head's two questions, each on its own labels: ``same`` on every window (a copy
    of the query's product or not), ``pick`` only on the copies (whether the policy picked it; on
    another product or background the question has no answer)."""
    loss = F.binary_cross_entropy_with_logits(same, same_labels)
    copies = same_labels > 0.5
    if copies.any():
        loss = loss + F.binary_cross_entropy_with_logits(pick[copies], labels[copies])
    return loss


class PickabilityHead(nn.Module):
    """Windows (:func:`roi_windows`), and with ``query`` the query's crops (:func:`query_crops`) ->
    the logit that the box holds a copy (of the query's product) the policy picks.

    ``factorised`` (with ``query``): that probability as a product of two, each with its own
    question -- will the policy pick what is in this window (``pick``: the window alone, as the
    window-only head) and is it a copy of the query's product (``same``: window and query) -- each
    taught by its own labels (:func:`factorised_loss`). Built because the head answering both at once
    ranks held-out categories below the window-only head (AP50 0.716 vs 0.747), on the guess that the
    unfamiliar query misled its pickability judgement; started from that head, it did not win them
    back (0.707; results/rod_pickability_factorised.json), so the guess is not the whole cause."""

    def __init__(self, depth: bool = True, width: int = 32, query: bool = False, factorised: bool = False) -> None:
        super().__init__()
        if factorised and not query:
            raise ValueError("a factorised pickability head compares with the query: it needs query=True")
        self.depth, self.query, self.factorised = depth, query, factorised
        self.features = _encoder(3 + int(depth) + 1, width)
        # the query as one vector; the window's features meet it per position (product and itself)
        self.query_features = _encoder(3, width) if query else None
        side = CROP // 16
        self.classify = _classifier(4 * width * (3 if query else 1) * side * side)  # `same` when factorised
        self.pick = _classifier(4 * width * side * side) if factorised else None

    def parts(self, windows: torch.Tensor, queries: torch.Tensor | None = None,
              owner: torch.Tensor | None = None) -> tuple[torch.Tensor | None, torch.Tensor]:
        """Logits per window: (``pick``, ``same``) for a factorised head, else (None, the head's logit)."""
        features = self.features(windows)
        pick = self.pick(features)[:, 0] if self.pick is not None else None
        if self.query_features is not None:
            if queries is None:
                raise ValueError("this pickability head compares each window with the query: give the query crops")
            q = self.query_features(queries).mean((2, 3))
            q = (q if owner is None else q[owner])[:, :, None, None].expand_as(features)
            features = torch.cat([features, features * q, q], 1)
        return pick, self.classify(features)[:, 0]

    def forward(self, windows: torch.Tensor, queries: torch.Tensor | None = None, owner: torch.Tensor | None = None) -> torch.Tensor:
        """Logits per window; ``queries``: one per window, or with ``owner`` (the query of each window)
        fewer, each encoded once. A factorised head's logit is that of σ(pick)·σ(same)."""
        pick, logit = self.parts(windows, queries, owner)
        return logit if pick is None else product_logit(pick, logit)

    @torch.no_grad()
    def probabilities(self, images: torch.Tensor, heights: torch.Tensor | None, boxes: list[torch.Tensor],
                      queries: torch.Tensor | None = None) -> list[torch.Tensor]:
        """Per image, the probability that each of its boxes (x1, y1, x2, y2) holds a copy the policy
        picks; ``queries``: per image its query crop (:func:`query_crops`), for a head that reads one."""
        counts = [len(b) for b in boxes]
        if not sum(counts):
            return [torch.zeros(0) for _ in boxes]
        owner = torch.repeat_interleave(torch.arange(len(boxes)), torch.tensor(counts)).to(images.device)
        windows = roi_windows(images.float(), heights.float() if self.depth and heights is not None else None,
                              torch.cat(boxes).float().to(images.device), owner)
        queries = queries.float() if self.query and queries is not None else None
        return list(torch.sigmoid(self(windows, queries, owner)).cpu().split(counts))


# ---------------------------------------------------------------------- learning it
def labelled_windows(dataset, progress: Callable[[int], None] | None = None, jittered: int = 1,
                     seed: int = 0, proposals: Callable[[dict], torch.Tensor] | None = None,
                     distractors: bool = False) -> dict[str, torch.Tensor]:
    """Windows of every labelled copy of a :class:`~binpick.detection.data.TaskDataset` (targets:
    picked, 1; unpickable: 0; the query copy left out) -- with ``distractors`` also of every instance
    of another product in the image (0: only the query tells them apart) --, each once as labelled and
    ``jittered`` more times moved by up to JITTER; with ``proposals`` (sample -> boxes x1, y1, x2, y2: the detector's own
    detections) also a window per proposal, 1 where it overlaps a picked copy at IoU >= 0.5, else 0 --
    what the head will be shown: misplaced boxes, other products and background included.

    Returns ``colour`` (N, 3 + 1 mask, ...) uint8, ``height`` (N, 1, ...) float16 (empty without
    depth), ``labels`` (N,), ``same`` (N,): 1 where the window holds a copy of the query's product,
    picked or not (a proposal: IoU >= 0.5 with one), and the query crop of each task once: ``queries``
    (T, 3, ...) uint8 with ``owner`` (N,), the task of each window."""

    rng = np.random.default_rng(seed)
    colour, height, labels, same, queries, owner = [], [], [], [], [], []
    for index in range(len(dataset)):
        sample = dataset[index]
        targets, unpickable = sample["targets"].reshape(-1, 4), sample["unpickable"].reshape(-1, 4)
        negatives = torch.cat([unpickable, sample["other_products"].reshape(-1, 4)]) if distractors else unpickable
        boxes = torch.cat([targets, negatives])
        label = torch.cat([torch.ones(len(targets)), torch.zeros(len(negatives))])
        copy = torch.cat([torch.ones(len(targets) + len(unpickable)), torch.zeros(len(negatives) - len(unpickable))])
        if len(boxes):
            variants = [boxes]
            for _ in range(jittered):
                size = boxes[:, 2:] - boxes[:, :2]
                shift = torch.from_numpy(rng.uniform(-JITTER, JITTER, (len(boxes), 4))).float() * size.repeat(1, 2)
                variants.append(boxes + shift)
            label, copy = label.repeat(len(variants)), copy.repeat(len(variants))
            if proposals is not None:
                found = proposals(sample).reshape(-1, 4).float()
                hit, on_copy = _covers(found, targets), _covers(found, torch.cat([targets, unpickable]))
                variants.append(found)
                label, copy = torch.cat([label, hit.float()]), torch.cat([copy, on_copy.float()])
            boxes = torch.cat(variants)
            heights = sample["depth"][None] if "depth" in sample else None
            windows = roi_windows(sample["image"][None], heights, boxes, torch.zeros(len(boxes), dtype=torch.long))
            colour.append((torch.cat([windows[:, :3], windows[:, -1:]], 1) * 255).round().to(torch.uint8))
            height.append(windows[:, 3:-1].half())
            labels.append(label)
            same.append(copy)
            photo = sample["query_image"][None] if dataset.query_mode == "photo" else None
            crop = query_crops(sample["image"][None], sample["query_box"][None], photo)
            owner.append(torch.full((len(boxes),), len(queries), dtype=torch.int32))
            queries.append((crop.clamp(0, 1) * 255).round().to(torch.uint8))
        if progress is not None:
            progress(1)
    if not labels:
        return {"colour": torch.zeros((0, 4, CROP, CROP), dtype=torch.uint8), "height": torch.zeros((0, 0, CROP, CROP), dtype=torch.float16),
                "labels": torch.zeros(0), "same": torch.zeros(0), "queries": torch.zeros((0, 3, CROP, CROP), dtype=torch.uint8),
                "owner": torch.zeros(0, dtype=torch.int32)}
    return {"colour": torch.cat(colour), "height": torch.cat(height), "labels": torch.cat(labels), "same": torch.cat(same),
            "queries": torch.cat(queries), "owner": torch.cat(owner)}


def _covers(found: torch.Tensor, boxes: torch.Tensor) -> torch.Tensor:
    """Which ``found`` boxes overlap one of ``boxes`` at IoU >= 0.5 (x1, y1, x2, y2)."""
    from binpick.detection.ops import box_iou

    if not len(found) or not len(boxes):
        return torch.zeros(len(found), dtype=torch.bool)
    return box_iou(found, boxes).max(1).values >= 0.5


def join_windows(parts: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """Several :func:`labelled_windows` results as one (each window still pointing at its own query)."""
    offsets = np.cumsum([0] + [len(p["queries"]) for p in parts[:-1]])
    joined = {key: torch.cat([p[key] for p in parts]) for key in ("colour", "height", "labels", "same", "queries")}
    joined["owner"] = torch.cat([p["owner"] + int(o) for p, o in zip(parts, offsets)])
    return joined


def assemble(colour: torch.Tensor, height: torch.Tensor, depth: bool) -> torch.Tensor:
    """Stored windows back into the head's input: RGB, heights (when the head reads them), mask."""
    planes = colour.float() / 255
    parts = [planes[:, :3]] + ([height.float()] if depth else []) + [planes[:, 3:]]
    return torch.cat(parts, 1)


def _queries(head: PickabilityHead, windows: dict[str, torch.Tensor], idx: torch.Tensor) -> torch.Tensor | None:
    return windows["queries"][windows["owner"][idx].long()].float() / 255 if head.query else None


def head_auc(head: PickabilityHead, windows: dict[str, torch.Tensor], batch: int = 512) -> float:
    """ROC AUC of the head's scores on stored windows (:func:`labelled_windows`): picked copies
    against the rest."""
    head.eval()
    labels = windows["labels"]
    with torch.no_grad():
        scores = torch.cat([head(assemble(windows["colour"][i:i + batch], windows["height"][i:i + batch], head.depth),
                                 _queries(head, windows, torch.arange(i, min(i + batch, len(labels)))))
                            for i in range(0, len(labels), batch)]) if len(labels) else torch.zeros(0)
    auc = roc_auc(labels.numpy(), scores.numpy())
    return 0.5 if auc is None else auc  # one class: no ranking to speak of


def train_epoch(head: PickabilityHead, optimiser: torch.optim.Optimizer, schedule, windows: dict[str, torch.Tensor],
                generator: torch.Generator, batch: int = 128, progress: Callable[[int], None] | None = None,
                group: Group = ALONE) -> float:
    """One pass in random order with mirror flips (jaws along y stay along y); the mean loss. In a
    data-parallel group every process draws the same order and flips and trains on its part of each
    batch, gradients averaged: close to the step a single process takes, not equal to it (batch norm
    sees each part's statistics, and the factorised head's pick term averages over each part's copies)."""
    head.train()
    labels = windows["labels"]
    order = torch.randperm(len(labels), generator=generator)
    losses = []
    for start in range(0, len(order) - batch + 1, batch):
        idx = order[start:start + batch]
        flip_across = torch.rand(len(idx), generator=generator) < 0.5
        flip_along = torch.rand(len(idx), generator=generator) < 0.5
        idx, flip_across, flip_along = group.part(idx), group.part(flip_across), group.part(flip_along)
        x = assemble(windows["colour"][idx], windows["height"][idx], head.depth)
        x[flip_across] = x[flip_across].flip(3)
        x[flip_along] = x[flip_along].flip(2)
        if head.factorised:
            loss = factorised_loss(*head.parts(x, _queries(head, windows, idx)), labels[idx], windows["same"][idx])
        else:
            loss = F.binary_cross_entropy_with_logits(head(x, _queries(head, windows, idx)), labels[idx])
        optimiser.zero_grad()
        loss.backward()
        group.average_gradients(head.parameters())
        optimiser.step()
        schedule.step()
        losses.append(loss.item())
        if progress is not None:
            progress(len(idx))
    return float(np.mean(losses)) if losses else float("nan")

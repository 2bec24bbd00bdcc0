"""COCO-style evaluation with pycocotools (thesis §5.4, Eq 5.25-5.28).

Every task (an image with one query) becomes one evaluation image whose ground truth is either the
boxes to find (``targets``), every other instance of the product (``all``, Table 5.6) or the
unpickable ones (``unpickable``, Table 5.5: lower is better). Where labels come from several trial
grasps, ``certain`` scores only the targets every grasp agreed on, with the ambiguous instances as
COCO crowd regions: a detection on one is neither a hit nor a false positive. AP50 and mAP@[.5:.95] come from
``COCOeval``; AP50 by object scale (Fig 5.12) uses its area ranges, with scale = sqrt(box area) /
image side.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
import torch

SCALE_BINS = ((0.0, 0.1), (0.1, 0.15), (0.15, 0.2), (0.2, 0.3), (0.3, 1.0))
GROUND_TRUTHS = ("targets", "all", "unpickable", "certain", "ambiguous", "other_products")


def collect(detect: Callable[[dict], list[dict[str, torch.Tensor]]], batches: Iterable[dict], progress=None
            ) -> list[dict[str, Any]]:
    """Run ``detect`` over batches; keep each task's detections and its ground truths (GROUND_TRUTHS)."""
    tasks = []
    for batch in batches:
        results = detect(batch)
        for i, result in enumerate(results):
            tasks.append({"index": batch["index"][i], "image_id": batch["image_id"][i],
                          "boxes": result["boxes"].cpu().numpy(), "scores": result["scores"].cpu().numpy(),
                          **{k: batch[k][i].numpy() for k in GROUND_TRUTHS}})
        if progress is not None:
            progress(len(results))
    return tasks


def coco_ap(tasks: list[dict[str, Any]], ground_truth: str, image_size: int, by_scale: bool = False,
            ignore: str | None = None) -> dict[str, Any]:
    """AP50, mAP (and AP50 per scale bin) of the tasks' detections against one kind of ground truth,
    the boxes of ``ignore`` as crowd regions (ignored); None where that ground truth is empty."""
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    images, annotations, detections = [], [], []
    for number, task in enumerate(tasks):
        images.append({"id": number + 1, "width": image_size, "height": image_size})
        for box in task[ground_truth]:
            x1, y1, x2, y2 = [float(v) for v in box]
            annotations.append({"id": len(annotations) + 1, "image_id": number + 1, "category_id": 1,
                                "bbox": [x1, y1, x2 - x1, y2 - y1], "area": (x2 - x1) * (y2 - y1), "iscrowd": 0})
        for box in task.get(ignore, ()) if ignore else ():
            x1, y1, x2, y2 = [float(v) for v in box]
            annotations.append({"id": len(annotations) + 1, "image_id": number + 1, "category_id": 1,
                                "bbox": [x1, y1, x2 - x1, y2 - y1], "area": (x2 - x1) * (y2 - y1), "iscrowd": 1})
        for box, score in zip(task["boxes"], task["scores"]):
            x1, y1, x2, y2 = [float(v) for v in box]
            detections.append({"image_id": number + 1, "category_id": 1, "bbox": [x1, y1, x2 - x1, y2 - y1],
                               "score": float(score)})
    empty = {"ap50": None, "map": None, "pr_recall": [], "pr_precision": []}
    if not any(a["iscrowd"] == 0 for a in annotations):
        return empty | ({"ap50_by_scale": {}} if by_scale else {})
    with contextlib.redirect_stdout(io.StringIO()):
        gt = COCO()
        gt.dataset = {"images": images, "annotations": annotations, "categories": [{"id": 1, "name": "target"}]}
        gt.createIndex()
        dt = gt.loadRes(detections) if detections else COCO()
        if not detections:
            return empty | {"ap50": 0.0, "map": 0.0} | ({"ap50_by_scale": {}} if by_scale else {})
        evaluator = COCOeval(gt, dt, "bbox")
        evaluator.params.maxDets = [1, 10, 100]
        if by_scale:
            side = float(image_size)
            evaluator.params.areaRng = [[0, 1e10]] + [[(a * side) ** 2, (b * side) ** 2] for a, b in SCALE_BINS]
            evaluator.params.areaRngLbl = ["all"] + [f"{a:g}-{b:g}" for a, b in SCALE_BINS]
        evaluator.evaluate()
        evaluator.accumulate()
        evaluator.summarize()
    precision = evaluator.eval["precision"]  # [IoU, recall, class, area, maxDets]

    def ap(iou_index: slice | int, area: int = 0) -> float | None:
        values = precision[iou_index, :, 0, area, -1]
        values = values[values > -1]
        return float(values.mean()) if values.size else None

    result = {"ap50": ap(0), "map": ap(slice(None)), "pr_recall": evaluator.params.recThrs.tolist(),
              "pr_precision": np.maximum(precision[0, :, 0, 0, -1], 0).tolist()}
    if by_scale:
        result["ap50_by_scale"] = {label: ap(0, i + 1) for i, label in enumerate(evaluator.params.areaRngLbl[1:])}
        result["gt_by_scale"] = {label: int(sum(1 for a in annotations if lo <= a["area"] < hi))
                                 for label, (lo, hi) in zip(evaluator.params.areaRngLbl[1:], evaluator.params.areaRng[1:])}
    return result


def copy_scores(tasks: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """Per labelled copy (pickable: 1, unpickable: 0), the best score of a detection on it at IoU 0.5
    (0 when none): whether a detector prefers what a policy can pick, apart from how well it finds the
    product at all (AP on unpickable copies rises with both)."""
    from binpick.detection.ops import box_iou

    labels, scores = [], []
    for task in tasks:
        boxes, detected = torch.as_tensor(task["boxes"]).reshape(-1, 4), torch.as_tensor(task["scores"]).reshape(-1)
        for label, key in ((1, "targets"), (0, "unpickable")):
            truth = torch.as_tensor(task[key]).reshape(-1, 4)
            if not len(truth):
                continue
            if len(boxes):
                best = torch.where(box_iou(truth, boxes) >= 0.5, detected[None], torch.zeros(())).max(1).values
            else:
                best = torch.zeros(len(truth))
            labels += [label] * len(truth)
            scores += best.tolist()
    return np.array(labels, dtype=np.int64), np.array(scores, dtype=np.float64)


def first_choices(tasks: list[dict[str, Any]]) -> dict[str, Any]:
    """Where the top-scoring detection lands in the bins that hold both pickable and unpickable copies:
    the copy a picker tries first, so the share on pickable copies is the preference that matters for
    picking (AP on unpickable copies also rises when a detector simply finds more of the product)."""
    from binpick.detection.ops import box_iou

    counts = {"pickable": 0, "unpickable": 0, "other": 0}
    for task in tasks:
        pickable, unpickable = (torch.as_tensor(task[key]).reshape(-1, 4) for key in ("targets", "unpickable"))
        boxes, scores = torch.as_tensor(task["boxes"]).reshape(-1, 4), torch.as_tensor(task["scores"]).reshape(-1)
        if not len(pickable) or not len(unpickable):
            continue
        if not len(boxes):
            counts["other"] += 1
            continue
        top = boxes[int(scores.argmax())][None]
        best = {kind: float(box_iou(top, truth).max()) for kind, truth in (("pickable", pickable), ("unpickable", unpickable))}
        kind = max(best, key=best.get)
        counts[kind if best[kind] >= 0.5 else "other"] += 1
    bins = sum(counts.values())
    return {"contested_bins": bins, **{f"first_on_{kind}": round(n / bins, 4) if bins else None for kind, n in counts.items()}}


def summarise(tasks: list[dict[str, Any]], image_size: int) -> dict[str, Any]:
    """The numbers ``results/rod.json`` keeps, for one model on one data set."""
    targets = coco_ap(tasks, "targets", image_size, by_scale=True)
    every = coco_ap(tasks, "all", image_size)
    unpickable = coco_ap(tasks, "unpickable", image_size)
    ambiguous = sum(len(task.get("ambiguous", ())) for task in tasks)
    certain = coco_ap(tasks, "certain", image_size, ignore="ambiguous") if ambiguous else {"ap50": None, "map": None}
    return {"tasks": len(tasks), "ap50": targets["ap50"], "map": targets["map"],
            "ap50_by_scale": targets["ap50_by_scale"], "gt_by_scale": targets.get("gt_by_scale", {}),
            "ap50_all": every["ap50"], "map_all": every["map"],
            "ap50_unpickable": unpickable["ap50"], "map_unpickable": unpickable["map"],
            "ap50_certain": certain["ap50"], "map_certain": certain["map"], "ambiguous_instances": ambiguous,
            "pr": {"recall": targets["pr_recall"], "precision": targets["pr_precision"]}}

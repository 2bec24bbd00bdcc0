"""The crop-query detector with and without its pickability head (``seen.rod.ap50``).

    binpick detect pickability configs/detection/pickability_crop_query.yaml --runs runs/pick38
    python experiments/rod_pickability.py --weights runs/pick38/pickability_crop_query/<time>/model.safetensors \
        --data runs/data/bins_2000/annotations_val.json --data runs/data/bins_fresh_seed16/annotations_val.json \
        [--compare OTHER_HEAD.safetensors] [--ship]

The same detections scored as the detector ranks them and times the head's probability that the box
holds a copy of the ordered product that Policy 1 picks (:mod:`binpick.detection.pickability`); with
``--compare``, also times another head's (the window-only head shipped before). Per ``--data`` file
(the first is the val set of ``seen.rod.ap50``): AP50 against the copies Policy 1 picked, AP50 on the
unpickable ones, ROC AUC of the score between the two, and where the false positives cost AP50 (the
same detections without those on unpickable copies, without those on other products); then the
held-out categories (bins_2000's test split, pickable targets) and ``predict``'s latency at batch 1
with the head. With ``--ship`` the weights become ``rod_tiny_320``: results/rod.json's ``seen.rod``
and ``latency_ms.shipped`` are then this detector's, the detector-only figures kept beside them as
``seen.rod_detector_only``.

Writes results/rod_pickability.json and its section of docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


import _common  # noqa: E402

SEEN = _common.ROOT / "runs" / "data" / "bins_2000" / "annotations_val.json"
HELD_OUT = _common.ROOT / "runs" / "data" / "bins_2000" / "annotations_test.json"
P1 = "pickable:y"


def scores_on(network, annotations: Path) -> dict:
    """AP50 (targets, unpickable copies) and ROC AUC of the copy scores, on one annotations file; and
    where the false positives cost AP50: the same detections with those on unpickable copies of the
    ordered product taken away, and with those on other products taken away."""
    import numpy as np
    import torch

    from binpick.detection.data import RepeatedInstances, TaskDataset
    from binpick.detection.evaluate import coco_ap, collect, copy_scores, summarise
    from binpick.detection.ops import box_iou
    from binpick.core.metrics import roc_auc
    from binpick.detection.train import detector_detect
    from binpick.detection.training_data import loader

    source = RepeatedInstances(annotations, targets=P1)
    dataset = TaskDataset(source, network.image_size, network.spec.query, network.query_size, depth=network.spec.reads_depth)
    with torch.no_grad():
        tasks = collect(detector_detect(network), loader(dataset, 8, False, 0, 0))
    metrics = summarise(tasks, network.image_size)
    labels, scores = copy_scores(tasks)

    def on(boxes: torch.Tensor, copies) -> torch.Tensor:
        copies = torch.as_tensor(np.asarray(copies)).reshape(-1, 4).float()
        if not len(boxes) or not len(copies):
            return torch.zeros(len(boxes), dtype=torch.bool)
        return box_iou(boxes, copies).max(1).values >= 0.5

    without_unpickable, without_other = [], []
    for task in tasks:
        boxes = torch.as_tensor(np.asarray(task["boxes"])).reshape(-1, 4).float()
        copy = on(boxes, task["all"])
        for kept, drop in ((without_unpickable, on(boxes, task["unpickable"]) & ~on(boxes, task["targets"])),
                           (without_other, on(boxes, task["other_products"]) & ~copy)):
            keep = (~drop).numpy()
            kept.append({**task, "boxes": np.asarray(task["boxes"])[keep], "scores": np.asarray(task["scores"])[keep]})
    size = network.image_size
    return {"ap50": round(metrics["ap50"], 4), "ap50_all": round(metrics["ap50_all"], 4),
            "ap50_unpickable": round(metrics["ap50_unpickable"], 4), "map": round(metrics["map"], 4),
            "pickable_auc": round(roc_auc(labels, scores), 4), "tasks": metrics["tasks"],
            "ap50_without_unpickable_fp": round(coco_ap(without_unpickable, "targets", size)["ap50"], 4),
            "ap50_without_other_product_fp": round(coco_ap(without_other, "targets", size)["ap50"], 4)}


def shown(file: Path) -> str:
    file = Path(file).resolve()
    return str(file.relative_to(_common.ROOT)) if file.is_relative_to(_common.ROOT) else str(file)


def section(result: dict) -> str:
    compared = "with_compared_head" in result["sets"][0]
    what = "a head that also sees the query" if result.get("query") else "a head that sees the window only"
    lines = ["## The crop query with a second look at each detection", "",
             f"`python experiments/rod_pickability.py` → `results/rod_pickability.json`. Weights: `{result['weights']}`: "
             f"{what} (`binpick detect pickability`, {result['head']['train_windows']} training windows, best val ROC AUC "
             f"{result['head']['val_auc']}). The same detections, scored by the detector alone"
             + (f", times the probability of the head before it (`{result['compared']['weights']}`, window only)" if compared else "")
             + " and times this head's probability that the box holds a copy of the ordered product that Policy 1 "
             "(jaws along y) picks. Every detection is kept (the head re-ranks):", "",
             "| data | tasks | AP50 detector" + (" / window head" if compared else "") + " / shipped head "
             "| AP50 on unpickable copies | ROC AUC pickable vs not | AP50 without the FPs on unpickable copies / on other products |",
             "|---|---:|---|---|---|---|"]
    keys = ["detector_only", *(["with_compared_head"] if compared else []), "with_head"]
    for row in result["sets"]:
        cells = [row[k] for k in keys]

        def joined(metric: str, bold_last: bool = False) -> str:
            values = [str(c.get(metric)) for c in cells]
            if bold_last:
                values[-1] = f"**{values[-1]}**"
            return " / ".join(values)

        head = row["with_head"]
        lines.append(f"| `{row['data']}` ({row['role']}) | {head['tasks']} | {joined('ap50', True)} | {joined('ap50_unpickable')} | "
                     f"{joined('pickable_auc')} | {head.get('ap50_without_unpickable_fp')} / {head.get('ap50_without_other_product_fp')} |")
    lines += ["", f"Latency of `predict`, batch 1, 2 threads, 320 px: {result['latency_ms']['detector_only']} ms without the head, "
              f"**{result['latency_ms']['with_head']} ms** with it (target ≤ 50).", "",
              "Seen-product target (`seen.rod.ap50`, the first row): ≥ 0.85; the thesis's Table 5.4 ROD 0.9056. "
              "The last column is where the shipped head's false positives still cost AP50: the same detections with those on "
              "unpickable copies of the ordered product taken away, and with those on other products taken away. "
              "The detector alone lost about as much to boxes on other products as to boxes on copies Policy 1 cannot pick; "
              "a head that sees only the window can lower the second kind but not the first, which is why the shipped head "
              "also reads the query: `configs/detection/pickability_crop_query_base.yaml` (copies and the detector's own detections, "
              "`proposals: 6`), then `configs/detection/pickability_crop_query.yaml` from it (`init`), with a window on every other "
              "product in each image (`distractors`). Its cost: on categories it never saw (the held-out row) comparing with "
              "the query misleads it, and it ranks below the window-only head there."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", required=True, help="detector weights with a pickability head (.safetensors or a run folder)")
    parser.add_argument("--data", type=Path, action="append", help="annotations to score (repeatable; the first: seen.rod.ap50's)")
    parser.add_argument("--compare", help="another detector with a pickability head (e.g. the shipped one before), scored on the same sets")
    parser.add_argument("--ship", action="store_true", help="copy the weights to the package as rod_tiny_320 and update results/rod.json")
    args = parser.parse_args()
    import torch

    from binpick.detection.detector import Detector

    torch.set_num_threads(2)
    detector = Detector.load(args.weights)
    network = detector.network.eval()
    if network.pickability is None:
        raise SystemExit(f"{args.weights} has no pickability head (binpick detect pickability makes one)")
    plain = network.without_pickability()
    compared = Detector.load(args.compare) if args.compare else None
    other = compared.network.eval() if compared is not None else None
    files = args.data or [SEEN]
    head = read_meta(detector.source)
    result = {"weights": shown(detector.source), "targets": "pickable by Policy 1 (jaws along y)",
              "head": {"val_auc": head.get("val_auc"), "train_windows": head.get("train_windows"), "trained_on": head.get("train")},
              "query": bool(network.spec.pickability_query), "sets": []}
    if other is not None:
        result["compared"] = {"weights": args.compare, "query": bool(other.spec.pickability_query), **read_meta(compared.source)}
    for index, file in enumerate([*files, HELD_OUT]):
        if not Path(file).is_file():
            print(f"skipping {file}: not on disk", flush=True)
            continue
        role = "held-out categories" if file == HELD_OUT else ("seen.rod.ap50's val set" if index == 0 else "seen products")
        row = {"data": shown(file), "role": role, "detector_only": scores_on(plain, file), "with_head": scores_on(network, file)}
        if other is not None:
            row["with_compared_head"] = scores_on(other, file)
        print(json.dumps(row), flush=True)
        result["sets"].append(row)
    from rod import interleaved_latency_ms, latency_input  # experiments/ is on the path (the script's own folder)

    image, box, depth = latency_input()
    fast = detector.inference_network  # what Detector.predict runs
    result["latency_ms"] = interleaved_latency_ms({"with_head": (fast, True), "detector_only": (fast.without_pickability(), False)},
                                                  image, box, depth)
    result["target"] = 0.85
    result["peak_rss_mib"] = round(_common.peak_rss_mib(), 1)
    _common.write_result("rod_pickability", result)
    _common.write_section_of("rod_pickability", section, "rod_pickability.json")
    if args.ship:
        ship(detector.source, result)
    print(json.dumps({k: result[k] for k in ("sets", "latency_ms")}, indent=1))


def read_meta(path: Path) -> dict:
    from binpick.detection.weights_file import read_detector_file, weights_path

    return read_detector_file(weights_path(Path(path)))[1].get("pickability") or {}


def ship(source: Path, result: dict) -> None:
    """The weights become the package's rod_tiny_320; rod.json's seen row and latency say so."""
    import shutil

    from binpick.detection.weights_file import weights_path

    target = _common.ROOT / "src" / "binpick" / "detection" / "weights" / "rod_tiny_320.safetensors"
    shutil.copyfile(weights_path(Path(source)), target)
    rod = json.loads((_common.RESULTS / "rod.json").read_text())
    first = result["sets"][0]
    if first["data"] != shown(SEEN):
        raise SystemExit(f"--ship needs {shown(SEEN)} as the first --data (the set of seen.rod.ap50)")
    rod["seen"]["rod_detector_only"] = rod["seen"].get("rod_detector_only") or rod["seen"]["rod"]
    # this run's figures only: keys of the row it replaces (measured on other detections) would be stale
    rod["seen"]["rod"] = {**first["with_head"], "ap50_certain": None, "pickability_head": True,
                          "pickability_query": result.get("query", False),
                          "measured": "experiments/rod_pickability.py (the shipped rod_tiny_320: detector and pickability head)"}
    rod["latency_ms"]["shipped"] = result["latency_ms"]["with_head"]
    rod["latency_ms"]["shipped_detector_only"] = result["latency_ms"]["detector_only"]
    rod["latency_ms"]["measured"] = "experiments/rod_pickability.py --ship, both in one run, in turns (the rest: experiments/rod.py latency)"
    from binpick.core.files import atomic_write_text

    atomic_write_text(_common.RESULTS / "rod.json", json.dumps(rod, indent=2) + "\n")
    from rod import rewrite_section

    rewrite_section()  # its tables: the seen row and the latency are the shipped detector's now
    print(f"shipped {target}; results/rod.json seen.rod.ap50 = {rod['seen']['rod']['ap50']}", flush=True)


if __name__ == "__main__":
    main()

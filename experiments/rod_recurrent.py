"""The recurrent repeated-object detector (thesis §5.2) beside ROD and TDID: a negative result is a result.

    python experiments/rod_recurrent.py pretrain [--set images=16480]   # configs/detection/rod_recurrent_pretrain.yaml (resumes)
    python experiments/rod_recurrent.py finetune                        # configs/detection/rod_recurrent_finetune.yaml (resumes)
    python experiments/rod_recurrent.py report                          # results/rod.json -> recurrent, docs/RESULTS.md
    python experiments/rod_recurrent.py repeats                         # how often a step finds what an earlier one found

The same test sets as ``experiments/rod.py``: the shifted set-up (``runs/data/shifted``, held-out
products, every copy a target), held-out categories of the default bins (``runs/data/bins_2000``
test split, every copy a target: the pre-trained model) and seen products (its val split, copies
Policy 1 can pick: the fine-tuned model). The shipped crop-query ROD is scored on the same tasks
beside it. Latency: ``detect`` at batch 1, 320 px, 2 threads, median of 20.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path


import _common  # noqa: E402
import rod as rod_benchmark  # noqa: E402

PRETRAIN = _common.recipe("rod_recurrent_pretrain")[0]
FINETUNE = _common.recipe("rod_recurrent_finetune")[0]
HELD_OUT = ["can", "mug", "toy"]
SHIPPED_ROD = _common.ROOT / "src" / "binpick" / "detection" / "weights" / "rod_tiny_320.safetensors"


def train(config_file: Path, settings: list[str] | None) -> None:
    from binpick.core.config import load_config
    from binpick.detection.recurrent_training import RecurrentTrainConfig, train_recurrent
    from binpick.cli.terminal import RichCallback

    config = load_config(RecurrentTrainConfig, config_file, rod_benchmark.parse_overrides(settings))
    with RichCallback() as callback:
        metrics = train_recurrent(config, callback)
    print(json.dumps(metrics["val"]), flush=True)


def latency_ms(model, repeats: int = 20) -> float:
    import numpy as np
    import torch

    torch.set_num_threads(2)
    image = torch.rand(1, 3, model.image_size, model.image_size)
    box = torch.tensor([[100.0, 100.0, 150.0, 160.0]])
    for _ in range(3):
        model.detect(image, box)
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        model.detect(image, box)
        times.append(1000 * (time.perf_counter() - started))
    return round(float(np.median(times)), 1)


def scored(detect, data: Path, split: str, targets: str, only: list[str] | None = None) -> dict:
    return rod_benchmark.keep(rod_benchmark.evaluate_on(detect, data, split, targets, rod_benchmark.SHIPPED_SIZE, only))


def scored_rod(model, data: Path, split: str, targets: str, only: list[str] | None = None) -> dict:
    """ROD as ``experiments/rod.py`` scores it: at its size, with its query kind and depth if it reads depth."""
    from binpick.detection.train import detector_detect

    return rod_benchmark.keep(rod_benchmark.evaluate_on(detector_detect(model), data, split, targets, model.image_size, only,
                                                        model.spec.query, model.spec.frames_photos, model.spec.reads_depth))


def report(pretrained_path: Path, finetuned_path: Path) -> None:
    import torch

    from binpick.detection.recurrent_training import load_recurrent, recurrent_detect
    from binpick.detection.weights_file import load_detector

    torch.set_num_threads(2)
    pretrained, finetuned = load_recurrent(pretrained_path), load_recurrent(finetuned_path)
    rod = load_detector(SHIPPED_ROD)
    every_copy = rod.without_pickability()  # its pickability head re-ranks for what a policy picks: not this task
    bins, shifted = rod_benchmark.DATA, rod_benchmark.SHIFTED
    rows: dict = {"recurrent": {}, "rod_shipped": {}}
    rows["recurrent"]["shifted_domain"] = scored(recurrent_detect(pretrained), shifted, "test", "all")
    rows["rod_shipped"]["shifted_domain"] = scored_rod(every_copy, shifted, "test", "all")
    rows["recurrent"]["zero_shot"] = {c: scored(recurrent_detect(pretrained), bins, "test", "all", [c]) for c in HELD_OUT}
    rows["rod_shipped"]["zero_shot"] = {c: scored_rod(every_copy, bins, "test", "all", [c]) for c in HELD_OUT}
    rows["recurrent"]["seen"] = scored(recurrent_detect(finetuned), bins, "val", rod_benchmark.P1)
    rows["rod_shipped"]["seen"] = scored_rod(rod, bins, "val", rod_benchmark.P1)
    for name, row in rows.items():
        print(name, json.dumps({k: (v["ap50"] if "ap50" in v else {c: x["ap50"] for c, x in v.items()}) for k, v in row.items()}), flush=True)
    path = _common.RESULTS / "rod.json"
    result = json.loads(path.read_text())  # the other rows keep the machine they were measured on
    kept = {key: result["recurrent"][key] for key in ("repeated_steps",) if key in result.get("recurrent", {})}  # its own phase
    result["recurrent"] = {
        **kept,
        "machine": _common.machine(), "peak_rss_mib": _common.peak_rss_mib(),
        **rows["recurrent"],
        "ms_per_image": latency_ms(pretrained),
        "images_seen": {"pretrain": pretrained.meta.get("images_seen"), "finetune": finetuned.meta.get("images_seen")},
        "trained_on": {"pretrain": pretrained.meta.get("trained_on"), "finetune": finetuned.meta.get("trained_on")},
        "data": {"shifted": str(shifted.relative_to(_common.ROOT)), "seen_and_held_out": str(bins.relative_to(_common.ROOT))},
        "rod_shipped_same_tasks": rows["rod_shipped"],
        "measured": "experiments/rod_recurrent.py report",
    }
    result["shifted_domain"]["recurrent"] = rows["recurrent"]["shifted_domain"]
    from binpick.core.files import atomic_write_text

    atomic_write_text(path, json.dumps(result, indent=2) + "\n")
    _common.write_section_of("rod_recurrent", section, "rod.json")


def repeats(pretrained_path: Path, tasks: int = 100) -> None:
    """``recurrent.repeated_steps``: of the steps that gave a box, the share whose box overlaps an
    earlier step's (IoU > 0.5) on the first ``tasks`` held-out tasks of the default bins: the thesis's
    failure (one object found again and again) measured; and the mean number of boxes per task."""
    import torch

    from binpick.detection.data import RepeatedInstances, TaskDataset, collate
    from binpick.detection.ops import box_iou
    from binpick.detection.recurrent_training import load_recurrent

    torch.set_num_threads(2)
    model = load_recurrent(pretrained_path)
    dataset = TaskDataset(RepeatedInstances(rod_benchmark.DATA / "annotations_test.json", targets="all"), model.image_size, "crop")
    repeated = boxes = 0
    for start in range(0, min(tasks, len(dataset)), 8):
        batch = collate([dataset[i] for i in range(start, min(start + 8, tasks, len(dataset)))])
        for result in model.detect(batch["image"], batch["query_box"]):
            found = result["boxes"]
            boxes += len(found)
            if len(found) > 1:
                overlaps = torch.triu(box_iou(found, found), 1)  # [i, j]: step i before step j
                repeated += int((overlaps.amax(0) > 0.5).sum())
    path = _common.RESULTS / "rod.json"
    result = json.loads(path.read_text())
    result["recurrent"]["repeated_steps"] = {"share": round(repeated / max(1, boxes), 4), "boxes_per_task": round(boxes / max(1, min(tasks, len(dataset))), 2),
                                             "tasks": min(tasks, len(dataset)), "data": "held-out categories, default bins (test split)"}
    from binpick.core.files import atomic_write_text

    atomic_write_text(path, json.dumps(result, indent=2) + "\n")
    print(result["recurrent"]["repeated_steps"], flush=True)
    _common.write_section_of("rod_recurrent", section, "rod.json")


def ap(row: dict | None) -> str:
    return "—" if not row or row.get("ap50") is None else f"{row['ap50']:.3f}"


def rod_budgets(result: dict) -> str:
    """The pre-training images of experiments/rod.py's rows (``pretraining_images_seen``), beside the recurrent one's."""
    seen = result.get("pretraining_images_seen") or {}
    no_lh, tdid, rod = (seen.get(f"pretrain_{row}") for row in ("rod_no_lh", "tdid", "rod"))

    def shown(count: int | None) -> str:
        return "—" if count is None else f"{count:,}"

    pair = f"ROD w/o L_h and TDID {shown(tdid)}" if no_lh == tdid else f"ROD w/o L_h {shown(no_lh)}, TDID {shown(tdid)}"
    return f"{pair}, ROD {shown(rod)}"


def section(result: dict) -> str:
    """The recurrent detector's section of docs/RESULTS.md, from results/rod.json's ``recurrent`` (and the
    pre-training budgets of experiments/rod.py's rows in the same file)."""
    rec = result["recurrent"]
    rod = rec["rod_shipped_same_tasks"]
    lines = ["## The recurrent detector the thesis set aside (§5.2)", "",
             "`python experiments/rod_recurrent.py pretrain && python experiments/rod_recurrent.py finetune && "
             "python experiments/rod_recurrent.py report` → `results/rod.json` → `recurrent`. "
             "A convolutional encoder (ROD's tiny backbone) and a decoder of three convolutional LSTMs (Eq 5.3) that gives one "
             "instance mask per step and a stop flag, conditioned on the query's crop; Hungarian-matched soft-IoU (Eq 5.4-5.5), "
             "stop (Eq 5.6) and repetition (Eq 5.8, through a similarity network trained by Eq 5.7) losses, introduced in the "
             "thesis's order while the roll-out grows. binpick's bins hold boxes, so the masks to predict are filled boxes and a "
             "detection is the box round a step's largest blob, scored by the step's objectness. "
             f"Pre-trained on `{rec['trained_on']['pretrain']}` ({rec['images_seen']['pretrain']:,} images seen; "
             f"{rod_budgets(result)}), fine-tuned on `{rec['trained_on']['finetune']}` ({rec['images_seen']['finetune']:,} images). "
             "AP50; the shipped crop-query ROD on the same tasks beside it (fine-tuned; its pickability head on for the pickable "
             "targets, off where every copy is a target):", "",
             "| test set | targets | recurrent | ROD shipped |", "|---|---|---|---|",
             f"| shifted set-up (held-out products) | every copy | {ap(rec['shifted_domain'])} | {ap(rod['shifted_domain'])} |"]
    for category in HELD_OUT:
        lines.append(f"| held-out {category}, default bins | every copy | {ap(rec['zero_shot'].get(category))} | "
                     f"{ap(rod['zero_shot'].get(category))} |")
    lines += [f"| seen products, default bins | pickable by Policy 1 | {ap(rec['seen'])} | {ap(rod['seen'])} |", "",
              f"`detect` at batch 1, 320 px, 2 threads: **{rec['ms_per_image']} ms** per image (the roll-out of "
              "every step; ROD's `predict`: `latency_ms` above)."]
    steps = rec.get("repeated_steps")
    if steps:
        lines += ["", f"What it learnt (`python experiments/rod_recurrent.py repeats`, {steps['tasks']} tasks of {steps['data']}): "
                  f"{steps['boxes_per_task']} boxes per task, and **{steps['share']:.0%}** of them overlap an earlier step's box "
                  "(IoU > 0.5): the steps find one region again and again, often a blob over several touching copies, while the "
                  "stop flag falls step by step much alike from image to image (how many steps to expect, not whether a new copy "
                  "was found) — the thesis's finding "
                  "(Fig 5.5a: the same mask at each step). A feed-forward ROD sees every copy at once; the recurrent decoder "
                  "must keep in its state what it has found, and at these budgets it does not."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("phase", choices=["pretrain", "finetune", "report", "repeats"])
    parser.add_argument("--set", dest="settings", action="append", help="KEY=VALUE overriding the config (e.g. images=8000)")
    parser.add_argument("--pretrained", type=Path, default=_common.ROOT / "runs" / "rod_recurrent" / "pretrain")
    parser.add_argument("--finetuned", type=Path, default=_common.ROOT / "runs" / "rod_recurrent" / "finetune")
    args = parser.parse_args()
    os.chdir(_common.ROOT)  # configs name the data relative to the repository
    if args.phase == "pretrain":
        train(PRETRAIN, args.settings)
    elif args.phase == "finetune":
        train(FINETUNE, args.settings)
    elif args.phase == "repeats":
        repeats(args.pretrained)
    else:
        report(args.pretrained, args.finetuned)


if __name__ == "__main__":
    main()

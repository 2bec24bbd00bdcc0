"""The picking detector through ONNX Runtime beside PyTorch, on this machine: the same boxes, and the
milliseconds per image.

    python benchmarks/onnx_latency.py [--turns 30] [--blocks 5] [--threads 2]

Both paths run ``Detector.predict`` on the sample frame that ships (its colour, shop photo and depth)
with the shipped ``rod_photo_learnt_tiny_320`` and its pickability head: only the detector's network
differs (PyTorch with batch norms folded, or the exported graph in ONNX Runtime). Agreement is
checked on the sample frame and on flipped and shifted copies of it, down to score 0.05. Writes
``latency_ms.onnx`` into results/rod.json (the rest of that file is kept) and the ONNX section of
docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import sys
import tempfile
import time

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "experiments"))  # _common: results and docs

import _common  # noqa: E402


def iou(a, b) -> float:
    ax2, ay2, bx2, by2 = a[0] + a[2], a[1] + a[3], b[0] + b[2], b[1] + b[3]
    w, h = max(0.0, min(ax2, bx2) - max(a[0], b[0])), max(0.0, min(ay2, by2) - max(a[1], b[1]))
    union = a[2] * a[3] + b[2] * b[3] - w * h
    return w * h / union if union > 0 else 1.0


def agreement(torch_detector, onnx_detector, frames) -> dict:
    worst_iou, worst_score, boxes = 1.0, 0.0, 0
    for rgb, photo, depth in frames:
        a = torch_detector.predict(rgb, query_image=photo, depth=depth, min_score=0.05)
        b = onnx_detector.predict(rgb, query_image=photo, depth=depth, min_score=0.05)
        if len(a.boxes) != len(b.boxes):
            return {"same_count": False, "torch": len(a.boxes), "onnx": len(b.boxes)}
        for box_a, box_b, score_a, score_b in zip(a.boxes, b.boxes, a.scores, b.scores):
            worst_iou = min(worst_iou, iou(box_a, box_b))
            worst_score = max(worst_score, abs(float(score_a) - float(score_b)))
            boxes += 1
    return {"same_count": True, "boxes": boxes, "min_iou": round(float(worst_iou), 6), "max_score_diff": float(f"{worst_score:.3g}")}


def timed(detector, rgb, photo, depth, turns: int, blocks: int) -> list[float]:
    for _ in range(3):
        detector.predict(rgb, query_image=photo, depth=depth)
    medians = []
    for _ in range(blocks):
        started = time.perf_counter()
        for _ in range(turns):
            detector.predict(rgb, query_image=photo, depth=depth)
        medians.append(round(1000 * (time.perf_counter() - started) / turns, 1))
    return medians


def section(rod: dict) -> str:
    """The ONNX section of docs/RESULTS.md, from results/rod.json's ``latency_ms.onnx`` (the weights: the
    ones its ``measured`` names)."""
    result = rod["latency_ms"]["onnx"]
    weights = result["measured"].split(": ", 1)[1].split(" through ", 1)[0]
    same = result["agreement"]
    return "\n".join([
        "## The picking detector in ONNX Runtime", "",
        f"`python benchmarks/onnx_latency.py` → `results/rod.json` (`latency_ms.onnx`). `{weights}` exported by "
        "`Detector.export(\"onnx\")` (photo correlation as a convolution, opset 18) and run by ONNX Runtime's CPU provider, "
        "beside the same weights in PyTorch; both through `Detector.predict` on the sample frame with its shop photo and depth "
        "(the pickability head re-scores in PyTorch on both paths).", "",
        "| runtime | ms per image (median of blocks) | blocks |", "|---|---|---|",
        f"| PyTorch (batch norms folded) | {result['torch']} | {', '.join(map(str, result['torch_blocks']))} |",
        f"| ONNX Runtime | {result['onnx']} | {', '.join(map(str, result['onnx_blocks']))} |", "",
        (f"Agreement on 4 frames (the sample, flipped and shifted), {same['boxes']} boxes down to score 0.05: smallest IoU "
         f"{same['min_iou']}, largest score difference {same['max_score_diff']} (must: IoU ≥ 0.99, scores within 1e-3)."
         if same.get("same_count") else f"Agreement: different box counts (PyTorch {same['torch']}, ONNX {same['onnx']})."),
        f"Export took {result['export_s']} s; peak memory {result['peak_rss_mib']} MiB; load average {result['load_average']}.",
    ])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--turns", type=int, default=30)
    parser.add_argument("--blocks", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    import numpy as np
    import torch

    from binpick.core.files import read_image
    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.core.depth import read_depth
    from binpick.samples import SAMPLE_FRAME

    torch.set_num_threads(args.threads)
    os.environ["XDG_CACHE_HOME"] = tempfile.mkdtemp(prefix="binpick-onnx-")  # export afresh: its time is measured too
    started = time.perf_counter()
    onnx_detector = Detector.load(PICKING, runtime="onnx")
    export_s = round(time.perf_counter() - started, 1)
    torch_detector = Detector.load(PICKING)
    rgb, photo = read_image(SAMPLE_FRAME / "rgb.png"), read_image(SAMPLE_FRAME / "photo.png", keep_alpha=True)
    depth = read_depth(SAMPLE_FRAME / "depth.png")
    frames = [(rgb, photo, depth), (rgb[:, ::-1].copy(), photo, depth[:, ::-1].copy()),
              (np.roll(rgb, 40, axis=0), photo, np.roll(depth, 20, axis=0)), (rgb[::-1].copy(), photo[:, ::-1].copy(), depth[::-1].copy())]
    same = agreement(torch_detector, onnx_detector, frames)
    torch_ms = timed(torch_detector, rgb, photo, depth, args.turns, args.blocks)
    onnx_ms = timed(onnx_detector, rgb, photo, depth, args.turns, args.blocks)
    result = {"torch": statistics.median(torch_ms), "onnx": statistics.median(onnx_ms), "torch_blocks": torch_ms,
              "onnx_blocks": onnx_ms, "threads": args.threads, "export_s": export_s, "agreement": same,
              "load_average": round(os.getloadavg()[0], 2),
              "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
              "measured": f"benchmarks/onnx_latency.py: {PICKING} through Detector.predict on the sample frame (photo, depth, "
                          f"pickability head), median of {args.blocks} blocks of {args.turns} turns, {args.threads} threads"}
    path = _common.RESULTS / "rod.json"
    data = json.loads(path.read_text())
    data.setdefault("latency_ms", {})["onnx"] = result
    from binpick.core.files import atomic_write_text

    atomic_write_text(path, json.dumps(data, indent=2) + "\n")
    _common.write_section_of("onnx", section, "rod.json")
    print(json.dumps({k: result[k] for k in ("torch", "onnx", "agreement", "export_s")}))


if __name__ == "__main__":
    main()

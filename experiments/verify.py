"""Is it the ordered product? The product check before a grasp, learnt against tuned.

    binpick data generate --out runs/data/random_20k --scenes 20000 --domain random --policies '' \\
        --held-out can,mug,toy --workers 2 --photo-views 4                  # randomised bins and studios
    binpick data generate --out runs/data/shifted --domain shifted --targets can,mug,toy --policies '' \\
        --scenes 120 --scenes-per-world 4 --seed 7                          # another camera, tote and light
    binpick data generate --out runs/data/verify_default --policies '' --scenes 160 --scenes-per-world 2 --seed 5
    python experiments/verify.py train [--scenes 8000] [--epochs 8]      # ships weights/product_verifier.safetensors
    python experiments/verify.py eval                                    # results/verify.json

``eval`` scores every instance (at least half visible) of each bin against the shop photo of the
product ordered in it (its canonical photo, as an order gives it): same product or not. Rows: the
hue-saturation histogram check with its tuned threshold (0.15), the same on a white-balanced frame
(shades of grey, p = 6), and the learnt verifier at probability 0.5. On binpick's own light (the
default bins) and on the shifted set-up (warm, hard light; products the verifier never saw).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import _common  # noqa: E402

DATA = _common.ROOT / "runs" / "data"
SETS = {"default": DATA / "verify_default", "shifted": DATA / "shifted"}
RUN = _common.ROOT / "runs" / "verifier"


def train(args) -> None:
    from binpick.cli import progress
    from binpick.detection.verifier import SHIPPED
    from binpick.detection.verifier_training import VerifierTrainConfig, train_verifier

    config = VerifierTrainConfig(data=str(args.data), out=str(args.out), scenes=args.scenes, epochs=args.epochs, threads=args.threads)
    with progress() as callback:
        metrics = train_verifier(config, callback)
    if args.ship:
        import shutil

        shutil.copyfile(Path(args.out) / "product_verifier.safetensors", SHIPPED)
    print(json.dumps({k: v for k, v in metrics.items() if k != "history"}, indent=1))


def white_balanced(rgb, p: int = 6):
    """Shades of grey (Finlayson & Trezzi 2004): each channel scaled so the frame's p-norm is grey."""
    import numpy as np

    values = rgb.astype(np.float32) + 1.0
    illuminant = (values ** p).reshape(-1, 3).mean(0) ** (1.0 / p)
    return np.clip(values * (illuminant.mean() / illuminant), 0, 255).astype(np.uint8)


def pairs_of(data: Path, limit: int | None):
    """Yield (photo, photo mask, rgb, depth, frame heights, boxes, same) per scene."""
    import numpy as np
    from PIL import Image

    from binpick.detection.data import read_image
    from binpick.detection.photos import photo_mask
    from binpick.grasping import DepthFrame, PinholeCamera

    for path in sorted((data / "scenes").glob("*.json"))[:limit]:
        record = json.loads(path.read_text())
        boxes = [a["bbox"] for a in record["annotations"] if a["visible_fraction"] >= 0.5 and a["area"] >= 100]
        same = [a["product"] == record["target"] for a in record["annotations"] if a["visible_fraction"] >= 0.5 and a["area"] >= 100]
        if not boxes:
            continue
        rgb = np.asarray(Image.open(data / record["file_name"]).convert("RGB"))
        depth = np.asarray(Image.open(data / record["depth_file"]), dtype=np.float32) / 1000.0
        frame = DepthFrame.from_depth(depth, PinholeCamera.from_record(record["camera"]))
        photo = read_image(data / "photos" / f"{record['target'].replace('/', '_')}.png", keep_alpha=True)
        yield photo, photo_mask(photo), rgb, frame.filled, frame.heights, np.array(boxes), np.array(same)


def evaluate(data: Path, verifier, limit: int | None) -> dict:
    import numpy as np

    from binpick.detection.verifier_training import scores
    from binpick.picking.colour import colour_histogram, colour_similarity

    found: dict[str, list] = {"histogram": [], "histogram_white_balanced": [], "learnt": []}
    labels = []
    for photo, mask, rgb, depth, heights, boxes, same in pairs_of(data, limit):
        histogram = colour_histogram(photo[..., :3], mask)
        balanced = white_balanced(rgb)
        found["histogram"] += [colour_similarity(histogram, rgb, heights, box) for box in boxes]
        found["histogram_white_balanced"] += [colour_similarity(histogram, balanced, heights, box) for box in boxes]
        found["learnt"] += list(verifier.probabilities(photo, mask, rgb, depth, boxes))
        labels += list(same.astype(int))
    labels = np.array(labels)
    thresholds = {"histogram": 0.15, "histogram_white_balanced": 0.15, "learnt": 0.5}
    rows = {name: {**scores(np.array(values), labels, thresholds[name]), "threshold": thresholds[name]}
            for name, values in found.items()}
    learnt = np.array(found["learnt"])
    rows["learnt"]["accepted_at"] = {f"{t:g}": {"right": round(float((learnt[labels == 1] >= t).mean()), 4),
                                                "wrong": round(float((learnt[labels == 0] >= t).mean()), 4)}
                                     for t in (0.1, 0.2, 0.3, 0.5, 0.7)}
    return rows


def evaluate_all(args) -> None:
    from binpick.detection.verifier import ProductVerifier

    verifier = ProductVerifier.load(args.weights)
    rows = {}
    for name, data in SETS.items():
        if not (data / "scenes").is_dir():
            sys.exit(f"{data} is missing: generate it first (see this script's docstring)")
        rows[name] = evaluate(data, verifier, args.limit)
        print(name, json.dumps(rows[name], indent=1))
    payload = {"sets": {k: str(v.relative_to(_common.ROOT)) for k, v in SETS.items()}, "verifier": verifier.meta,
               "pairs": rows, "peak_rss_mib": round(_common.peak_rss_mib(), 1)}
    _common.write_result("verify", payload)
    lines = ["## Is it the ordered product? (the check before a grasp)", "",
             "Every instance at least half visible, scored against the canonical shop photo of the product ordered in its bin "
             "(`python experiments/verify.py eval` → `results/verify.json`). *right accepted*: the ordered product's instances "
             "passing the check; *wrong accepted*: other products' instances passing it.", "",
             "| set-up | check | threshold | AUC | right accepted | wrong accepted | calibration error |", "|---|---|---|---|---|---|---|"]
    for name, methods in rows.items():
        for method, row in methods.items():
            lines.append(f"| {name} | {method} | {row['threshold']} | {row.get('auc')} | {row.get('right_accepted')} | "
                         f"{row.get('wrong_accepted')} | {row.get('ece') if method == 'learnt' else '—'} |")
    _common.write_section("verify", "\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train")
    t.add_argument("--data", type=Path, default=DATA / "random_20k")
    t.add_argument("--out", type=Path, default=RUN)
    t.add_argument("--scenes", type=int, default=8000)
    t.add_argument("--epochs", type=int, default=8)
    t.add_argument("--threads", type=int, default=2)
    t.add_argument("--ship", action="store_true", help="copy the weights into the package")
    e = sub.add_parser("eval")
    e.add_argument("--weights", type=Path, default=None, help="default: the shipped verifier")
    e.add_argument("--limit", type=int, default=None, help="scenes per set (default: all)")
    args = parser.parse_args()
    train(args) if args.command == "train" else evaluate_all(args)


if __name__ == "__main__":
    main()

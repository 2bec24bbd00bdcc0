"""Is it the ordered product? The product check before a grasp, learnt against tuned.

    binpick data generate --out runs/data/random_20k --scenes 20000 --domain random --policies '' \\
        --held-out can,mug,toy --workers 2 --photo-views 4                  # randomised bins and studios
    binpick data generate --out runs/data/shifted --domain shifted --targets can,mug,toy --policies '' \\
        --scenes 120 --scenes-per-world 4 --seed 7                          # another camera, tote and light
    binpick data generate --out runs/data/verify_default --policies '' --scenes 160 --scenes-per-world 2 --seed 5
    binpick data generate --out runs/data/verify_calibrate --domain random --targets can,mug,toy --policies '' \\
        --scenes 160 --scenes-per-world 2 --seed 11                         # held-out products, randomised light
    python experiments/verify.py train [--scenes 8000] [--epochs 8] --out runs/verifier
    python experiments/verify.py calibrate --weights runs/verifier/product_verifier.safetensors   # its threshold
    python experiments/verify.py eval --weights runs/verifier/product_verifier.safetensors        # results/verify.json
    python experiments/verify.py ship --weights runs/verifier/product_verifier.safetensors        # if no worse anywhere

``eval`` scores every instance (at least half visible) of each bin against the shop photo of the
product ordered in it (its canonical photo, as an order gives it): same product or not. Rows: the
hue-saturation histogram check with its tuned threshold (0.15), the same on a white-balanced frame
(shades of grey, p = 6), and the learnt verifier at its calibrated threshold (0.5 for weights without
one). On binpick's own light (the default bins) and on the shifted set-up (warm, hard light; products
the verifier never saw). *Look-alikes* are the other products' instances whose colours match the
photo's (histogram intersection >= 0.5): what only shape tells apart.

``calibrate`` chooses the learnt check's threshold on held-out products under randomised light (a set
none of the rows above uses): the lowest probability at which the pairs it accepts are at least
``--precision`` the ordered product; it is written into the weights, and the picker uses it.
``ship`` copies weights into the package only if they are no worse than the shipped ones (AUC, and
look-alikes accepted) on any set, unless ``--reason`` says why (kept in the weights).
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
CALIBRATION = DATA / "verify_calibrate"
LOOK_ALIKE = 0.5  # colour histogram intersection with the photo from which another product is a look-alike
RUN = _common.ROOT / "runs" / "verifier"


def train(args) -> None:
    from binpick.cli import progress
    from binpick.detection.verifier_training import VerifierTrainConfig, train_verifier

    config = VerifierTrainConfig(data=str(args.data), out=str(args.out), scenes=args.scenes, epochs=args.epochs, threads=args.threads,
                                 repainted=args.repainted)
    with progress() as callback:
        metrics = train_verifier(config, callback)
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


def scored_pairs(data: Path, verifiers: dict, limit: int | None) -> tuple[dict, object]:
    """Every pair's score by each check (the two histogram checks and each verifier), and the labels."""
    import numpy as np

    from binpick.picking.colour import colour_histogram, colour_similarity

    found: dict[str, list] = {"histogram": [], "histogram_white_balanced": [], **{name: [] for name in verifiers}}
    labels = []
    for photo, mask, rgb, depth, heights, boxes, same in pairs_of(data, limit):
        histogram = colour_histogram(photo[..., :3], mask)
        balanced = white_balanced(rgb)
        found["histogram"] += [colour_similarity(histogram, rgb, heights, box) for box in boxes]
        found["histogram_white_balanced"] += [colour_similarity(histogram, balanced, heights, box) for box in boxes]
        for name, verifier in verifiers.items():
            found[name] += list(verifier.probabilities(photo, mask, rgb, depth, boxes))
        labels += list(same.astype(int))
    return {name: np.array(values, dtype=float) for name, values in found.items()}, np.array(labels)


def threshold_of(verifier) -> float:
    """The threshold the picker uses with these weights: their calibrated one, else the picker's default."""
    from binpick.picking.product_check import THRESHOLDS

    return float(verifier.meta.get("threshold", THRESHOLDS["learnt"]))


def learnt_row(probabilities, labels, colour, threshold: float) -> dict:
    """The learnt check's row: scores at ``threshold``, precision and recall, look-alikes accepted."""
    from binpick.detection.verifier_training import scores

    accepted = probabilities >= threshold
    look_alike = (labels == 0) & (colour >= LOOK_ALIKE)
    return {**scores(probabilities, labels, threshold), "threshold": round(threshold, 4),
            "precision": round(float(labels[accepted].mean()), 4) if accepted.any() else None,
            "recall": round(float(accepted[labels == 1].mean()), 4) if (labels == 1).any() else None,
            "look_alikes": int(look_alike.sum()),
            "look_alikes_accepted": round(float(accepted[look_alike].mean()), 4) if look_alike.any() else None,
            "accepted_at": {f"{t:g}": {"right": round(float((probabilities[labels == 1] >= t).mean()), 4),
                                       "wrong": round(float((probabilities[labels == 0] >= t).mean()), 4)}
                            for t in (0.1, 0.2, 0.3, 0.5, 0.7)}}


def evaluate(data: Path, verifiers: dict, limit: int | None) -> dict:
    from binpick.detection.verifier_training import scores

    found, labels = scored_pairs(data, verifiers, limit)
    rows = {name: {**scores(found[name], labels, 0.15), "threshold": 0.15} for name in ("histogram", "histogram_white_balanced")}
    for name, verifier in verifiers.items():
        rows[name] = learnt_row(found[name], labels, found["histogram"], threshold_of(verifier))
    return rows


def verifiers_of(paths: list[Path] | None) -> dict:
    """``learnt``: the shipped verifier; each path given beside it under its run's name."""
    from binpick.detection.verifier import ProductVerifier

    verifiers = {"learnt": ProductVerifier.load()}
    for path in paths or []:
        verifiers[f"learnt:{Path(path).parent.name}"] = ProductVerifier.load(path)
    return verifiers


def evaluate_all(args) -> None:
    verifiers = verifiers_of(args.weights)
    rows = {}
    for name, data in SETS.items():
        if not (data / "scenes").is_dir():
            sys.exit(f"{data} is missing: generate it first (see this script's docstring)")
        rows[name] = evaluate(data, verifiers, args.limit)
        print(name, json.dumps({k: {m: v.get(m) for m in ("auc", "precision", "recall", "look_alikes_accepted")} for k, v in rows[name].items()}))
    payload = {"sets": {k: str(v.relative_to(_common.ROOT)) for k, v in SETS.items()},
               "verifier": verifiers["learnt"].meta, "candidates": {name: v.meta for name, v in verifiers.items() if name != "learnt"},
               "pairs": rows, "peak_rss_mib": round(_common.peak_rss_mib(), 1)}
    _common.write_result("verify", payload)
    _common.write_section_of("verify", section, "verify.json")


def section(result: dict) -> str:
    """The results page's section from results/verify.json as written."""
    def shown(row: dict, key: str):
        return "—" if row.get(key) is None else row[key]

    lines = ["## Is it the ordered product? (the check before a grasp)", "",
             "Every instance at least half visible, scored against the canonical shop photo of the product ordered in its bin "
             "(`python experiments/verify.py eval` → `results/verify.json`). *right accepted* (recall): the ordered product's "
             "instances passing the check; *wrong accepted*: other products' instances passing it; *precision*: of the instances "
             "passing, the share that are the ordered product; *look-alikes accepted*: other products whose colours match the "
             f"photo's (histogram intersection ≥ {LOOK_ALIKE}) passing it, of how many. The learnt check's threshold is the one "
             "calibrated with its weights on held-out products under randomised light (`python experiments/verify.py calibrate`); "
             "the threshold column is the one each row was measured at.", "",
             "| set-up | check | threshold | AUC | right accepted | wrong accepted | precision | look-alikes accepted (of) | calibration error |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, methods in result["pairs"].items():
        for method, row in methods.items():
            learnt = method.startswith("learnt")
            look_alikes = f"{shown(row, 'look_alikes_accepted')} ({shown(row, 'look_alikes')})" if learnt else "—"
            lines.append(f"| {name} | {method} | {row['threshold']} | {row.get('auc')} | {row.get('right_accepted')} | "
                         f"{row.get('wrong_accepted')} | {shown(row, 'precision') if learnt else '—'} | {look_alikes} | "
                         f"{shown(row, 'ece') if learnt else '—'} |")
    threshold = (result.get("verifier") or {}).get("threshold_chosen_on")
    if threshold:
        lines += ["", f"The shipped check's threshold, {result['verifier']['threshold']}, was chosen on `{threshold['set']}` "
                      f"({threshold['products']}; {threshold['pairs']} pairs) as the lowest giving precision ≥ "
                      f"{threshold['target_precision']}: there precision {threshold['precision']}, recall {threshold['recall']}."]
    return "\n".join(lines)


def calibrate(args) -> None:
    """The lowest threshold at which the accepted pairs of held-out products (randomised light) are at
    least ``--precision`` right, written into the weights with the precision and recall it gives there."""
    import numpy as np

    from binpick.detection.verifier import ProductVerifier

    if not (CALIBRATION / "scenes").is_dir():
        sys.exit(f"{CALIBRATION} is missing: generate it first (see this script's docstring)")
    verifier = ProductVerifier.load(args.weights)
    found, labels = scored_pairs(CALIBRATION, {"learnt": verifier}, args.limit)
    probabilities = found["learnt"]
    chosen = None
    for threshold in np.round(np.arange(0.02, 0.99, 0.01), 2):
        accepted = probabilities >= threshold
        if accepted.any() and labels[accepted].mean() >= args.precision:
            chosen = float(threshold)
            break
    if chosen is None:
        sys.exit(f"no threshold gives precision {args.precision} on {CALIBRATION.name}: the check cannot be calibrated to it")
    row = learnt_row(probabilities, labels, found["histogram"], chosen)
    if not row.get("pairs"):
        sys.exit(f"{CALIBRATION.name} holds only one kind of pair (same product or not): it cannot calibrate a threshold")
    curve = {f"{t:g}": {"precision": round(float(labels[probabilities >= t].mean()), 4) if (probabilities >= t).any() else None,
                        "recall": round(float((probabilities[labels == 1] >= t).mean()), 4)} for t in np.round(np.arange(0.1, 1.0, 0.1), 1)}
    verifier.save(args.weights, {"threshold": chosen, "threshold_chosen_on": {
        "set": CALIBRATION.name, "products": "held out (can, mug, toy), randomised light and camera", "target_precision": args.precision,
        "precision": row["precision"], "recall": row["recall"], "pairs": row["pairs"], "look_alikes_accepted": row["look_alikes_accepted"],
        "curve": curve}})
    print(json.dumps(curve))
    print(json.dumps({"threshold": chosen, **{k: row[k] for k in ("precision", "recall", "auc", "pairs", "look_alikes", "look_alikes_accepted")}}))


def ship(args) -> None:
    """Copy ``--weights`` into the package if they are no worse than the shipped check on any set
    (AUC, and look-alikes accepted, from results/verify.json as ``eval`` measured them)."""
    import shutil

    from binpick.detection.verifier import SHIPPED, ProductVerifier

    measured = json.loads((_common.RESULTS / "verify.json").read_text())
    rows = measured.get("pairs") or {}
    name = f"learnt:{Path(args.weights).parent.name}"
    digests = (measured.get("provenance") or {}).get("digests") or {}
    for path in (Path(args.weights).resolve(), SHIPPED):  # the very files eval measured, not namesakes or later edits
        key = _common.repo_relative(path)
        if digests.get(key) != _common.input_digests_of([path]).get(key):
            sys.exit(f"{key} is not the file results/verify.json measured: python experiments/verify.py eval --weights {args.weights}")
    worse = []
    for set_name in SETS:
        mine, shipped = (rows.get(set_name) or {}).get(name), (rows.get(set_name) or {}).get("learnt")
        if mine is None or shipped is None or mine.get("auc") is None or shipped.get("auc") is None:
            sys.exit(f"{name} or the shipped check has no AUC on {set_name}: python experiments/verify.py eval --weights {args.weights}")
        if mine["auc"] < shipped["auc"]:
            worse.append(f"{set_name} AUC {mine['auc']} < {shipped['auc']}")
        if (mine.get("look_alikes_accepted") or 0) > (shipped.get("look_alikes_accepted") or 0):
            worse.append(f"{set_name} look-alikes accepted {mine['look_alikes_accepted']} > {shipped['look_alikes_accepted']}")
    if worse and not args.reason:
        sys.exit(f"not shipped: {name} is worse than the shipped check on {'; '.join(worse)} (give --reason TEXT to ship it anyway)")
    verifier = ProductVerifier.load(args.weights)
    verifier.save(args.weights, {"shipped": {"replaced": ProductVerifier.load().meta.get("trained_on"), "worse_on": worse,
                                             "reason": args.reason, "commit": _common.provenance().get("commit")}})
    shutil.copyfile(args.weights, SHIPPED)
    print(f"shipped {args.weights} -> {SHIPPED.relative_to(_common.ROOT)}" + (f" (worse on {'; '.join(worse)}: {args.reason})" if worse else ""))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train")
    t.add_argument("--data", type=Path, default=DATA / "random_20k")
    t.add_argument("--out", type=Path, default=RUN)
    t.add_argument("--scenes", type=int, default=8000)
    t.add_argument("--epochs", type=int, default=8)
    t.add_argument("--threads", type=int, default=2)
    t.add_argument("--repainted", type=float, default=0.0, help="share of negatives repainted in the photo's colours")
    e = sub.add_parser("eval")
    e.add_argument("--weights", type=Path, nargs="*", default=None, help="candidates measured beside the shipped verifier")
    e.add_argument("--limit", type=int, default=None, help="scenes per set (default: all)")
    c = sub.add_parser("calibrate")
    c.add_argument("--weights", type=Path, required=True)
    c.add_argument("--precision", type=float, default=0.98, help="share of accepted pairs that must be the ordered product")
    c.add_argument("--limit", type=int, default=None)
    s = sub.add_parser("ship")
    s.add_argument("--weights", type=Path, required=True)
    s.add_argument("--reason", default=None, help="why weights worse somewhere are shipped anyway (kept in them)")
    args = parser.parse_args()
    {"train": train, "eval": evaluate_all, "calibrate": calibrate, "ship": ship}[args.command](args)


if __name__ == "__main__":
    main()

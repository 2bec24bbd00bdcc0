"""Statistics of a generated warehouse data set, and its pictures for the docs.

    binpick data generate --out runs/data/bins_2000 --scenes 2000 --workers 2 --held-out can,mug,toy --set split_rule=random
    python experiments/data_stats.py [--data runs/data/bins_2000]

Writes results/data_stats.json ({scenes, instances_per_image, pickable_fraction {policy},
pickability_differs_fraction, ...}), the data-stats section of docs/RESULTS.md,
docs/img/bins_labelled.png (one bin, one panel per grasp policy, Fig 5.13 style) and
docs/img/shop_photos.png (every product's shop photo).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import _common  # noqa: E402
import numpy as np  # noqa: E402

from binpick.warehouse.coco import dataset_stats, load_records, open_dataset  # noqa: E402

IMAGES = _common.ROOT / "docs" / "img"


def pick_example(records: list[dict], policies: list[str]) -> dict:
    """A scene where the policies disagree on several instances (what Fig 5.13 shows)."""
    def disagreements(record: dict) -> int:
        return sum(len({a["pickable"].get(p) for p in policies}) > 1 for a in record["annotations"] if a["is_target"])

    return max(records, key=lambda r: (disagreements(r), len(r["annotations"])))


def section(result: dict) -> str:
    """The data-set section of docs/RESULTS.md, from results/data_stats.json (the policies: its
    ``pickable_fraction`` keys, in the data set's order)."""
    policies = list(result["pickable_fraction"])
    rows = ["## Warehouse bin data set (thesis §5.4.4, §6.3)", "",
            f"`python experiments/data_stats.py --data {_common.repo_relative(result['data'])}` → "
            "`results/data_stats.json`; pictures: `docs/img/bins_labelled.png`, `docs/img/shop_photos.png`.", "",
            "| | ours | target / thesis |", "|---|---|---|",
            f"| scenes | {result['scenes']:,} | 2,000 |",
            f"| instances per image | {result['instances_per_image']:.2f} ({result['target_instances_per_image']:.2f} of the ordered product) | — |"]
    for policy, fraction in result["pickable_fraction"].items():
        rows.append(f"| pickable by policy {policy} (jaws along the robot's {policy}-axis) | {fraction:.1%} | — |")
    if result["pickability_differs_fraction"] is not None:
        verdict = "met" if result["met"] else "missed"
        rows.append(f"| instances whose pickability differs between the policies | {result['pickability_differs_fraction']:.1%} | > 10% ({verdict}) |")
    if result["pickable_fraction_by_category"]:
        rows += ["", "Pickable fraction by product category (trial grasps from the saved scene state):", "",
                 "| category | instances | " + " | ".join(f"policy {p}" for p in policies) + " |", "|---|---|" + "---|" * len(policies)]
        for category, fractions in result["pickable_fraction_by_category"].items():
            rows.append(f"| {category} | {result['categories'].get(category, 0)} | " + " | ".join(f"{fractions.get(p, 0):.0%}" for p in policies) + " |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=_common.ROOT / "runs" / "data" / "bins_2000")
    args = parser.parse_args()
    manifest = open_dataset(args.data)
    policies = manifest["config"]["policies"]
    records = load_records(args.data)
    stats = dataset_stats(records, policies)
    result = {"data": str(args.data), "requested_scenes": manifest["config"].get("scenes"), **stats,
              "target_differs_fraction": 0.10,
              "met": stats["pickability_differs_fraction"] is not None and stats["pickability_differs_fraction"] > 0.10}
    _common.write_result("data_stats", result)

    from PIL import Image

    from _figures import contact_sheet, plot_policies_side_by_side

    IMAGES.mkdir(parents=True, exist_ok=True)
    if policies:
        plot_policies_side_by_side(args.data, pick_example(records, policies), policies, IMAGES / "bins_labelled.png")
    photos = {p.stem: np.asarray(Image.open(p).convert("RGB").resize((128, 128))) for p in sorted((args.data / "photos").glob("*.png"))}
    if photos:
        Image.fromarray(contact_sheet(photos, columns=9)).save(IMAGES / "shop_photos.png")

    print(_common.write_section_of("data_stats", section, "data_stats.json"))


if __name__ == "__main__":
    main()

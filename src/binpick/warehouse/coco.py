"""A data set's files read back and merged: scene records checked field by field, COCO annotations,
counts and the data-set card."""

from __future__ import annotations

from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from binpick.core.errors import ConfigError, InputFileError
from binpick.core.files import (
    atomic_write_json,
    atomic_write_text,
    read_json_object,
    require_fields,
)
from binpick.warehouse.generation import FORMAT


def open_dataset(data: Path) -> dict[str, Any]:
    """The manifest of a data-set folder, or one clear line saying why it is not one."""
    manifest = Path(data) / "dataset.json"
    if not manifest.is_file():
        raise ConfigError(f"{str(data)!r} is not a binpick data set (no dataset.json); make one with: binpick data generate --out {data}")
    content = read_json_object(manifest, "data-set manifest", {"format": str, "config": dict, "products": list})
    if content["format"] != FORMAT:
        raise ConfigError(f"{manifest} is not a {FORMAT} data set")
    require_fields(content["config"], {"policies": list}, f"data-set manifest {str(manifest)!r}")
    if not all(isinstance(p, dict) and isinstance(p.get("id"), str) and isinstance(p.get("category"), str)
               for p in content["products"]):
        raise InputFileError(f"data-set manifest {str(manifest)!r} is damaged: a product has no id or category")
    return content


_RECORD = {"index": int, "file_name": str, "depth_file": str, "width": int, "height": int, "split": str, "target": str,
           "seed": int, "annotations": list, "picked_by": (str, type(None))}
_ANNOTATION = {"slot": int, "product": str, "is_target": bool, "is_query": bool, "bbox": list, "area": (int, float),
               "visible_fraction": (int, float), "pickable": dict}


def read_record(path: Path) -> dict[str, Any]:
    """One scene's JSON, checked field by field: a damaged file is one line that says how to redo it."""
    where = f"scene file {str(path)!r}"
    try:
        record = read_json_object(path, "scene file")
        require_fields(record, _RECORD, where)
        for annotation in record["annotations"]:
            if not isinstance(annotation, dict):
                raise InputFileError(f"{where} is damaged: an annotation is not an object")
            require_fields(annotation, _ANNOTATION, where)
            box = annotation["bbox"]
            if len(box) != 4 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in box):
                raise InputFileError(f"{where} is damaged: a bbox is not 4 numbers")
    except InputFileError as error:
        raise InputFileError(f"{error}; delete it and run generate again to redo that scene") from None
    return record


def read_scene(data: Path, index: int) -> tuple[dict[str, Any], list[str]]:
    manifest = open_dataset(data)
    path = Path(data) / "scenes" / f"{index:06d}.json"
    if not path.is_file():
        raise ConfigError(f"scene {index} is not in {data} (scenes 0..{manifest['config'].get('scenes', '?')} may still be generating)")
    return read_record(path), manifest["config"]["policies"]


# ---------------------------------------------------------------------- COCO files and the card
def load_records(out: Path) -> list[dict[str, Any]]:
    return [read_record(path) for path in sorted((Path(out) / "scenes").glob("*.json"))]


def to_coco(records: list[dict[str, Any]], library_products: list[dict[str, str]]) -> dict[str, Any]:
    library_products = list(library_products)
    listed = {p["id"] for p in library_products}
    for record in records:  # a randomised world's own products are not in the library
        for a in record["annotations"]:
            if a["product"] not in listed:
                listed.add(a["product"])
                library_products.append({"id": a["product"], "category": a.get("category", "random")})
    category_ids = {p["id"]: i + 1 for i, p in enumerate(library_products)}
    coco = {"info": {"description": "binpick warehouse bins", "format": FORMAT},
            "categories": [{"id": category_ids[p["id"]], "name": p["id"], "supercategory": p["category"]} for p in library_products],
            "images": [], "annotations": []}
    next_id = 1
    for record in records:
        image_id = record["index"] + 1
        query_id = None
        for a in record["annotations"]:
            x, y, w, h = a["bbox"]
            coco["annotations"].append({
                "id": next_id, "image_id": image_id, "category_id": category_ids[a["product"]], "bbox": [x, y, w, h],
                "area": a["area"], "iscrowd": 0, "instance_id": a["slot"], "visible_fraction": a["visible_fraction"],
                "is_target": a["is_target"], "is_query": a["is_query"], "pickable": a["pickable"],
                **({"pickable_rate": a["pickable_rate"]} if "pickable_rate" in a else {})})  # label_trials > 1
            if a["is_query"]:
                query_id = next_id
            next_id += 1
        coco["images"].append({"id": image_id, "file_name": record["file_name"], "depth_file": record["depth_file"],
                               "width": record["width"], "height": record["height"], "split": record["split"],
                               "target_product": record["target"], "query_annotation_id": query_id,
                               "picked_by": record["picked_by"], "seed": record["seed"],
                               **({"camera": record["camera"]} if record.get("camera") else {})})
    return coco


def finalise(out: Path) -> dict[str, Any]:
    """Merge the scene shards into COCO files (all, and one per split) and write the card."""
    out = Path(out)
    manifest = open_dataset(out)
    records = load_records(out)
    coco = to_coco(records, manifest["products"])
    atomic_write_json(out / "annotations.json", coco, indent=None)
    for split in ("train", "val", "test"):
        ids = {image["id"] for image in coco["images"] if image["split"] == split}
        atomic_write_json(out / f"annotations_{split}.json", coco | {
            "images": [i for i in coco["images"] if i["id"] in ids],
            "annotations": [a for a in coco["annotations"] if a["image_id"] in ids]}, indent=None)
    stats = dataset_stats(records, manifest["config"]["policies"])
    atomic_write_text(out / "CARD.md", card(stats, manifest))
    return stats


def dataset_stats(records: list[dict[str, Any]], policies: list[str]) -> dict[str, Any]:
    """Instances per image, pickable fraction per policy and category, and how often the policies disagree."""
    instances = [len(r["annotations"]) for r in records]
    targets = [a for r in records for a in r["annotations"] if a["is_target"]]
    labelled = [a for a in targets if all(p in a["pickable"] for p in policies)] if policies else []
    by_category: dict[str, dict[str, float]] = defaultdict(dict)
    for policy in policies:
        groups: dict[str, list[bool]] = defaultdict(list)
        for a in labelled:
            groups[a["category"]].append(a["pickable"][policy])
        for category, values in groups.items():
            by_category[category][policy] = round(float(np.mean(values)), 4)
    differs = [len({a["pickable"][p] for p in policies}) > 1 for a in labelled] if len(policies) > 1 else []
    splits = Counter(r["split"] for r in records)
    trials = [t["success"] for r in records for t in r.get("grasp_trials", [])]
    return {"scenes": len(records), "instances": int(sum(instances)),
            "grasp_trials": len(trials), "grasp_trial_success": round(float(np.mean(trials)), 4) if trials else None,
            "instances_per_image": round(float(np.mean(instances)), 3) if records else 0.0,
            "target_instances_per_image": round(len(targets) / max(1, len(records)), 3),
            "labelled_instances": len(labelled),
            "pickable_fraction": {p: round(float(np.mean([a["pickable"][p] for a in labelled])), 4) for p in policies} if labelled else {},
            "pickable_fraction_by_category": dict(sorted(by_category.items())),
            "pickability_differs_fraction": round(float(np.mean(differs)), 4) if differs else None,
            "scenes_with_a_pick": sum(r["picked_by"] is not None for r in records),
            "splits": dict(splits), "categories": dict(Counter(a["category"] for a in targets))}


def card(stats: dict[str, Any], manifest: dict[str, Any]) -> str:
    config = manifest["config"]
    lines = ["# binpick warehouse bins — data-set card", "",
             f"Generated by `binpick data generate` ({FORMAT}); seed {config['seed']}, {config['image_size']} px overhead RGB-D,",
             f"{config['copies'][0]}–{config['copies'][1]} copies of one product plus {config['distractors'][0]}–{config['distractors'][1]} "
             f"distractor products per bin; grasp policies: {', '.join(config['policies']) or 'none'}.", "",
             "| | |", "|---|---|",
             f"| scenes | {stats['scenes']} (splits: {', '.join(f'{k} {v}' for k, v in sorted(stats['splits'].items()))}) |",
             f"| instances | {stats['instances']} ({stats['instances_per_image']} per image, {stats['target_instances_per_image']} of the target) |",
             f"| labelled target instances | {stats['labelled_instances']} |"]
    for policy, fraction in stats["pickable_fraction"].items():
        lines.append(f"| pickable by policy {policy} | {fraction:.1%} |")
    if stats.get("grasp_trials"):
        lines.append(f"| grasp trials (candidates from depth, executed with a carry) | {stats['grasp_trials']}, "
                     f"{stats['grasp_trial_success']:.1%} held |")
    if stats["pickability_differs_fraction"] is not None:
        lines.append(f"| pickability differs between policies | {stats['pickability_differs_fraction']:.1%} |")
    if stats["pickable_fraction_by_category"]:
        policies = config["policies"]
        lines += ["", "Pickable fraction by product category:", "", "| category | " + " | ".join(policies) + " |",
                  "|---|" + "---|" * len(policies)]
        for category, fractions in stats["pickable_fraction_by_category"].items():
            lines.append(f"| {category} | " + " | ".join(f"{fractions.get(p, float('nan')):.0%}" for p in policies) + " |")
    return "\n".join(lines) + "\n"

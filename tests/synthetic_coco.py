"""A tiny COCO-format data set of repeated objects, drawn in milliseconds, for detector tests."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

SHAPES = {"red_square": ("rectangle", (220, 40, 40)), "blue_disc": ("ellipse", (40, 80, 230)),
          "green_bar": ("bar", (40, 190, 60))}


def _draw(draw: ImageDraw.ImageDraw, kind: str, colour, x: int, y: int, size: int) -> list[float]:
    if kind == "bar":
        box = [x, y + size // 3, x + size, y + 2 * size // 3]
        draw.rectangle(box, fill=colour)
    else:
        box = [x, y, x + size, y + size]
        getattr(draw, kind)(box, fill=colour)
        draw.rectangle([x + size // 3, y + size // 3, x + 2 * size // 3, y + 2 * size // 3], fill=(250, 250, 250))
    return [float(box[0]), float(box[1]), float(box[2] - box[0] + 1), float(box[3] - box[1] + 1)]


def make_coco(folder: Path, images: int = 12, size: int = 128, seed: int = 0, pickable: bool = False,
              depth: bool = False, pickable_rule: str = "left") -> Path:
    """Each image: 2-4 copies of one shape and one copy of another, on a noisy grey floor, without
    overlaps. With ``pickable``, copies left of the image centre are labelled pickable by policy
    ``y`` and the first copy is the picked query (the warehouse format); ``pickable_rule="small"``
    labels the copies smaller than the middle of the size range instead (a window shows it). With ``depth``, a 16-bit
    depth PNG per image (mm; floor at 800, objects 40 mm tall) named by ``depth_file``."""
    rng = np.random.default_rng(seed)
    folder = Path(folder)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    if depth:
        (folder / "depth").mkdir(exist_ok=True)
    names = list(SHAPES)
    coco = {"images": [], "annotations": [], "categories": [{"id": i + 1, "name": n, "supercategory": n} for i, n in enumerate(names)]}
    for index in range(images):
        floor = rng.normal(120, 12, (size, size, 3)).clip(0, 255).astype(np.uint8)
        heights = np.full((size, size), 800, np.uint16)
        picture = Image.fromarray(floor)
        draw = ImageDraw.Draw(picture)
        target, other = rng.choice(len(names), 2, replace=False)
        copies = int(rng.integers(2, 5))
        cells = rng.permutation(9)[:copies + 1]  # a 3 x 3 layout keeps objects apart
        for k, cell in enumerate(cells):
            category = target if k < copies else other
            kind, colour = SHAPES[names[category]]
            object_size = int(rng.integers(size // 6, size // 4))
            x = int(cell % 3 * size / 3 + rng.integers(2, size // 3 - object_size - 1))
            y = int(cell // 3 * size / 3 + rng.integers(2, size // 3 - object_size - 1))
            bbox = _draw(draw, kind, colour, x, y, object_size)
            heights[int(bbox[1]):int(bbox[1] + bbox[3]), int(bbox[0]):int(bbox[0] + bbox[2])] = 760
            annotation = {"id": len(coco["annotations"]) + 1, "image_id": index + 1, "category_id": int(category) + 1,
                          "bbox": bbox, "area": bbox[2] * bbox[3], "iscrowd": 0}
            if pickable and category == target:
                picked = object_size < (size // 6 + size // 4) / 2 if pickable_rule == "small" else bbox[0] + bbox[2] / 2 < size / 2
                annotation |= {"is_query": k == 0, "pickable": {"y": bool(picked)}}
            coco["annotations"].append(annotation)
        file_name = f"images/{index:04d}.png"
        picture.save(folder / file_name)
        coco["images"].append({"id": index + 1, "file_name": file_name, "width": size, "height": size})
        if depth:
            Image.fromarray(heights).save(folder / f"depth/{index:04d}.png")
            coco["images"][-1]["depth_file"] = f"depth/{index:04d}.png"
    path = folder / "annotations.json"
    path.write_text(json.dumps(coco))
    return path

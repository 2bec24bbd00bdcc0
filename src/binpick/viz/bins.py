"""Bin scenes labelled as thesis Fig 5.13: green = pickable, red = unpickable (by the chosen grasp
policy), blue = the query instance, grey = other products."""

from __future__ import annotations

from pathlib import Path

import numpy as np


COLOURS = {"pickable": (40, 200, 60), "unpickable": (230, 40, 40), "query": (40, 90, 255), "other": (150, 150, 150)}


def draw_boxes(image: np.ndarray, boxes: list[tuple[tuple[float, float, float, float], str]], width: int = 3) -> np.ndarray:
    """Boxes (x, y, w, h) in the named colours, drawn on a copy of ``image``."""
    from PIL import Image, ImageDraw

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    for (x, y, w, h), kind in boxes:
        draw.rectangle([x, y, x + w - 1, y + h - 1], outline=COLOURS[kind], width=width)
    return np.asarray(picture)


def labelled_scene(data_dir: Path, record: dict, policy: str | None) -> np.ndarray:
    from binpick.core.files import inside, opened_image

    path = inside(data_dir, record["file_name"], "scene image")
    with opened_image(path, "scene image") as opened:
        image = np.asarray(opened.convert("RGB"))
    boxes = []
    for a in sorted(record["annotations"], key=lambda a: a["is_query"]):  # the query on top
        if a["is_query"]:
            kind = "query"
        elif not a["is_target"]:
            kind = "other"
        elif policy is None or policy not in a["pickable"]:
            kind = "pickable"
        else:
            kind = "pickable" if a["pickable"][policy] else "unpickable"
        boxes.append((a["bbox"], kind))
    return draw_boxes(image, boxes)

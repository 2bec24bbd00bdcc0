"""Pictures of repeated object detection: overlays (query blue, detections orange, as thesis Fig
5.10), max-heatmap images (Fig 6.11), precision-recall curves and AP by object scale (Fig 5.12)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

ORANGE, BLUE = (255, 140, 0), (40, 90, 255)


def overlay(image: np.ndarray, boxes: np.ndarray, scores: np.ndarray, query_box: np.ndarray | None = None,
            query_image: np.ndarray | None = None, min_score: float = 0.3) -> np.ndarray:
    """Detections scoring at least ``min_score`` in orange with their scores, the query box in blue,
    a photo query inset at the top right. Boxes are x, y, w, h."""
    from PIL import Image, ImageDraw

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    width = max(2, image.shape[1] // 200)
    for (x, y, w, h), score in zip(boxes, scores):
        if score >= min_score:
            draw.rectangle([x, y, x + w - 1, y + h - 1], outline=ORANGE, width=width)
            draw.text((x + 3, y + 2), f"{score:.2f}", fill=ORANGE)
    if query_box is not None:
        x, y, w, h = query_box
        draw.rectangle([x, y, x + w - 1, y + h - 1], outline=BLUE, width=width)
    if query_image is not None:
        side = image.shape[1] // 4
        inset = Image.fromarray(query_image).resize((side, side))
        picture.paste(inset, (image.shape[1] - side - 4, 4))
        draw.rectangle([image.shape[1] - side - 5, 3, image.shape[1] - 4, side + 4], outline=BLUE, width=2)
    return np.asarray(picture)


def heatmap_image(heatmap: np.ndarray, size: int) -> np.ndarray:
    """A max heatmap (values in [-1, 1]) as an RGB image of ``size`` pixels (Fig 6.11's bottom row)."""
    import matplotlib
    from PIL import Image

    colours = matplotlib.colormaps["magma"](np.clip((heatmap + 1) / 2, 0, 1))[..., :3]
    return np.asarray(Image.fromarray((colours * 255).astype(np.uint8)).resize((size, size), Image.NEAREST))


def plot_pr_curves(curves: dict[str, dict], path: Path, title: str) -> None:
    """Precision against recall at IoU 0.5, one line per model (``{name: {recall, precision, ap50}}``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axis = plt.subplots(figsize=(5.2, 4.4))
    for name, curve in curves.items():
        if curve.get("recall"):
            axis.plot(curve["recall"], curve["precision"], label=f"{name} (AP50 {curve['ap50']:.2f})")
    axis.set_xlabel("recall")
    axis.set_ylabel("precision")
    axis.set_xlim(0, 1)
    axis.set_ylim(0, 1.02)
    axis.set_title(title)
    axis.legend(fontsize=8)
    axis.grid(alpha=0.3)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_ap_by_scale(results: dict[str, dict[str, float | None]], path: Path, title: str) -> None:
    """AP50 per object-scale bin, one line per layout (Fig 5.12)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axis = plt.subplots(figsize=(6.0, 4.2))
    for name, by_scale in results.items():
        labels = list(by_scale)
        values = [np.nan if by_scale[k] is None else by_scale[k] for k in labels]
        axis.plot(range(len(labels)), values, marker="o", label=name)
        axis.set_xticks(range(len(labels)), labels)
    axis.set_xlabel("object scale: sqrt(box area) / image side")
    axis.set_ylabel("AP50")
    axis.set_ylim(0, 1)
    axis.set_title(title)
    axis.legend()
    axis.grid(alpha=0.3)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)

"""Pictures of repeated object detection: overlays (query blue, detections orange, as thesis Fig
5.10), max-heatmap images (Fig 6.11), precision-recall curves and AP by object scale (Fig 5.12)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

ORANGE, BLUE = (255, 140, 0), (40, 90, 255)


def _font(size: int):
    """A scalable font at ``size`` pixels (Pillow's bundled one: no system fonts needed)."""
    from PIL import ImageFont

    return ImageFont.load_default(size=size)


def _label(draw, xy: tuple[float, float], text: str, colour, font) -> None:
    """Text on a dark box, readable on any background."""
    left, top, right, bottom = draw.textbbox(xy, text, font=font)
    draw.rectangle([left - 2, top - 1, right + 2, bottom + 1], fill=(20, 20, 20))
    draw.text(xy, text, fill=colour, font=font)


def overlay(image: np.ndarray, boxes: np.ndarray, scores: np.ndarray, query_box: np.ndarray | None = None,
            query_image: np.ndarray | None = None, min_score: float = 0.3, legend: str | None = None) -> np.ndarray:
    """Detections scoring at least ``min_score`` in orange with their scores, the query box in blue,
    a photo query inset at the top right, and a legend (``legend`` says what the boxes are where they
    are not all the detections: a plan's). Boxes are x, y, w, h. Line widths and text
    scale with the image, so a 416 px scene and a 1920 px camera frame both read well."""
    from PIL import Image, ImageDraw

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    width = max(2, image.shape[1] // 200)
    font = _font(max(11, image.shape[1] // 32))
    shown = 0
    for (x, y, w, h), score in zip(boxes, scores):
        if score >= min_score:
            draw.rectangle([x, y, x + w - 1, y + h - 1], outline=ORANGE, width=width)
            _label(draw, (x + width + 1, y + width), f"{score:.2f}", ORANGE, font)
            shown += 1
    if query_box is not None:
        x, y, w, h = query_box
        draw.rectangle([x, y, x + w - 1, y + h - 1], outline=BLUE, width=width)
    if query_image is not None:
        side = image.shape[1] // 4
        inset = Image.fromarray(query_image).resize((side, side))
        picture.paste(inset, (image.shape[1] - side - 4, 4))
        draw.rectangle([image.shape[1] - side - 5, 3, image.shape[1] - 4, side + 4], outline=BLUE, width=2)
    query = "query: photo (inset)" if query_image is not None else "query: blue box"
    what = legend or f"{shown} detections >= {min_score:.2f} (orange, detector score)"
    _label(draw, (6, image.shape[0] - font.size - 8), f"{query}; {what}", (235, 235, 235), font)
    return np.asarray(picture)


GREEN, RED = (40, 200, 60), (230, 40, 40)


def draw_jaws(image: np.ndarray, jaws: list[tuple[np.ndarray, np.ndarray, bool, str]]) -> np.ndarray:
    """Grasps drawn as jaw lines: for each ``(finger_a, finger_b, succeeded, label)`` (pixels (u, v) of
    the open fingers), a line between the fingers with a bar for each finger, green where the grasp
    placed the product and red where it did not, and its label (the attempt's number) beside it."""
    from PIL import Image, ImageDraw

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    width = max(2, image.shape[1] // 200)
    font = _font(max(11, image.shape[1] // 32))
    for a, b, succeeded, label in jaws:
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        colour = GREEN if succeeded else RED
        across = b - a
        bar = np.array([-across[1], across[0]]) / max(np.linalg.norm(across), 1e-6) * max(4.0, 0.12 * np.linalg.norm(across))
        draw.line([tuple(a), tuple(b)], fill=colour, width=width)
        for finger in (a, b):
            draw.line([tuple(finger - bar), tuple(finger + bar)], fill=colour, width=2 * width)
        _label(draw, tuple(b + bar + 2), label, colour, font)
    return np.asarray(picture)


def draw_cups(image: np.ndarray, cups: list[tuple[np.ndarray, float, bool, str]]) -> np.ndarray:
    """Suction grasps drawn as the cup's lip: for each ``(centre, radius, succeeded, label)`` (pixels),
    a circle with a dot at its centre, green where the grasp placed the product and red where it did
    not, and its label beside it."""
    from PIL import Image, ImageDraw

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    width = max(2, image.shape[1] // 200)
    font = _font(max(11, image.shape[1] // 32))
    for centre, radius, succeeded, label in cups:
        (u, v), colour = np.asarray(centre, dtype=float), GREEN if succeeded else RED
        draw.ellipse([u - radius, v - radius, u + radius, v + radius], outline=colour, width=width)
        draw.ellipse([u - width, v - width, u + width, v + width], fill=colour)
        _label(draw, (u + radius + 2, v - radius - 2), label, colour, font)
    return np.asarray(picture)


def heatmap_figure(heatmaps: list[np.ndarray], image: np.ndarray | None = None) -> np.ndarray:
    """The ROD modules' max heatmaps (Eq 5.12; Fig 6.11's bottom row) as one RGB picture: the scene,
    then one panel per pyramid level with its title and a shared colour bar of the correlation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = ([image] if image is not None else []) + list(heatmaps)
    fig, axes = plt.subplots(1, len(panels), figsize=(3.0 * len(panels) + 1.0, 3.3), squeeze=False, layout="constrained")
    shown = None
    for index, (axis, panel) in enumerate(zip(axes[0], panels)):
        if image is not None and index == 0:
            axis.imshow(panel)
            axis.set_title("scene")
        else:
            level = index - (image is not None)
            shown = axis.imshow(panel, cmap="magma", vmin=-1, vmax=1)
            axis.set_title(f"ROD level {level + 1}: {panel.shape[1]}×{panel.shape[0]} cells")
        axis.set_xticks([])
        axis.set_yticks([])
    if shown is not None:
        fig.colorbar(shown, ax=list(axes[0]), fraction=0.03, label="max correlation with the query")
    fig.canvas.draw()
    picture = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return picture


def captioned(frame: np.ndarray, text: str) -> np.ndarray:
    """A frame with ``text`` on a dark band along its bottom (a GIF's "attempt 1: slipped")."""
    from PIL import Image, ImageDraw

    height, width = frame.shape[:2]
    band = max(14, height // 14)
    picture = Image.new("RGB", (width, height + band), (20, 20, 20))
    picture.paste(Image.fromarray(np.ascontiguousarray(frame[..., :3])), (0, 0))
    ImageDraw.Draw(picture).text((6, height + band // 2), text, fill=(255, 255, 255), font=_font(max(10, band - 4)), anchor="lm")
    return np.asarray(picture)


def depth_picture(depth: np.ndarray) -> np.ndarray:
    """Depth (metres; 0 or non-finite: no reading) as colours, near bright, far dark, holes black, with
    its range written in a corner: what the grasp planner saw."""
    import matplotlib
    from PIL import Image, ImageDraw

    depth = np.asarray(depth, dtype=np.float32)
    valid = np.isfinite(depth) & (depth > 0)
    near, far = (np.percentile(depth[valid], [2, 98]) if valid.any() else (0.0, 1.0))
    scaled = np.clip((far - np.where(valid, depth, far)) / max(far - near, 1e-6), 0, 1)
    colours = (matplotlib.colormaps["viridis"](scaled)[..., :3] * 255).astype(np.uint8)
    colours[~valid] = 0
    picture = Image.fromarray(colours)
    font = _font(max(10, depth.shape[0] // 24))
    _label(ImageDraw.Draw(picture), (4, 4), f"depth {near:.2f}-{far:.2f} m, holes black", (255, 255, 255), font)
    return np.asarray(picture)


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
    finish_plot(fig, axis, path, title)


def finish_plot(fig, axis, path: Path, title: str) -> None:
    """Title, legend and grid; then the PNG, written where asked."""
    import matplotlib.pyplot as plt

    axis.set_title(title)
    axis.legend(fontsize=8)
    axis.grid(alpha=0.3)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)

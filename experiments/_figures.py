"""Figures only the experiment scripts draw (the results page's pictures): AP by object scale, learning
curves, a heatmap as an image, bins labelled by several policies side by side, a contact sheet of
shop photos."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from binpick.viz.bins import COLOURS, labelled_scene
from binpick.viz.detection import finish_plot


def heatmap_image(heatmap: np.ndarray, size: int) -> np.ndarray:
    """A max heatmap (values in [-1, 1]) as an RGB image of ``size`` pixels (Fig 6.11's bottom row)."""
    import matplotlib
    from PIL import Image

    colours = matplotlib.colormaps["magma"](np.clip((heatmap + 1) / 2, 0, 1))[..., :3]
    return np.asarray(Image.fromarray((colours * 255).astype(np.uint8)).resize((size, size), Image.NEAREST))


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


def plot_learning_curves(histories: dict[str, list[dict]], path: Path, title: str) -> None:
    """Val AP50 against training images seen, one line per run (``{name: metrics['history']}``);
    a fine-tuning run continues from the images its pre-training saw when named ``A -> B``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axis = plt.subplots(figsize=(6.4, 4.2))
    for name, history in histories.items():
        points = [(h.get("images_seen", h["step"]), h["ap50"]) for h in history if h.get("ap50") is not None]
        if points:
            xs, ys = zip(*points)
            axis.plot(xs, ys, marker="o", markersize=3, label=name)
    axis.set_xlabel("training images seen")
    axis.set_ylabel("val AP50")
    axis.set_ylim(0, 1)
    finish_plot(fig, axis, path, title)


def plot_policies_side_by_side(data_dir: Path, record: dict, policies: list[str], path: Path) -> None:
    """One panel per grasp policy (Fig 5.13 style) and a legend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    fig, axes = plt.subplots(1, len(policies), figsize=(4.2 * len(policies), 4.6))
    for axis, policy in zip(np.atleast_1d(axes), policies):
        axis.imshow(labelled_scene(data_dir, record, policy))
        axis.set_title(f"policy {policy}: jaws along the robot's {policy}-axis")
        axis.axis("off")
    legend = [Patch(edgecolor=np.array(c) / 255, facecolor="none", label=k) for k, c in COLOURS.items()]
    fig.legend(handles=legend, loc="lower center", ncol=4, frameon=False)
    fig.suptitle(f"scene {record['index']}: {record['target']} (pickability by trial grasps)")
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def contact_sheet(photos: dict[str, np.ndarray], columns: int = 8) -> np.ndarray:
    """Tile photos (same size) row by row, for docs."""
    images = [image[..., :3] for image in photos.values()]
    rows = -(-len(images) // columns)
    h, w, _ = images[0].shape
    sheet = np.full((rows * h, columns * w, 3), 255, np.uint8)
    for i, image in enumerate(images):
        sheet[(i // columns) * h:(i // columns + 1) * h, (i % columns) * w:(i % columns + 1) * w] = image
    return sheet

"""APRiL figures: reconstruction grids (Figs 4.6, 4.8, 4.10) and goal heat maps (Fig 4.7)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def plot_reconstructions(images: np.ndarray, reconstructions: np.ndarray, path: Path, title: str = "") -> Path:
    """Inputs on the top row, φ_dec(φ_enc(I)) below; several views (stacked channels) side by side."""
    count = len(images)
    views = images.shape[-1] // 3 if images.shape[-1] % 3 == 0 else images.shape[-1]
    figure, axes = plt.subplots(2, count, figsize=(1.6 * count * views ** 0.5, 3.4 / views ** 0.5 + 0.4), squeeze=False)
    for column in range(count):
        for row, batch in enumerate((images, reconstructions)):
            image = np.concatenate(np.split(batch[column], views, axis=-1), axis=1)  # (H, W·views, C)
            axes[row, column].imshow(image[..., 0] if image.shape[-1] == 1 else image, cmap="gray", vmin=0, vmax=255)
            axes[row, column].axis("off")
    figure.suptitle(title, fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return Path(path)


def plot_goal_heatmap(goals: np.ndarray, lengths: np.ndarray, path: Path, title: str = "", bins: int = 6) -> Path:
    """Average actions per episode by the goal's (x, y) position (thesis Fig 4.7); empty cells blank."""
    x, y = goals[:, 0], goals[:, 1]
    edges_x = np.linspace(x.min(), x.max() + 1e-9, bins + 1)
    edges_y = np.linspace(y.min(), y.max() + 1e-9, bins + 1)
    total, _, _ = np.histogram2d(x, y, bins=[edges_x, edges_y], weights=lengths)
    count, _, _ = np.histogram2d(x, y, bins=[edges_x, edges_y])
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
    figure, axis = plt.subplots(figsize=(4.4, 3.8))
    image = axis.imshow(mean.T, origin="lower", cmap="viridis",
                        extent=(edges_x[0], edges_x[-1], edges_y[0], edges_y[-1]), aspect="auto")
    figure.colorbar(image, ax=axis, label="average actions")
    axis.set_xlabel("goal x")
    axis.set_ylabel("goal y")
    axis.set_title(title, fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return Path(path)

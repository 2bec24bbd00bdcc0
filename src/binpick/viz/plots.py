"""Learning curves (thesis Figs 3.3, 3.5 style): success rate and average actions per evaluation."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def plot_learning_curve(evaluations: list[dict[str, float]], path: Path, title: str = "",
                        threshold: float | None = None, goal_areas: list[float] | None = None) -> Path | None:
    """Two panels over simulator steps: success rate, and average actions ± std; with ``goal_areas``
    the curriculum's goal area is drawn on a second axis (thesis Fig 3.5)."""
    if not evaluations:
        return None
    steps = [e["sim_steps"] for e in evaluations]
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    top.plot(steps, [e["success_rate"] for e in evaluations], marker="o", color="tab:green")
    if threshold is not None:
        top.axhline(threshold, linestyle="--", color="grey", linewidth=1, label=f"{threshold:.0%}")
        top.legend(loc="lower right")
    top.set_ylabel("eval success rate")
    top.set_ylim(-0.02, 1.02)
    means = [e["mean_length"] for e in evaluations]
    stds = [e["std_length"] for e in evaluations]
    bottom.plot(steps, means, marker="o", color="tab:blue")
    bottom.fill_between(steps, [m - s for m, s in zip(means, stds)], [m + s for m, s in zip(means, stds)],
                        color="tab:blue", alpha=0.2)
    bottom.set_ylabel("average actions per episode")
    bottom.set_xlabel("simulator steps")
    if goal_areas is not None and any(a != goal_areas[0] for a in goal_areas):
        area_axis = bottom.twinx()
        area_axis.step(steps, goal_areas, where="post", color="tab:orange", linewidth=1.5)
        area_axis.set_ylabel("goal area (fraction of play area)", color="tab:orange")
        area_axis.set_ylim(-0.02, 1.02)
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return Path(path)

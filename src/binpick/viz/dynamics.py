"""Thesis Fig 3.9: requested moves against what the simulator and the GP do, on a grid of positions.

Top-down (x, y) arrows for actions along ±x and ±y at several scales: pink = requested move (the
action times the largest step the simulator made for a full action), blue = the actual move; one
column for the simulator, one for the GP, one row per action scale, each row magnified so that its
requested moves have the same length on the page.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


if TYPE_CHECKING:  # viz sits below rl: the type only
    from binpick.rl.dynamics import GPDynamics

DIRECTIONS = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]], float)


def probe_simulator(env, positions: np.ndarray, scale: float, settle_steps: int = 15) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each position and direction: drive the gripper there, apply one action, record Δz."""
    starts, actions, moves = [], [], []
    unwrapped = env.unwrapped
    for position in positions:
        for direction in DIRECTIONS:
            observation, _ = env.reset(seed=0)
            unwrapped.goal = np.full(3, 50.0)  # unreachable: no early termination while probing
            for _ in range(settle_steps):
                grip = observation["achieved_goal"]
                observation, *_ = unwrapped.step(np.append(np.clip(10 * (position - grip), -1, 1), 0.0))
            action = np.zeros(unwrapped.action_space.shape, np.float32)
            action[:2] = scale * direction
            start = observation["achieved_goal"].copy()
            observation, *_ = unwrapped.step(action)
            starts.append(start)
            actions.append(action)
            moves.append(observation["achieved_goal"] - start)
    return np.array(starts), np.array(actions), np.array(moves)


def plot_dynamics_comparison(env, gp: GPDynamics, path: Path, scales=(1.0, 0.4, 0.1), grid: int = 4) -> Path:
    """Draw the figure; returns its path. Positions span the FetchReach goal range around the start."""
    observation, _ = env.reset(seed=0)
    centre = observation["achieved_goal"].copy()
    offsets = np.linspace(-0.12, 0.12, grid)
    positions = np.array([centre + [dx, dy, 0.0] for dx in offsets for dy in offsets])
    figure, axes = plt.subplots(len(scales), 2, figsize=(9, 4.2 * len(scales)), squeeze=False)
    full_step = None
    for row, scale in enumerate(scales):
        starts, actions, moves = probe_simulator(env, positions, scale)
        if full_step is None:
            full_step = np.abs(moves[:, :2]).max() / scale  # how far a full action moves here
        predicted, _ = gp.predict(starts, actions)
        # magnify each row so a requested move spans 40% of the grid spacing: small actions stay visible
        spacing = offsets[1] - offsets[0]
        magnify = 0.4 * spacing / (full_step * scale)
        for column, (title, actual) in enumerate((("simulator", moves * magnify), ("GP", predicted * magnify))):
            axis = axes[row, column]
            requested = actions[:, :2] * full_step * magnify
            axis.quiver(starts[:, 0], starts[:, 1], requested[:, 0], requested[:, 1], color="hotpink",
                        angles="xy", scale_units="xy", scale=1, width=0.006, label="requested")
            axis.quiver(starts[:, 0], starts[:, 1], actual[:, 0], actual[:, 1], color="tab:blue",
                        angles="xy", scale_units="xy", scale=1, width=0.004, label="actual")
            axis.set_title(f"{title}, action scale {scale} (arrows x{magnify:.1f})")
            axis.set_aspect("equal")
            axis.set_xlabel("x (m)")
            axis.set_ylabel("y (m)")
    axes[0, 0].legend(loc="upper left", fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return Path(path)

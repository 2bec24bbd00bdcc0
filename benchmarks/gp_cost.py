"""GP imagination cost against simulator cost per transition, in one process (thesis §3.3.1).

    python benchmarks/gp_cost.py

Fits the GP on 15 random FetchReach episodes (as the thesis does), then times
- the simulator: FetchReach steps without rendering, and with an 84x84 camera image;
- the GP: batched imagined episodes with the current SAC policy (actor forward pass included).
Thesis: 0.0025 s per GP step vs 0.01 s per rendered simulator step. Target: batched GP
imagination >= 20x cheaper per transition than a MuJoCo step. Also draws docs/img/gp_dynamics.png
(the Fig 3.9 diagnostic). Writes results/gp_cost.json and a section of docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "experiments"))  # _common: results and docs

import _common  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

import binpick  # noqa: E402
from binpick.rl.gp_her.agents import GoalSAC  # noqa: E402
from binpick.rl.gp_her.dynamics import GPDynamics  # noqa: E402
from binpick.rl.gp_her.imagination import imagine_episodes  # noqa: E402
from binpick.rl.common.replay import EpisodeReplayBuffer  # noqa: E402
from binpick.rl.common.wrappers import SemanticState  # noqa: E402

DIRECTIONS = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]], float)  # the requested moves of Fig 3.9


def random_transitions(env, episodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    env.action_space.seed(0)
    states, actions, nexts, goals = [], [], [], []
    for episode in range(episodes):
        observation, _ = env.reset(seed=episode)
        goals.append(observation["desired_goal"])
        done = False
        while not done:
            action = env.action_space.sample()
            following, _, terminated, truncated, _ = env.step(action)
            states.append(observation["achieved_goal"])
            actions.append(action)
            nexts.append(following["achieved_goal"])
            observation, done = following, terminated or truncated
    return np.array(states), np.array(actions), np.array(nexts), np.array(goals)


def time_simulator(env, steps: int) -> float:
    env.reset(seed=0)
    env.action_space.seed(1)
    for _ in range(20):
        env.step(env.action_space.sample())
    started = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    return (time.perf_counter() - started) / steps


def section(result: dict) -> str:
    """The GP-cost section of docs/RESULTS.md, from results/gp_cost.json."""
    sim, sim_rendered = result["sim_s_per_transition"], result["sim_rendered_84px_s_per_transition"]
    ratio, ratio_rendered = result["gp_cheaper_than_sim"], result["gp_cheaper_than_rendered_sim"]
    return "\n".join([
        "## GP imagination cost (thesis §3.3.1)",
        "",
        "Seconds per transition, measured in one process by `python benchmarks/gp_cost.py` → "
        "`results/gp_cost.json`. GP: 15 random FetchReach episodes, imagined episodes rolled "
        f"{result['imagined_batch_episodes']} at a time with the SAC actor, closed-form predictive mean and variance.",
        "",
        "| | ours | thesis |",
        "|---|---:|---:|",
        f"| MuJoCo FetchReach step, no rendering | {sim * 1e6:.0f} µs | — |",
        f"| MuJoCo FetchReach step + 84×84 image | {sim_rendered * 1e6:.0f} µs | 10,000 µs (rendered) |",
        f"| GP imagined step (batched) | {result['gp_s_per_transition'] * 1e6:.1f} µs | 2,500 µs |",
        f"| GP cheaper than the simulator | **{ratio:.0f}×** (target ≥ 20×: {'met' if ratio >= 20 else 'not met'}); "
        f"{ratio_rendered:.0f}× vs rendered | 4× vs rendered |",
        "",
        "![GP dynamics](img/gp_dynamics.png)",
        "",
        "Fig 3.9 analogue (`docs/img/gp_dynamics.png`): pink = requested move, blue = actual move, "
        "simulator left, GP right, one row per action scale.",
    ])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=1000, help="imagined episodes rolled together")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(os.cpu_count() or 1)

    env = SemanticState(binpick.make("binpick/FetchReach-v0"))
    states, actions, nexts, goals = random_transitions(env, 15)
    gp = GPDynamics(seed=0)
    fit = gp.fit(states, actions, nexts)
    print(f"GP fitted on {fit.points} transitions of 15 random episodes in {fit.seconds:.1f} s")

    sim = time_simulator(env, 3000)
    image_env = SemanticState(binpick.make("binpick/FetchReach-v0", image="rgb", image_size=84))
    sim_rendered = time_simulator(image_env, 500)
    image_env.close()

    model = GoalSAC("MultiInputPolicy", env, seed=0, device="cpu", policy_kwargs={"net_arch": [64, 64]},
                    replay_buffer_class=EpisodeReplayBuffer,
                    replay_buffer_kwargs={"compute_reward": env.unwrapped.compute_reward, "max_episode_steps": 50})
    rng = np.random.default_rng(0)
    timings = []
    for _ in range(args.repeats):
        starts = states[rng.integers(0, len(states), args.batch)]
        batch_goals = goals[rng.integers(0, len(goals), args.batch)]
        started = time.perf_counter()
        episodes = imagine_episodes(gp, model.batch_policy, starts, batch_goals, env.unwrapped.compute_reward, 50, rng)
        elapsed = time.perf_counter() - started
        timings.append(elapsed / sum(e.length for e in episodes))
    gp_cost = float(np.median(timings))
    ratio, ratio_rendered = sim / gp_cost, sim_rendered / gp_cost
    print(f"simulator {sim * 1e6:.0f} µs/transition, with 84px image {sim_rendered * 1e6:.0f} µs; "
          f"GP {gp_cost * 1e6:.1f} µs/transition -> {ratio:.1f}x cheaper ({ratio_rendered:.0f}x vs rendered)")

    figure = plot_dynamics_comparison(binpick.make("binpick/FetchReach-v0"), gp,
                                      _common.ROOT / "docs" / "img" / "gp_dynamics.png")
    payload = {"sim_s_per_transition": sim, "sim_rendered_84px_s_per_transition": sim_rendered,
               "gp_s_per_transition": gp_cost, "gp_cheaper_than_sim": ratio, "gp_cheaper_than_rendered_sim": ratio_rendered,
               "target_ratio": 20, "met": ratio >= 20, "imagined_batch_episodes": args.batch,
               "gp_fit_seconds": fit.seconds, "gp_points": fit.points, "torch_threads": torch.get_num_threads(),
               "thesis_sim_s_per_rendered_transition": 0.01, "thesis_gp_s_per_transition": 0.0025,
               "peak_rss_mib": round(_common.peak_rss_mib(), 1)}
    path = _common.write_result("gp_cost", payload)
    print(f"wrote {path} and {figure}")
    _common.write_section_of("gp_cost", section, "gp_cost.json")


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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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


if __name__ == "__main__":
    main()

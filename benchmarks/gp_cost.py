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

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "experiments"))  # _common: results and docs

import _common  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

import binpick  # noqa: E402
from binpick.rl.agents import GoalSAC  # noqa: E402
from binpick.rl.dynamics import GPDynamics  # noqa: E402
from binpick.rl.imagination import imagine_episodes  # noqa: E402
from binpick.rl.replay import EpisodeReplayBuffer  # noqa: E402
from binpick.rl.wrappers import SemanticState  # noqa: E402
from binpick.viz.dynamics import plot_dynamics_comparison  # noqa: E402


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


if __name__ == "__main__":
    main()

"""Why greedy DQN cycles on Arm2D (Table 3.1): the same SB3 DQN on the arm's semantic state.

    python benchmarks/dqn_diagnosis.py [--steps 200000] [--only baseline gamma_095 ...]

The pixel DQN of Table 3.1 took 965 actions greedily (worse than random). To tell perception from
value learning, each row here trains SB3's DQN with Table 3.1's budget and settings on the arm's
state (cos/sin of the joints and the end point; the goal is fixed) instead of the picture — about 3
minutes a row on one core — and changes one thing. If greedy actions cycle without any pixels too,
the cause is the Q-learning, not the CNN; and which change stops the cycles says which part.
Writes results/dqn_diagnosis.json and its section of docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.dirname(__file__))

import _common  # noqa: E402

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from stable_baselines3 import DQN  # noqa: E402

from binpick.envs import make  # noqa: E402
from binpick.rl.evaluate import evaluate_policy  # noqa: E402

# Table 3.1's DQN settings (configs/rl_arm2d_dqn.yaml before the diagnosis), then one change per row
BASELINE = dict(buffer_size=50_000, target_update_interval=1000, learning_rate=1e-4, learning_starts=10_000,
                exploration_fraction=0.2, exploration_final_eps=0.05, gamma=0.99, train_freq=4)
ROWS = {
    "baseline": ("Table 3.1's settings (γ 0.99, lr 1e-4, C 1,000, a gradient step every 4 actions)", {}),
    "gamma_095": ("discount γ 0.95", {"gamma": 0.95}),
    "lr_5e-4": ("learning rate 5e-4", {"learning_rate": 5e-4}),
    "train_freq_1": ("a gradient step every action (4x the updates)", {"train_freq": 1}),
    "target_250": ("target network refreshed every 250 steps", {"target_update_interval": 250}),
    "gamma_095_lr_5e-4": ("γ 0.95 and lr 5e-4 (configs/rl_arm2d_dqn.yaml now)", {"gamma": 0.95, "learning_rate": 5e-4}),
}
EPISODES = 100


class StateObservation(gym.ObservationWrapper):
    """Arm2D's semantic state (cos, sin of the three joints; end point) as a flat Box."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.observation_space = gym.spaces.Box(-2.0, 2.0, (8,), np.float32)

    def observation(self, observation: dict) -> np.ndarray:
        return observation["observation"].astype(np.float32)


def state_env() -> gym.Env:
    return StateObservation(make("binpick/Arm2D-v0", goal_conditioned=True, image=None))


def run_row(changes: dict, steps: int) -> dict:
    model = DQN("MlpPolicy", state_env(), seed=0, device="cpu", **{**BASELINE, **changes})
    started = time.perf_counter()
    model.learn(steps)
    wall = time.perf_counter() - started
    env = state_env()
    row = {"sim_steps": steps, "wall_seconds": round(wall, 1), "settings": {**BASELINE, **changes}}
    for name, epsilon in (("greedy", 0.0), ("epsilon_greedy", 0.05)):
        result = evaluate_policy(model, env, episodes=EPISODES, seed=50_000, epsilon=epsilon)
        row[name] = {"mean": result.mean_length, "std": result.std_length, "success_rate": result.success_rate}
    env.close()
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200_000, help="training steps per row (Table 3.1's run: 200,000)")
    parser.add_argument("--only", nargs="+", choices=list(ROWS), default=list(ROWS))
    args = parser.parse_args()
    torch.set_num_threads(1)
    path = _common.RESULTS / "dqn_diagnosis.json"
    previous = json.loads(path.read_text()) if path.exists() else {}
    rows = previous.get("rows", {})
    for key in args.only:
        rows[key] = {"change": ROWS[key][0], **run_row(ROWS[key][1], args.steps)}
        print(key, rows[key]["greedy"], rows[key]["epsilon_greedy"], flush=True)
    _common.write_result("dqn_diagnosis", {"observation": "semantic state", "episodes": EPISODES, "rows": rows,
                                           "peak_rss_mib": round(_common.peak_rss_mib(), 1)})
    lines = ["## Why greedy DQN cycled on Arm2D", "",
             "SB3 DQN on Arm2D's semantic state instead of the picture, fixed goal, one change per row; "
             f"average actions ± std over {EPISODES} seeded episodes (T = 1000). "
             "`python benchmarks/dqn_diagnosis.py` → `results/dqn_diagnosis.json`.", "",
             "| change | steps | greedy | ε-greedy (0.05) |", "|---|---:|---:|---:|"]
    for key in ROWS:
        if key in rows:
            row = rows[key]
            cells = [f"{row[k]['mean']:.1f} ± {row[k]['std']:.1f} ({row[k]['success_rate']:.0%} reach)" for k in ("greedy", "epsilon_greedy")]
            lines.append(f"| {row['change']} | {row['sim_steps']:,} | {cells[0]} | {cells[1]} |")
    _common.write_section("dqn_diagnosis", "\n".join(lines))


if __name__ == "__main__":
    main()

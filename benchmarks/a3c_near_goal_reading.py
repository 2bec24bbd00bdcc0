"""How well does an A3C pixel network read Arm2D's tip and goal, by how close the tip is to the goal?

    python benchmarks/a3c_near_goal_reading.py KEY=RUN_DIR [KEY=RUN_DIR ...] [--pictures 4000]

A pixel learner with an auxiliary state head (``a3c.state_weight``) acts on features that read the arm's
state; whether it can tell when the arm is nearly there depends on how well it reads the tip and the goal
*when they are close*, where every successful episode ends and where, in the picture, the last link lies
over the goal's disc. On ``--pictures`` rendered random poses, half of them with the goal moved next to the
tip (offsets of 1.5 success radii a coordinate), this reports the median error of the end point, the goal
and the tip-to-goal vector the run's latest checkpoint reads, by true tip-goal distance, and how often
it reads "within the success radius" there. Writes results/a3c_near_goal_reading.json and its section of
docs/RESULTS.md. About a minute a run on one core.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.dirname(__file__))

import _common  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from binpick.config import load_run_config  # noqa: E402
from binpick.rl.a3c_train import load_a3c_policy, read_a3c_checkpoint  # noqa: E402
from binpick.rl.config import RLConfig  # noqa: E402
from binpick.runs import latest_checkpoint  # noqa: E402

BINS = [(0.0, 0.07), (0.07, 0.15), (0.15, 0.3), (0.3, 0.6), (0.6, 9.0)]


def pictures(config: RLConfig, count: int, seed: int = 90_000) -> tuple[torch.Tensor, np.ndarray]:
    from binpick.rl.a3c_train import make_env

    env = make_env(config)
    arm, rng = env.unwrapped, np.random.default_rng(seed)
    arm.set_goal_area(1.0)
    images, states = [], []
    for index in range(count):
        image, info = env.reset(seed=seed + index)
        if index % 2 == 0:
            image, info = arm.place_goal(arm.end_point + rng.normal(0.0, 1.5 * arm.tolerance, 2))
        images.append(image)
        states.append(info["state_continuous"])
    env.close()
    return torch.from_numpy(np.stack(images)), np.stack(states)


def measure(run: Path, count: int) -> dict:
    checkpoint = latest_checkpoint(run / "checkpoints")
    if checkpoint is None:
        sys.exit(f"{run}: no checkpoint")
    config = load_run_config(RLConfig, run)
    if config.a3c.state_key != "state_continuous" or not config.a3c.state_weight:
        sys.exit(f"{run}: needs the auxiliary head on info['state_continuous'] (a3c.state_key, a3c.state_weight)")
    model = load_a3c_policy(checkpoint).model
    images, truth = pictures(config, count)
    with torch.no_grad():
        read = torch.cat([model.state(model.features(batch)) for batch in images.split(500)]).numpy()
    tolerance = 0.07
    distance = np.linalg.norm(truth[:, 6:8] - truth[:, 8:10], axis=1)
    end_error = np.linalg.norm(read[:, 6:8] - truth[:, 6:8], axis=1)
    goal_error = np.linalg.norm(read[:, 8:10] - truth[:, 8:10], axis=1)
    vector_error = np.linalg.norm((read[:, 6:8] - read[:, 8:10]) - (truth[:, 6:8] - truth[:, 8:10]), axis=1)
    says_there = np.linalg.norm(read[:, 6:8] - read[:, 8:10], axis=1) <= tolerance
    bins = []
    for low, high in BINS:
        chosen = (distance >= low) & (distance < high)
        bins.append({"from": low, "to": high, "pictures": int(chosen.sum()),
                     "end_point_median": float(np.median(end_error[chosen])),
                     "goal_median": float(np.median(goal_error[chosen])),
                     "tip_to_goal_median": float(np.median(vector_error[chosen])),
                     "tip_to_goal_p90": float(np.percentile(vector_error[chosen], 90)),
                     "reads_within_radius": float(says_there[chosen].mean())})
    _, meta = read_a3c_checkpoint(checkpoint)
    return {"run_dir": str(run.relative_to(_common.ROOT)) if run.is_relative_to(_common.ROOT) else str(run),
            "checkpoint": checkpoint.name, "pictures": count, "bins": bins,
            "pretrain_near_goal": config.a3c.pretrain_near_goal, "observation_shape": meta["observation_shape"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="KEY=RUN_DIR (an A3C run with the auxiliary state head)")
    parser.add_argument("--pictures", type=int, default=4000)
    args = parser.parse_args()
    measured = {key: measure(run, args.pictures) for key, run in _common.keyed_run_dirs(args.runs)}
    _common.write_result("a3c_near_goal_reading", {"runs": measured, "peak_rss_mib": round(_common.peak_rss_mib(), 1)})
    rows = ["| run | tip-goal distance | pictures | end point | goal | tip-to-goal (p90) | reads 'there' |",
            "|---|---|---:|---:|---:|---:|---:|"]
    for key, result in measured.items():
        for b in result["bins"]:
            rows.append(f"| {key} | {b['from']:.2f}-{b['to']:.2f} | {b['pictures']} | {b['end_point_median']:.3f} | "
                        f"{b['goal_median']:.3f} | {b['tip_to_goal_median']:.3f} ({b['tip_to_goal_p90']:.3f}) | "
                        f"{b['reads_within_radius']:.0%} |")
    _common.write_section("a3c_near_goal_reading", "\n".join([
        "## Where A3C's pixel network reads Arm2D's tip and goal badly",
        "",
        "`python benchmarks/a3c_near_goal_reading.py KEY=RUN ...`: median error (play-area units; success radius "
        f"0.07) of the state each run's latest checkpoint reads off {args.pictures:,} rendered pictures, half of them "
        "with the goal next to the tip, by the true tip-goal distance; 'reads there' is how often the read tip-goal "
        "distance is within the radius. Runs: " + "; ".join(f"{k}: `{r['run_dir']}` ({r['checkpoint']})"
                                                        for k, r in measured.items()) + ".",
        "",
        *rows,
    ]))
    for key, result in measured.items():
        print(key, [(b["from"], round(b["goal_median"], 3), round(b["tip_to_goal_median"], 3), round(b["reads_within_radius"], 2))
                    for b in result["bins"]])


if __name__ == "__main__":
    main()

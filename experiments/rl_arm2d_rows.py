"""Evaluate A3C run folders made outside experiments/rl_arm2d.py (for example a benchmark run continued
further) on the same 200 seeded whole-area episodes, greedy and sampling, and merge them into
results/rl_arm2d.json under the keys given.

    python experiments/rl_arm2d_rows.py KEY=RUN_DIR [KEY=RUN_DIR ...] [--note TEXT]

The 2M-step state rows came from the two 1M state runs (entropy 0.01) copied to runs/explore,
``total_timesteps: 2000000`` set in each copy's config.yaml and ``binpick rl train --resume COPY``.
"""

from __future__ import annotations

import argparse


import rl_arm2d  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rows", nargs="+", help="KEY=RUN_DIR")
    parser.add_argument("--note", default="", help="how the run was made, stored with its rows")
    args = parser.parse_args()
    rows = {}
    for key, run, policy, config, metrics in rl_arm2d.keyed_runs(args.rows):
        extra = {"sim_steps": metrics["sim_steps"], "wall_seconds": metrics["wall_seconds"], "run_dir": run,
                 **({"note": args.note} if args.note else {}),
                 **({"pretrain": metrics["pretrain"]} if "pretrain" in metrics else {}),
                 "trained_goal_area": metrics["final_goal_area"]}  # where a curriculum had got to
        rows[key] = rl_arm2d.evaluate(policy, 1.0, config=config) | extra
        rows[f"{key}_sampled"] = rl_arm2d.evaluate(policy, 1.0, deterministic=False, config=config) | extra
        print(key, f"greedy {rows[key]['mean']:.1f}, sampling {rows[f'{key}_sampled']['mean']:.1f}", flush=True)
    rl_arm2d.merge_rows(rows)


if __name__ == "__main__":
    main()

"""Thesis Tables 3.3 and 3.4 on FetchReach with binpick's GP imagination and episode HER.

    python experiments/rl_fetchreach_gp_tables.py --table 3.3
    python experiments/rl_fetchreach_gp_tables.py --table 3.4 [--alphas 1 10 50] [--capacities 10000 1000000]

Table 3.3: a single goal, with a fixed start and with a noisy start (±10 cm): simulator episodes,
GP episodes and the final average actions (thesis: 2.00 with 4 sim / 1,500 GP episodes; 6.69 with 79
sim / 400,000 GP episodes). Table 3.4: random goals, α_HER x M: episodes in Ω when training starts
(10% full) and training iterations (gradient steps) until average actions < 5 (thesis best: α=1,
M=10^4, 12,700 iterations). Runs start from configs/rl/rl_fetchreach_gp_her.yaml. Writes
results/rl_fetchreach_gp_tables.json and sections of docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import _common  # noqa: E402

from binpick.rl.config import RLConfig  # noqa: E402
from binpick.core.config import load_config  # noqa: E402
from binpick.rl.train import Trainer  # noqa: E402
from binpick.cli.terminal import RichCallback  # noqa: E402

BASE = "configs/rl/rl_fetchreach_gp_her.yaml"
GOAL = (0.1, 0.05, 0.05)  # the single goal of Table 3.3, metres from the gripper's start


def run(name: str, steps: int, seed: int, **changes) -> dict:
    # the tables need the whole run (e.g. iterations to < 5 actions): no early stop
    overrides = {"name": name, "total_timesteps": steps, "seed": seed, "eval.stop_after_successes": 0}
    config = load_config(RLConfig, _common.ROOT / BASE, overrides | {key.replace("__", "."): value for key, value in changes.items()})
    trainer = Trainer.new(config, _common.ROOT / "runs" / "bench")
    with RichCallback() as callback:
        metrics = trainer.run(callback)
    metrics["run_dir"] = str(trainer.run_dir.relative_to(_common.ROOT))
    reached = [e for e in metrics.pop("evaluations") if e["success_rate"] >= config.eval.success_threshold]
    metrics["at_threshold"] = reached[0] if reached else None  # what it took to first reach 95% success
    return metrics


THESIS_3_3 = {"fixed_start": "2.00 (4 sim + 15 for the GP, 1,500 GP)", "noisy_start": "6.69 (79 sim, 400,000 GP)"}
THESIS_3_4 = {(1, 10_000): (550, 12_700), (10, 10_000): (100, 22_700), (50, 10_000): (300, 114_100),
              (1, 1_000_000): (50_150, 13_100), (10, 1_000_000): (9_450, 21_900), (50, 1_000_000): (21_600, 66_200)}
DEFAULT_SEED = 0


def section_table_3_3(result: dict) -> str:
    """Table 3.3's section of docs/RESULTS.md, from results/rl_fetchreach_gp_tables.json (the simulator steps:
    the runs'; the seed: the rows', the default where a file written before rows kept it lacks it)."""
    rows = result["table_3_3"]
    steps = " / ".join(sorted({f"{row['sim_steps']}" for row in rows.values()}))
    seeds = " / ".join(sorted({f"{row.get('seed', DEFAULT_SEED)}" for row in rows.values()}))
    lines = ["## Table 3.3: FetchReach, single goal, GP imagination", "",
             "`python experiments/rl_fetchreach_gp_tables.py --table 3.3` → `results/rl_fetchreach_gp_tables.json`. "
             f"Goal fixed at {GOAL} m from the gripper's start; noisy start = ±10 cm per axis; "
             f"{steps} simulator steps, seed {seeds}.", "",
             "Episode counts are those at the first evaluation with ≥ 95% success (the 15 random warm-up "
             "episodes that fit the GP included); the final figure is after the whole run.", "",
             "| set-up | simulator episodes | GP episodes | final avg actions (ours) | thesis |", "|---|---:|---:|---:|---:|"]
    for label, row in rows.items():
        sim = "not reached" if row["sim_episodes_to_95"] is None else f"{row['sim_episodes_to_95']:,}"
        gp = "—" if row["gp_episodes_to_95"] is None else f"{row['gp_episodes_to_95']:,}"
        lines.append(f"| {label.replace('_', ' ')} | {sim} | {gp} | "
                     f"{row['final_avg_actions']:.2f} ± {row['final_std_actions']:.2f} | {THESIS_3_3[label]} |")
    return "\n".join(lines)


def section_table_3_4(result: dict) -> str:
    """Table 3.4's section of docs/RESULTS.md, from results/rl_fetchreach_gp_tables.json (the simulator steps:
    the runs')."""
    rows = result["table_3_4"]
    steps = " / ".join(sorted({f"{row['sim_steps']}" for row in rows.values()}))
    lines = ["## Table 3.4: FetchReach, random goals, α_HER × M", "",
             "`python experiments/rl_fetchreach_gp_tables.py --table 3.4` → `results/rl_fetchreach_gp_tables.json`. "
             "Episodes sampled (simulator + GP) until Ω is 10% full and training starts; in brackets all "
             "episodes in Ω then, HER copies included. Iterations = gradient steps until the evaluated average is "
             f"below 5 actions ('—' = not within {steps} simulator steps). One seed per cell.", "",
             "| α_HER | M | episodes until training: ours (all in Ω) / thesis | iterations to < 5 actions: ours / thesis | final avg actions |",
             "|---:|---:|---:|---:|---:|"]
    for row in rows.values():
        t = THESIS_3_4.get((row["alpha_her"], row["M"]), ("—", "—"))
        origin = row["episodes_until_training_by_origin"]
        sampled = origin.get("real", 0) + origin.get("imagined", 0)
        its = "—" if row["iterations_to_5_actions"] is None else f"{row['iterations_to_5_actions']:,}"
        lines.append(f"| {row['alpha_her']} | {row['M']:,} | {sampled:,} ({row['episodes_until_training']:,}) / {t[0]:,} | "
                     f"{its} / {t[1]:,} | {row['final_avg_actions']:.2f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--table", choices=["3.3", "3.4"], required=True)
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    parser.add_argument("--steps", type=int, default=6000, help="simulator steps per run")
    parser.add_argument("--alphas", type=int, nargs="+", default=[1, 10, 50])
    parser.add_argument("--capacities", type=int, nargs="+", default=[10_000, 1_000_000])
    parser.add_argument("--report-only", action="store_true", help="rewrite the docs table from the JSON, run nothing")
    args = parser.parse_args()
    path = _common.RESULTS / "rl_fetchreach_gp_tables.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    if args.report_only:
        if args.table == "3.4" and "table_3_4" in results:
            _common.write_section_of("table_3_4", section_table_3_4, "rl_fetchreach_gp_tables.json")
        return
    if args.table == "3.3":
        rows = {}
        for label, noise in (("fixed_start", 0.0), ("noisy_start", 0.1)):
            # as in the thesis, learn mostly inside the GP: many gradient steps and imagined episodes
            # for each simulator step
            m = run(f"table33_{label}", args.steps, args.seed, env_kwargs={"goal_offset": list(GOAL), "start_noise": noise},
                    sac__gradient_steps=20, gp__imagined_per_real=50.0, eval__every=250)
            first = m["at_threshold"] or {}
            rows[label] = {"seed": args.seed, "sim_episodes_to_95": first.get("sim_episodes"), "gp_episodes_to_95": first.get("imagined_episodes"),
                           "sim_steps_to_95": first.get("sim_steps"), "avg_actions_at_95": first.get("mean_length"),
                           **{k: m[k] for k in ("sim_episodes", "imagined_episodes", "her_episodes", "sim_steps",
                                                "final_avg_actions", "final_std_actions", "final_success", "run_dir")}}
            print(label, rows[label], flush=True)
        results["table_3_3"] = rows
        _common.write_result("rl_fetchreach_gp_tables", results)
        _common.write_section_of("table_3_3", section_table_3_3, "rl_fetchreach_gp_tables.json")
    else:
        rows = results.get("table_3_4", {})
        for alpha in args.alphas:
            for capacity in args.capacities:
                m = run(f"table34_a{alpha}_m{capacity}", args.steps, args.seed,
                        replay__her_additions=alpha, replay__capacity_episodes=capacity)
                started = m["episodes_when_training_started"] or {}
                rows[f"alpha{alpha}_M{capacity}"] = {
                    "alpha_her": alpha, "M": capacity, "episodes_until_training": sum(started.values()),
                    "episodes_until_training_by_origin": started,
                    "iterations_to_5_actions": m["gradient_steps_to_5_actions"], "final_avg_actions": m["final_avg_actions"],
                    "sim_steps": m["sim_steps"], "run_dir": m["run_dir"]}
                print(alpha, capacity, rows[f"alpha{alpha}_M{capacity}"], flush=True)
                results["table_3_4"] = rows
                _common.write_result("rl_fetchreach_gp_tables", results)  # after every run: a long grid keeps what it has
                _common.write_section_of("table_3_4", section_table_3_4, "rl_fetchreach_gp_tables.json")
    results["peak_rss_mib"] = round(_common.peak_rss_mib(), 1)
    _common.write_result("rl_fetchreach_gp_tables", results)


if __name__ == "__main__":
    main()

"""Thesis Tables 3.1 and 3.2 on Arm2D from images: random / DQN / A3C with a fixed goal, and
A3C with and without the goal-area curriculum on the same budget.

    python experiments/rl_arm2d.py [--only random shortest_path a3c dqn curriculum no_curriculum] [--steps-scale 1.0]

Each learner trains from its config in configs/ (run folders in runs/bench/) and is then evaluated
on 200 seeded episodes; the curriculum runs are evaluated on the whole play area. A killed run continues
where its last checkpoint left it when the benchmark is run again with the same settings (--fresh: new
runs). The A3C rows of the two tables (AS_IT_ACTS) are the policy sampled, as A3C acts, with its argmax
under "greedy"; Table 3.2's stages are the curriculum run's last 200 training episodes at each goal area,
as the thesis measured them. Thesis: 369±341 / 134±99 / 15±3 (Table 3.1); 15 / 42 / 13 / 25±6 at single
goal / ¼ / ½ / whole (Table 3.2). Targets: DQN <= 150; curriculum <= 25 at the whole area. Long: 2M
steps a curriculum run (~75 min on 2 cores); results are merged into results/rl_arm2d.json so parts can
be run separately. The way there is kept as further --only names (RUNS below).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

import _common  # noqa: E402

from binpick.envs import make  # noqa: E402
from binpick.rl.config import RLConfig  # noqa: E402
from binpick.core.config import load_config  # noqa: E402
from binpick.rl.common.evaluate import evaluate_policy, random_policy  # noqa: E402
from binpick.rl.policy import load_policy  # noqa: E402
from binpick.rl.envs import make_env as make_run_env  # noqa: E402
from binpick.rl.train import trainer_for  # noqa: E402
from binpick.core.config import load_run_config  # noqa: E402
from binpick.cli.terminal import RichCallback  # noqa: E402

RUNS = {
    "a3c": ("configs/rl/rl_arm2d_a3c.yaml", 0.0),
    "dqn": ("configs/rl/rl_arm2d_dqn.yaml", 0.0),
    # Table 3.2's pair: end to end from 32 px, pretrained perception, a semantic bottleneck with the state learner's
    # two layers on it (depth, not the reading, was found to be what kept pixel learners behind)
    "curriculum_whole_area": ("configs/rl/rl_arm2d_curriculum_keypoints_bottleneck_deep.yaml", 1.0),
    "no_curriculum_whole_area": ("configs/rl/rl_arm2d_no_curriculum_keypoints_bottleneck_deep.yaml", 1.0),
    # the way there, each row kept with the key it was measured under. First the thesis-style network
    # with a flattened trunk, whose curriculum starts from the single-goal "a3c" run (init_from)
    "curriculum_flat_whole_area": ("configs/rl/rl_arm2d_curriculum.yaml", 1.0),
    "no_curriculum_flat_whole_area": ("configs/rl/rl_arm2d_no_curriculum.yaml", 1.0),
    # the same with a3c.encoder: keypoints, each training its own single-goal start
    "curriculum_keypoints_whole_area": ("configs/rl/rl_arm2d_curriculum_keypoints.yaml", 1.0),
    "no_curriculum_keypoints_whole_area": ("configs/rl/rl_arm2d_no_curriculum_keypoints.yaml", 1.0),
    # ... plus the auxiliary state loss (a3c.state_weight)
    "curriculum_keypoints_state_whole_area": ("configs/rl/rl_arm2d_curriculum_keypoints_state.yaml", 1.0),
    "no_curriculum_keypoints_state_whole_area": ("configs/rl/rl_arm2d_no_curriculum_keypoints_state.yaml", 1.0),
    # the same learner on the arm's semantic state instead of pixels (a3c.encoder: state): perception taken away
    "curriculum_state_whole_area": ("configs/rl/rl_arm2d_curriculum_state.yaml", 1.0),
    "no_curriculum_state_whole_area": ("configs/rl/rl_arm2d_no_curriculum_state.yaml", 1.0),
    # entropy bonus 0.01 instead of 0.001 (the state runs showed the policy stopped exploring)
    "curriculum_state_entropy_whole_area": ("configs/rl/rl_arm2d_curriculum_state_entropy.yaml", 1.0),
    "no_curriculum_state_entropy_whole_area": ("configs/rl/rl_arm2d_no_curriculum_state_entropy.yaml", 1.0),
    "curriculum_keypoints_state_entropy_whole_area": ("configs/rl/rl_arm2d_curriculum_keypoints_state_entropy.yaml", 1.0),
    "no_curriculum_keypoints_state_entropy_whole_area": ("configs/rl/rl_arm2d_no_curriculum_keypoints_state_entropy.yaml", 1.0),
    # the auxiliary head regresses angles as cos/sin (no jump at ±π), weight 1, 32 px pictures, 2M steps
    "curriculum_keypoints_continuous_whole_area": ("configs/rl/rl_arm2d_curriculum_keypoints_continuous.yaml", 1.0),
    "no_curriculum_keypoints_continuous_whole_area": ("configs/rl/rl_arm2d_no_curriculum_keypoints_continuous.yaml", 1.0),
    # ... whose network first learns to read the state off rendered pictures (a3c.pretrain_*), then RL from pixels
    "curriculum_keypoints_pretrained_whole_area": ("configs/rl/rl_arm2d_curriculum_keypoints_pretrained.yaml", 1.0),
    "no_curriculum_keypoints_pretrained_whole_area": ("configs/rl/rl_arm2d_no_curriculum_keypoints_pretrained.yaml", 1.0),
    # ... whose policy reads an MLP on the state its auxiliary head reads (a3c.policy_input: state_estimate)
    "curriculum_keypoints_bottleneck_whole_area": ("configs/rl/rl_arm2d_curriculum_keypoints_bottleneck.yaml", 1.0),
    "no_curriculum_keypoints_bottleneck_whole_area": ("configs/rl/rl_arm2d_no_curriculum_keypoints_bottleneck.yaml", 1.0),
    # ... with the state learner's depth on the state estimate (a3c.hidden_layers: 2): Table 3.2's pair above
    # the state learner acting on pixels through the frozen APRiL keypoint network (READ_STATE below)
    "curriculum_read_state_whole_area": ("configs/rl/rl_arm2d_curriculum_read_state.yaml", 1.0),
    "no_curriculum_read_state_whole_area": ("configs/rl/rl_arm2d_no_curriculum_read_state.yaml", 1.0),
}
KEYPOINTS = _common.ROOT / "runs" / "bench" / "arm2d_keypoints" / "keypoints.safetensors"  # rl_arm2d_april.py makes it
READ_STATE = ("curriculum_read_state_whole_area", "no_curriculum_read_state_whole_area")
ALIASES = {"curriculum": "curriculum_whole_area", "no_curriculum": "no_curriculum_whole_area",
           "curriculum_keypoints_bottleneck_deep": "curriculum_whole_area",
           "no_curriculum_keypoints_bottleneck_deep": "no_curriculum_whole_area",
           "curriculum_keypoints": "curriculum_keypoints_whole_area",
           "no_curriculum_keypoints": "no_curriculum_keypoints_whole_area",
           "curriculum_keypoints_state": "curriculum_keypoints_state_whole_area",
           "no_curriculum_keypoints_state": "no_curriculum_keypoints_state_whole_area",
           "curriculum_state": "curriculum_state_whole_area", "no_curriculum_state": "no_curriculum_state_whole_area",
           **{name: f"{name}_whole_area" for name in ("curriculum_state_entropy", "no_curriculum_state_entropy",
                                                      "curriculum_keypoints_state_entropy",
                                                      "no_curriculum_keypoints_state_entropy",
                                                      "curriculum_keypoints_continuous",
                                                      "no_curriculum_keypoints_continuous",
                                                      "curriculum_keypoints_pretrained",
                                                      "no_curriculum_keypoints_pretrained",
                                                      "curriculum_keypoints_bottleneck",
                                                      "no_curriculum_keypoints_bottleneck",
                                                      "curriculum_flat", "no_curriculum_flat",
                                                      "curriculum_read_state", "no_curriculum_read_state")}}
# Tables 3.1 and 3.2's A3C rows: the policy as A3C acts, sampling its actions -- the thesis's figures are its
# training episodes (Figs 3.3b and 3.5: moving averages over 100 of them) -- with the argmax under "greedy". The
# rows of the way there keep the layout they were measured in: KEY greedy, KEY_sampled sampling.
AS_IT_ACTS = ("a3c", "curriculum_whole_area", "no_curriculum_whole_area")
EPISODES = 200


def evaluate(policy, goal_area: float, seed: int = 50_000, epsilon: float = 0.0, deterministic: bool = True,
             config: RLConfig | None = None, wrap_env=None) -> dict:
    """200 seeded episodes at ``goal_area``; an A3C run's config gives its own env (pixels or state)."""
    if config is not None and config.algorithm == "a3c":
        env = make_run_env(config, wrap_env)
        env.unwrapped.set_goal_area(goal_area)
    else:
        env = make("binpick/Arm2D-v0", goal_area=goal_area)
    result = evaluate_policy(policy, env, episodes=EPISODES, seed=seed, epsilon=epsilon, deterministic=deterministic)
    env.close()
    return {"mean": result.mean_length, "std": result.std_length, "success_rate": result.success_rate,
            "episodes": EPISODES, "goal_area": goal_area, "epsilon": epsilon, "deterministic": deterministic}


def merge_rows(rows: dict) -> dict:
    """Merge measured rows into results/rl_arm2d.json as the file is now, after each row: a later crash
    loses nothing measured, and two arms run at once (one process each) do not overwrite each other's rows.
    Returns the merged results."""
    path = _common.RESULTS / "rl_arm2d.json"
    results = (json.loads(path.read_text()) if path.exists() else {}) | rows
    results["peak_rss_mib"] = round(max(_common.peak_rss_mib(), results.get("peak_rss_mib", 0.0)), 1)
    _common.write_result("rl_arm2d", {k: v for k, v in results.items() if k not in ("benchmark", "machine")})
    return results


def keyed_runs(items: list[str]) -> list[tuple]:
    """``KEY=RUN_DIR`` arguments -> (key, run, policy, config, its metrics.json); a bad one is one line."""
    runs = []
    for key, folder in _common.keyed_run_dirs(items):
        policy, config = load_policy(folder)
        run = str(folder.relative_to(_common.ROOT)) if folder.is_relative_to(_common.ROOT) else str(folder)
        runs.append((key, run, policy, config, json.loads((folder / "metrics.json").read_text())))
    return runs


def shortest_path(goal_area: float, seed: int = 50_000) -> dict:
    """Fewest actions from each evaluation episode's start to the goal: every pose the six actions can
    reach is the start's joint angles plus multiples of π/8 (16³ poses), so the shortest path is the
    cheapest pose within the success radius, each joint's cost the shorter way round. What "good" means."""
    env = make("binpick/Arm2D-v0", goal_area=goal_area, image="grey", image_size=16)
    arm, turns = env.unwrapped, np.arange(16)
    grid = np.stack(np.meshgrid(turns, turns, turns, indexing="ij"), -1).reshape(-1, 3)
    cost = np.minimum(grid, 16 - grid).sum(1)
    lengths = []
    for episode in range(EPISODES):
        env.reset(seed=seed + episode)
        poses = arm.angles + grid * (np.pi / 8)
        cumulative = np.cumsum(poses, axis=1)
        ends = np.stack([(arm.link_lengths * np.cos(cumulative)).sum(1), (arm.link_lengths * np.sin(cumulative)).sum(1)], 1)
        reachable = np.linalg.norm(ends - arm.goal, axis=1) <= arm.tolerance
        lengths.append(int(cost[reachable].min()) if reachable.any() else 1000)
    env.close()
    return {"mean": float(np.mean(lengths)), "std": float(np.std(lengths)), "success_rate": float(np.mean(np.array(lengths) < 1000)),
            "episodes": EPISODES, "goal_area": goal_area}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", default=["random", "shortest_path", "a3c", "dqn", "curriculum", "no_curriculum"])
    parser.add_argument("--steps-scale", type=float, default=1.0, help="scale every config's total_timesteps")
    parser.add_argument("--report-only", action="store_true", help="rewrite the docs table from the JSON, run nothing")
    parser.add_argument("--fresh", action="store_true", help="start new run folders rather than continue the latest with the same config")
    parser.add_argument("--address", default=None, help="A3C's rollout workers as Ray actors on this cluster (local: one on "
                                                        "this machine); rows are stored as KEY_ray, runs in runs/bench_ray")
    args = parser.parse_args()
    bench = _common.ROOT / "runs" / ("bench" if args.address is None else "bench_ray")
    path = _common.RESULTS / "rl_arm2d.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    measured: dict = {}
    for item in [] if args.report_only else args.only:
        key = ALIASES.get(item, item)
        if key == "shortest_path":
            results["shortest_path"] = shortest_path(0.0)
            results["shortest_path_whole_area"] = shortest_path(1.0)
        elif key == "random":
            env = make("binpick/Arm2D-v0")
            results["random"] = evaluate(random_policy(env, 0), 0.0)
            results["random_whole_area"] = evaluate(random_policy(env, 0), 1.0)  # Table 3.2's reference
            env.close()
        else:
            config_path, area = RUNS[key]
            base = load_config(RLConfig, _common.ROOT / config_path)
            overrides = {"total_timesteps": int(base.total_timesteps * args.steps_scale),
                         "curriculum.stages": [{**asdict(stage), "ramp_steps": int(stage.ramp_steps * args.steps_scale),
                                                "hold_steps": int(stage.hold_steps * args.steps_scale)}
                                               for stage in base.curriculum.stages]}
            if key == "curriculum_flat_whole_area":  # thesis §3.2: start from the single-goal A3C network
                single_goal = _common.ROOT / results.get("a3c", {}).get("run_dir", "missing")
                if not (single_goal / "config.yaml").is_file():
                    sys.exit("the curriculum starts from the single-goal A3C run: run --only a3c first")
                overrides["init_from"] = str(single_goal)
            config = load_config(RLConfig, _common.ROOT / config_path, overrides)
            wrap_env = None
            if key in READ_STATE:
                from binpick.april.arm2d import ReadStateOffPixels

                if not KEYPOINTS.is_file():
                    sys.exit(f"{key} reads the state with {KEYPOINTS}: make it with experiments/rl_arm2d_april.py first")
                wrap_env = ReadStateOffPixels(str(KEYPOINTS))
            if args.address is not None and config.algorithm != "a3c":
                sys.exit(f"--address runs A3C's workers on Ray; {key} is {config.algorithm}")
            trainer = (continued(config, args.fresh, wrap_env, bench)
                       or trainer_for(config, bench, wrap_env=wrap_env))
            with RichCallback() as callback:
                if args.address is None:
                    metrics = trainer.run(callback)
                else:
                    from binpick.integrations.ray.a3c import learn_on_ray

                    metrics = trainer.run(callback, learn=learn_on_ray(args.address))
            policy, _ = load_policy(trainer.run_dir)
            made = {"sim_steps": metrics["sim_steps"], "wall_seconds": metrics["wall_seconds"],
                    "run_dir": str(trainer.run_dir.relative_to(_common.ROOT)),
                    **({"pretrain": metrics["pretrain"]} if "pretrain" in metrics else {})}
            greedy = evaluate(policy, area, config=config, wrap_env=wrap_env) | made
            if config.algorithm == "a3c":  # an actor-critic acts by sampling its policy (Mnih et al. 2016)
                sampled = evaluate(policy, area, deterministic=False, config=config, wrap_env=wrap_env) | made
                if key in AS_IT_ACTS:
                    results[key] = sampled | {"greedy": {k: greedy[k] for k in ("mean", "std", "success_rate")}}
                else:
                    results[key], results[f"{key}_sampled"] = greedy, sampled
            else:
                results[key] = greedy
            if key.startswith("curriculum"):
                results[key.replace("whole_area", "stages")] = [e for e in metrics["evaluations"]]
                results[key] |= {"advance": config.curriculum.advance, "advanced_at": metrics.get("curriculum_advanced_at", [])}
                if key in AS_IT_ACTS:
                    results[key.replace("whole_area", "training_stages")] = training_stages(trainer.run_dir, config.curriculum.window)
            if key == "dqn":  # Mnih et al. (2015) evaluate with ε = 0.05; greedy above
                results["dqn_epsilon_greedy"] = evaluate(policy, area, epsilon=0.05) | {
                    k: results[key][k] for k in ("sim_steps", "wall_seconds", "run_dir")}
        print(key, results[key], flush=True)
        mine = {k: v for k, v in results.items()
                if k == key or k.startswith((f"{key}_", *(key.replace("whole_area", end) for end in ("stages", "training_stages"))))}
        if args.address is not None:  # beside the local rows, not over them
            mine = {f"{k}_ray": v for k, v in mine.items() if not k.endswith("_ray")}
            results = json.loads(path.read_text()) if path.exists() else {}
        measured |= mine
        results = merge_rows(measured)

    plot_training(results)
    _common.write_section_of("rl_arm2d", section, "rl_arm2d.json")


def drawn(results: dict) -> bool:
    """Whether the figure of Table 3.2's pair has been drawn: both rows measured (it is kept when their runs are gone)."""
    return all(key in results for key in ("curriculum_whole_area", "no_curriculum_whole_area"))


def section(results: dict) -> str:
    """The Arm2D section of docs/RESULTS.md (Tables 3.1 and 3.2 and the way there), from results/rl_arm2d.json."""

    def cell(key: str) -> str:
        row = results.get(key)
        if row is None:
            return "not measured (stopped part-way, or not run)"
        budget = f", after {row['sim_steps']:,} steps" if "sim_steps" in row else ""
        return f"{row['mean']:.1f} ± {row['std']:.1f} ({row['success_rate']:.0%} reach{budget})"

    def argmax(key: str) -> str:
        greedy = results.get(key, {}).get("greedy")
        return f"{greedy['mean']:.1f} ± {greedy['std']:.1f} ({greedy['success_rate']:.0%} reach), greedy" if greedy else ""

    return "\n".join([
        "## Arm2D from images: Tables 3.1 and 3.2",
        "",
        f"Average actions per episode ± std over {EPISODES} seeded episodes (T = 1000) after training; "
        "`python experiments/rl_arm2d.py` → `results/rl_arm2d.json` (keys in brackets). The A3C rows act as A3C acts, "
        "sampling its policy: the thesis's figures are its training episodes (Figs 3.3b and 3.5, moving averages over "
        "100), and A3C trains and acts by sampling. Their argmax is beside them: it can cycle between two poses on some "
        "starts, as greedy DQN did before its fix.",
        "",
        "| method | goal | ours | the other way to act | thesis |",
        "|---|---|---:|---:|---:|",
        f"| random (`random`) | fixed | {cell('random')} | | 369 ± 341 |",
        f"| DQN (SB3), greedy (`dqn`) | fixed | {cell('dqn')} | {cell('dqn_epsilon_greedy')}, ε = 0.05 | 134 ± 99 |",
        f"| A3C, 2 workers, 64 px, flattened trunk (`a3c`) | fixed | {cell('a3c')} | {argmax('a3c')} | 15 ± 3 |",
        f"| random (`random_whole_area`) | whole area | {cell('random_whole_area')} | | – |",
        f"| A3C + curriculum ({curriculum_rule(results)}), end to end from 32 px (`curriculum_whole_area`) | "
        f"whole area | {cell('curriculum_whole_area')} | {argmax('curriculum_whole_area')} | 25 ± 6 |",
        f"| the same network, same budget, no curriculum (`no_curriculum_whole_area`) | whole area | "
        f"{cell('no_curriculum_whole_area')} | {argmax('no_curriculum_whole_area')} | did not converge |",
        f"| shortest path on the arm's action lattice (exhaustive search, not a learner) | fixed | {cell('shortest_path')} | | |",
        f"| the same | whole area | {cell('shortest_path_whole_area')} | | |",
        "",
        *headline_paragraph(results),
        f"![Table 3.2's pair as it trains](img/{FIGURE.name})" if drawn(results) else "",
        "",
        "Table 3.2 by stage, as the thesis measured it (Fig 3.5: training episodes, moving average over 100): the "
        "curriculum run's last 200 training episodes at each goal area, the window its re-convergence rule watches "
        "(`curriculum_training_stages`); steps count from its start, single-goal stage included.",
        "",
        "| goal area | ours | at step | thesis |",
        "|---|---:|---:|---:|",
        *stage_rows(results.get("curriculum_training_stages", [])),
        "",
        "At a quarter and half of the area ours stay above the thesis's 42 and 13: the rule widens once a stage has "
        "been held its minimum (50k steps) and the last 200 episodes' mean is within 10% of the 200 before, that is "
        "once it stops falling, not once it is low; the thesis let the half-area stage converge before widening. Not "
        "tuned: the whole-area figure is Table 3.2's result.",
        "",
        "Its periodic evaluations, greedy (20 episodes; the last at each goal area; `curriculum_stages`):",
        "",
        "| goal area | ours | after steps | thesis |",
        "|---|---:|---:|---:|",
        *stage_rows(results.get("curriculum_stages", [])),
        "",
        "### The way there",
        "",
        "Every run measured on the way to the rows above, each under the key it was measured with: here `KEY` is the "
        "greedy evaluation and `KEY_sampled` the sampled one. The first pair is the thesis-style network (a flattened "
        "trunk on 64 px pictures) whose curriculum starts from the single-goal `a3c` run (`init_from`), 1M steps.",
        "",
        "| method | goal | ours | thesis |",
        "|---|---|---:|---:|",
        f"| A3C, flattened trunk, + curriculum ({curriculum_rule(results, 'curriculum_flat_whole_area')}), greedy | whole area | "
        f"{cell('curriculum_flat_whole_area')} | 25 ± 6 |",
        f"| the same, sampling its policy | whole area | {cell('curriculum_flat_whole_area_sampled')} | |",
        f"| the same, no curriculum, greedy | whole area | {cell('no_curriculum_flat_whole_area')} | did not converge |",
        f"| the same, no curriculum, sampling its policy | whole area | {cell('no_curriculum_flat_whole_area_sampled')} | |",
        f"| A3C, keypoints trunk, + curriculum ({curriculum_rule(results, 'curriculum_keypoints_whole_area')}), greedy "
        f"| whole area | {cell('curriculum_keypoints_whole_area')} | 25 ± 6 |",
        f"| A3C, keypoints trunk, + curriculum, sampling its policy | whole area | {cell('curriculum_keypoints_whole_area_sampled')} | |",
        f"| A3C, keypoints trunk, same budget, no curriculum, greedy | whole area | {cell('no_curriculum_keypoints_whole_area')} | |",
        f"| A3C, keypoints trunk, same budget, no curriculum, sampling | whole area | "
        f"{cell('no_curriculum_keypoints_whole_area_sampled')} | |",
        f"| A3C, keypoints + state loss, + curriculum, greedy | whole area | {cell('curriculum_keypoints_state_whole_area')} | 25 ± 6 |",
        f"| A3C, keypoints + state loss, + curriculum, sampling | whole area | "
        f"{cell('curriculum_keypoints_state_whole_area_sampled')} | |",
        f"| A3C, keypoints + state loss, no curriculum, greedy | whole area | {cell('no_curriculum_keypoints_state_whole_area')} | |",
        f"| A3C, keypoints + state loss, no curriculum, sampling | whole area | "
        f"{cell('no_curriculum_keypoints_state_whole_area_sampled')} | |",
        f"| A3C on the arm's state (no pixels), + curriculum, greedy | whole area | {cell('curriculum_state_whole_area')} | |",
        f"| A3C on the arm's state (no pixels), + curriculum, sampling | whole area | "
        f"{cell('curriculum_state_whole_area_sampled')} | |",
        f"| A3C on the arm's state (no pixels), no curriculum, greedy | whole area | {cell('no_curriculum_state_whole_area')} | |",
        f"| A3C on the arm's state (no pixels), no curriculum, sampling | whole area | "
        f"{cell('no_curriculum_state_whole_area_sampled')} | |",
        f"| A3C on the arm's state, entropy bonus 0.01, + curriculum, greedy | whole area | "
        f"{cell('curriculum_state_entropy_whole_area')} | |",
        f"| A3C on the arm's state, entropy bonus 0.01, + curriculum, sampling | whole area | "
        f"{cell('curriculum_state_entropy_whole_area_sampled')} | |",
        f"| A3C on the arm's state, entropy bonus 0.01, no curriculum, greedy | whole area | "
        f"{cell('no_curriculum_state_entropy_whole_area')} | |",
        f"| A3C on the arm's state, entropy bonus 0.01, no curriculum, sampling | whole area | "
        f"{cell('no_curriculum_state_entropy_whole_area_sampled')} | |",
        f"| the same state learner continued to 2M steps, + curriculum, sampling | whole area | "
        f"{cell('curriculum_state_entropy_2m_sampled')} | |",
        f"| the same state learner continued to 2M steps, no curriculum, sampling | whole area | "
        f"{cell('no_curriculum_state_entropy_2m_sampled')} | |",
        f"| that 2M state policy on pixels (APRiL: its state read off the image by learnt keypoints), + curriculum, "
        f"sampling | whole area | {cell('curriculum_state_entropy_2m_pixels_sampled')} | 25 ± 6 |",
        f"| that 2M state policy on pixels, + curriculum, greedy | whole area | {cell('curriculum_state_entropy_2m_pixels')} | |",
        f"| that 2M state policy on pixels, no curriculum, sampling | whole area | "
        f"{cell('no_curriculum_state_entropy_2m_pixels_sampled')} | |",
        f"| that 2M state policy on pixels, no curriculum, greedy | whole area | {cell('no_curriculum_state_entropy_2m_pixels')} | |",
        f"| A3C, keypoints + state loss, entropy bonus 0.01, + curriculum, greedy | whole area | "
        f"{cell('curriculum_keypoints_state_entropy_whole_area')} | 25 ± 6 |",
        f"| A3C, keypoints + state loss, entropy bonus 0.01, + curriculum, sampling | whole area | "
        f"{cell('curriculum_keypoints_state_entropy_whole_area_sampled')} | |",
        f"| A3C, keypoints + state loss, entropy bonus 0.01, no curriculum, greedy | whole area | "
        f"{cell('no_curriculum_keypoints_state_entropy_whole_area')} | |",
        f"| A3C, keypoints + state loss, entropy bonus 0.01, no curriculum, sampling | whole area | "
        f"{cell('no_curriculum_keypoints_state_entropy_whole_area_sampled')} | |",
        f"| A3C from 32 px, state loss on cos/sin, network first taught to read the state (pretrained), + curriculum, "
        f"sampling | whole area | {cell('curriculum_keypoints_pretrained_whole_area_sampled')} | 25 ± 6 |",
        f"| the same, + curriculum, greedy | whole area | {cell('curriculum_keypoints_pretrained_whole_area')} | |",
        f"| the same, no curriculum, sampling | whole area | {cell('no_curriculum_keypoints_pretrained_whole_area_sampled')} | |",
        f"| the same, no curriculum, greedy | whole area | {cell('no_curriculum_keypoints_pretrained_whole_area')} | |",
        f"| the same, + curriculum, its 1,050,015-step checkpoint, sampling | whole area | "
        f"{cell('curriculum_keypoints_pretrained_1m_sampled')} | |",
        f"| the same, + curriculum, its 1,050,015-step checkpoint, greedy | whole area | "
        f"{cell('curriculum_keypoints_pretrained_1m')} | |",
        f"| A3C on pixels through the frozen APRiL keypoint network (the state learner acting on read states), + curriculum, "
        f"sampling | whole area | {cell('curriculum_read_state_whole_area_sampled')} | 25 ± 6 |",
        f"| the same, + curriculum, greedy | whole area | {cell('curriculum_read_state_whole_area')} | |",
        f"| the same, no curriculum, sampling | whole area | {cell('no_curriculum_read_state_whole_area_sampled')} | |",
        f"| the same, no curriculum, greedy | whole area | {cell('no_curriculum_read_state_whole_area')} | |",
        "",
        "The flattened pair: with goals anywhere, 1M steps are far from the thesis's budget (\"hundreds of thousands of episodes\", §3.3): the curriculum's own training episodes were still "
        "long when the area reached the whole play area.",
        "",
        "The flattened pair uses entropy_beta 0.001, the single-goal run A3C's usual 0.01. binpick scales "
        "rewards by 0.01 (returns in [-1, 0]); that scales the advantages but not the entropy bonus, and at 0.01 the "
        "policy stayed near uniform (entropy 1.5-1.75 of at most ln 6 = 1.79 through the whole curriculum run). At 0.001 "
        "its entropy fell to 0.6-1.1 and the sampled policy at the whole area went from 342 to 250 actions (the earlier "
        "run, 2026-11-30, against this one); greedy stayed at ~930. The greedy rows at the whole area say little: on 300 "
        "start states the no-curriculum run's argmax (and the earlier curriculum run's) was the same action on every "
        "one, a joint spinning in place, which is why those two rows read exactly alike; this curriculum run's took two "
        "actions. At 1M steps, with or without the curriculum, training episodes were still ~250 actions long.",
        "",
        "Why (section 'Why the curriculum stalls' below): the flattened trunk gives every place in the picture "
        "its own weights and cannot locate a goal where it has not seen one, so every widening meets goals it cannot "
        "read; and at the single goal, where 400k of the curriculum's steps go, the reward never asks where the goal is. "
        "The keypoints rows change the first (`a3c.encoder: keypoints`); the state-loss rows also the second "
        "(`a3c.state_weight: 0.1`, untuned: the features regress the arm's semantic state beside the A3C losses). The "
        "keypoints pair was stopped part-way (curriculum at 650,011 steps, control at 450,009, of 1M) to give the two "
        "cores to the state-loss curriculum run; both resume with `python experiments/rl_arm2d.py --only "
        "curriculum_keypoints no_curriculum_keypoints`. The state-loss control was stopped at 100,018 steps "
        "(resumes with `--only no_curriculum_keypoints_state`) to give the cores to the runs below.",
        "",
        "How much of the gap is perception? The state rows run the same learner, schedule and budget on the arm's "
        "semantic state (`a3c.encoder: state`: cos/sin of the joints, end point and goal through the same 256-unit "
        "layer; no pixels). With the entropy bonus at 0.001 it learnt the single goal in 100k steps (greedy 10-11 actions, "
        "against ~400k from pixels) but then did what the pixel runs did: training episodes ~210-305 actions at a quarter "
        "of the area and 131.5 sampling at the whole area after 1M. So the learner, not only the picture, stalls. Its "
        "entropy says why: it fell to 0.39 (of ln 6 = 1.79) at the single goal and further, to 0.24-0.28, while the area "
        "widened, where the thesis saw it rise: a near-deterministic single-goal policy that stops exploring when new "
        "goals come. With the bonus at 0.01 the entropy stayed 1.3-1.7, training episodes at a quarter of the area were "
        "~110 actions, and the state learner reached 46.3 sampling at the whole area (100% reach) after the same 1M "
        "steps, its training episodes still falling (74 → 61 → 51 over the last 150k). A learning rate of 1e-3 instead "
        "(bonus 0.001) diverged once the area widened (value loss 0.02 → 0.37, entropy → 0.02, episodes ~610 actions at "
        "0.8 of the area; stopped at ~850k, not a row). Greedy rows stay poor at either bonus: the argmax of a policy "
        "this close to uniform is not the policy, and it cycles. The shortest path on the arm's action lattice is "
        "6.1 actions to the fixed goal and 6.8 anywhere, so the thesis's 15 and 25 are 2.5x and 3.7x it. "
        "Without the curriculum the same state learner (bonus 0.01, goals anywhere from the first step) did better on "
        "the same 1M: 29.7 ± 20.9 sampling (100% reach; training episodes 29 at the end), against the curriculum's "
        "46.3. On the state, at this budget, the thesis's direction does not appear: its schedule spends 400k steps on "
        "one goal, whose policy the wider areas must then unlearn, while goals anywhere from the start are reachable "
        "for an exploring policy (random reach at the whole area above) and teach the goal's reading from the first "
        "step. Continued to 2M steps (`experiments/rl_arm2d_rows.py`: each 1M run copied, its total_timesteps raised, "
        "resumed), both state learners pass the thesis's figure sampling their policy: curriculum 20.5 ± 13.4, no "
        "curriculum 19.5 ± 15.2 (100% reach; greedy 221.8 and 172.5). So A3C with the entropy bonus at 0.01 does "
        "reach Table 3.2's 25 in 2M steps when it sees the state, and the curriculum is not what gets it there.",
        "",
        "From pixels the entropy fix does not carry over at 1M (keypoints + state loss, bonus 0.01: 318.9 sampling, "
        "866.3 greedy, against 311.8 / 921.3 at 0.001). The pixel learner is the slow part: at 0.01 its single-goal "
        "training episodes were still 60 actions after 300k steps (the state learner: 15 after 100k), its entropy stayed "
        "1.6-1.7, and every widening found training episodes of ~300. Its features locate the goal (probe above: 0.056) "
        "but the end point only to 0.116, wider than the 0.07 success radius, and the policy must move that end point "
        "onto the goal. What would close it: train the policy on the state, where it reaches 20 in 2M steps, and deploy "
        "it on pixels through a perception that regresses the state precisely enough (APRiL, ch. 4; end point and goal "
        "within ~0.03), or several million pixel steps (~1 h per 1M on this machine).",
        "",
        *april_paragraph(results),
        *pretrained_paragraph(results),
        "The flattened curriculum run by stage (last periodic evaluation at each goal area, 20 episodes, greedy); it "
        "starts from the single-goal `a3c` run (`init_from`), so steps count from there.",
        "",
        "| goal area | ours | after steps | thesis |",
        "|---|---:|---:|---:|",
        *stage_rows(results.get("curriculum_flat_stages", [])),
        "",
        "The same for the keypoints run (`a3c.encoder: keypoints`), which trains its own single-goal start:",
        "",
        "| goal area | ours | after steps | thesis |",
        "|---|---:|---:|---:|",
        *stage_rows(results.get("curriculum_keypoints_stages", [])),
        "",
        "And for the keypoints run with the auxiliary state loss:",
        "",
        "| goal area | ours | after steps | thesis |",
        "|---|---:|---:|---:|",
        *stage_rows(results.get("curriculum_keypoints_state_stages", [])),
        "",
        "And for the same learner and schedule on the arm's semantic state instead of pixels (`a3c.encoder: state`):",
        "",
        "| goal area | ours | after steps | thesis |",
        "|---|---:|---:|---:|",
        *stage_rows(results.get("curriculum_state_stages", [])),
        "",
        "The same on the state with the entropy bonus at 0.01:",
        "",
        "| goal area | ours | after steps | thesis |",
        "|---|---:|---:|---:|",
        *stage_rows(results.get("curriculum_state_entropy_stages", [])),
        "",
        "And from pixels (keypoints + state loss) with the entropy bonus at 0.01:",
        "",
        "| goal area | ours | after steps | thesis |",
        "|---|---:|---:|---:|",
        *stage_rows(results.get("curriculum_keypoints_state_entropy_stages", [])),
        "",
        "And from 32 px pictures with the perception pretrained to read the state (cos/sin), the same schedule "
        "(filled in when the run reaches its 2M steps):",
        "",
        "| goal area | ours | after steps | thesis |",
        "|---|---:|---:|---:|",
        *stage_rows(results.get("curriculum_keypoints_pretrained_stages", [])),
    ])


def continued(config: RLConfig, fresh: bool, wrap_env=None, bench: Path = _common.ROOT / "runs" / "bench"):
    """The trainer of the latest run of this very config (it resumes from its last checkpoint), or None."""
    latest = None if fresh else _common.latest_run(bench, config.name)
    if latest is None or load_run_config(RLConfig, latest) != config:
        return None
    print(f"{config.name}: continuing {latest.relative_to(_common.ROOT)}", flush=True)
    return trainer_for(resume=latest, wrap_env=wrap_env)


def april_paragraph(results: dict) -> list[str]:
    """What the pixel-deployed state rows (experiments/rl_arm2d_april.py) say, from their numbers."""
    row = results.get("curriculum_state_entropy_2m_pixels_sampled")
    control = results.get("no_curriculum_state_entropy_2m_pixels_sampled")
    if not row or not control:
        return []
    seen = row["perception"]
    state, state_control = results["curriculum_state_entropy_2m_sampled"], results["no_curriculum_state_entropy_2m_sampled"]
    greedy, greedy_control = results["curriculum_state_entropy_2m"], results["no_curriculum_state_entropy_2m"]
    return [
        "From pixels the APRiL way (thesis ch. 4 on this task; `python experiments/rl_arm2d_april.py "
        "curriculum_state_entropy_2m=RUN no_curriculum_state_entropy_2m=RUN`): the 2M-step state policies above act on "
        "the state read off the 64 px image alone, by a network that finds the two elbows, the end point and the goal "
        f"(spatial soft-argmax; {seen['train_images']:,} rendered random poses, {seen['epochs']} epochs, "
        f"{seen['seconds'] / 60:.0f} min on 2 busy cores; joint angles from the elbows). On 2,000 held-out images its "
        f"end point is off by {seen['end_point_median']:.3f} (median; 95th percentile {seen['end_point_p95']:.3f}) and "
        f"the goal by {seen['goal_median']:.3f} ({seen['goal_p95']:.3f}), against the 0.07 success radius. On the same "
        f"200 seeded whole-area episodes: curriculum {row['mean']:.1f} ± {row['std']:.1f} sampling "
        f"({row['success_rate']:.0%} reach), no curriculum {control['mean']:.1f} ± {control['std']:.1f} "
        f"({control['success_rate']:.0%}); on the true state they took {state['mean']:.1f} and {state_control['mean']:.1f} "
        f"(greedy on pixels {results['curriculum_state_entropy_2m_pixels']['mean']:.1f} and "
        f"{results['no_curriculum_state_entropy_2m_pixels']['mean']:.1f}, on the state {greedy['mean']:.1f} and "
        f"{greedy_control['mean']:.1f}: the argmax cycles on some starts either way). So the thesis's 25 ± 6 is "
        f"{'reached' if row['mean'] <= 25 else 'not reached'} from pixels when the policy learns on the state and "
        "perception is learnt apart, as chapter 4 proposes; end to end from pixels (rows above) it is not, at this "
        "budget. The curriculum's advantage over no curriculum does not appear either way.",
        "",
    ]


def pretrained_paragraph(results: dict) -> list[str]:
    """What the end-to-end pixel rows with a pretrained perception say, from their numbers."""
    row, greedy = results.get("curriculum_keypoints_pretrained_1m_sampled"), results.get("curriculum_keypoints_pretrained_1m")
    if not row or not greedy:
        return []
    state = results["curriculum_state_entropy_whole_area_sampled"]
    pixels = results["curriculum_keypoints_state_entropy_whole_area_sampled"]
    flattened = results["curriculum_flat_whole_area_sampled"]
    pretrain = row.get("pretrain", {})
    return [
        "End to end from pixels again (2026-12-02). Two causes kept the pixel learner behind the state learner, step "
        "for step. First, the auxiliary head regressed `info[\"state\"]`, whose joint angles jump at ±π and hold most of "
        "its variance: trained on that target alone at A3C's learning rate, the keypoints network read the end point "
        "0.34 off after 6,000 updates, against 0.14 (32 px) and 0.10 (64 px) with the angles as cos/sin "
        "(`info[\"state_continuous\"]`, `a3c.state_key`; section 'What A3C's auxiliary head should regress' below). "
        "Second, the perception was learnt while acting, at 1e-4: with the cos/sin target at weight 1 on 32 px "
        "(`rl_arm2d_*_keypoints_continuous.yaml`) the auxiliary loss was still 0.07-0.10 a component after 300k steps "
        "(its TensorBoard log; those two runs were stopped there for the next two) and the single-goal training "
        "episodes ~70 actions. The pretrained curriculum run (`rl_arm2d_curriculum_keypoints_pretrained.yaml`) first "
        f"fits the network to the state on {pretrain.get('pictures', 0):,} rendered random poses with goals anywhere "
        f"({pretrain.get('epochs', 0)} epochs at 1e-3: {pretrain.get('untrained_error', float('nan')):.3f} → "
        f"{pretrain.get('held_out_error', float('nan')):.3f} RMS a component on held-out pictures, "
        f"{pretrain.get('wall_seconds', 0) / 60:.0f} min), then learns from the pictures alone, the auxiliary loss "
        "still on (0.002-0.005 a component throughout). Its checkpoint at "
        f"{row['sim_steps']:,} steps (widened on re-convergence at 400,013, 584,445 and 782,426 steps, the whole area "
        f"from 882,226 on) takes {row['mean']:.1f} ± "
        f"{row['std']:.1f} actions sampling on the 200 whole-area episodes ({row['success_rate']:.0%} reach), greedy "
        f"{greedy['mean']:.1f}; after the same 1M steps the state learner took {state['mean']:.1f} sampling, the "
        f"earlier pixel runs {pixels['mean']:.1f} (keypoints + raw state loss) and {flattened['mean']:.1f} (flattened "
        "trunk). Better than every earlier pixel run, far from the state learner. The run was stopped with its last "
        "checkpoint at 1,200,009 of its 2M steps and its no-curriculum control at 600,010, to give the cores to the "
        "measurement of where the lag starts (section 'A3C's pace on Arm2D's single goal' below); both resume with `python experiments/rl_arm2d.py "
        "--only curriculum_keypoints_pretrained` and `--only no_curriculum_keypoints_pretrained`. The thesis reports "
        "its 25 after 1,000,000 episodes (§3.3: \"for the 1,000,000 episodes it took to achieve the final result in "
        "Section 3.2\"); 1M steps here are ~10,000 episodes.",
        "",
        "Where the lag came from (2026-12-02, section 'What slows A3C from pixels on Arm2D's single goal' below): not "
        "the reading -- the state learner fed the frozen reading of A3C's own pixel network kept its pace, with the "
        "errors tied to the pose or shuffled -- but the network above it. The state learner has two 256-unit layers "
        "on the state; every pixel learner above had one above what it read, and the state learner with one learns "
        "the single goal at their pace. With two (`a3c.hidden_layers: 2`) the bottleneck learns the single goal at the "
        "state learner's pace: that is the pair at the top of this section. The read-state pair "
        "(`rl_arm2d_curriculum_read_state.yaml`: the state learner acting on 64 px pictures through the frozen APRiL "
        "keypoint network) was stopped at 94k for it (checkpoint 50,004; `--only curriculum_read_state` resumes).",
        "",
    ]


def headline_paragraph(results: dict) -> list[str]:
    """What Table 3.1's DQN and Table 3.2's pair are and what their numbers say, from the numbers."""
    row, control = results.get("curriculum_whole_area"), results.get("no_curriculum_whole_area")
    lines = [
        "DQN: γ 0.95 and learning rate 5e-4 (the thesis gives neither). With γ 0.99 and 1e-4 its Q-values were still far "
        "from converged after 200,000 steps and the greedy policy cycled between two arm poses (965 actions, 4% reach); "
        "the same happens on the arm's state without any CNN, and goes with a lower γ, a higher learning rate or more "
        "updates per step (section 'Why greedy DQN cycled on Arm2D' below).",
        "",
    ]
    if not row or "pretrain" not in row:
        return lines
    pretrain = row["pretrain"]
    lines += [
        "Table 3.2's pair (`configs/rl/rl_arm2d_curriculum_keypoints_bottleneck_deep.yaml` and "
        "`rl_arm2d_no_curriculum_keypoints_bottleneck_deep.yaml`; `python experiments/rl_arm2d.py --only curriculum "
        "no_curriculum`, each resumes) learns end to end from 32 px pictures, the thesis's network changed where the way "
        "there (below) found it failing: a keypoints trunk (each feature map's expected position, so what it learnt "
        "of a goal in one place holds everywhere) whose auxiliary head regresses the arm's state with its angles as "
        f"cos/sin (`a3c.state_weight: 1`), first fitted to that state on {pretrain['pictures']:,} rendered pictures "
        f"({pretrain['epochs']} epochs: {pretrain['untrained_error']:.3f} → {pretrain['held_out_error']:.3f} RMS a "
        f"component held out, {pretrain['wall_seconds'] / 60:.0f} min); policy and value read two 256-unit layers on "
        "that state estimate (`a3c.policy_input: state_estimate`, `a3c.hidden_layers: 2`), the state learner's depth; "
        "entropy bonus 0.01; 2M steps, where the thesis took 1,000,000 episodes (§3.3). The curriculum holds the "
        "single goal for 400k steps, then widens the area each time the last 200 training episodes have "
        f"re-converged ({curriculum_rule(results)}); the control has goals anywhere from its first step.",
        "",
    ]
    if control:
        standard_error = ((row["std"] ** 2 + control["std"] ** 2) / EPISODES) ** 0.5  # of the difference in means
        better, worse = row["mean"] < control["mean"] - 2 * standard_error, row["mean"] > control["mean"] + 2 * standard_error
        reach = results.get("random_whole_area", {}).get("success_rate", float("nan"))
        lines += [
            f"With the curriculum the sampled policy takes {row['mean']:.1f} ± {row['std']:.1f} actions at the whole "
            f"area ({row['success_rate']:.0%} reach), the thesis's 25 ± 6; without it, on the same budget, "
            f"{control['mean']:.1f} ± {control['std']:.1f} ({control['success_rate']:.0%} reach). "
            + (f"The curriculum is ahead by {control['mean'] - row['mean']:.1f} actions (standard error of the "
               f"difference {standard_error:.1f}), as in the thesis." if better else
               (f"The curriculum is behind by {row['mean'] - control['mean']:.1f} actions (standard error of the "
                f"difference {standard_error:.1f}): here it costs steps" if worse else
                f"The two are within noise of each other (difference {row['mean'] - control['mean']:+.1f}, standard "
                f"error {standard_error:.1f}): here the curriculum is not what gets the learner there")
               + ", unlike the thesis, whose control did not converge: with the entropy bonus at 0.01, goals anywhere are reachable for an "
               f"exploring policy from the start (random reaches {reach:.0%} of them) and teach the goal's reading from "
               "the first step, as the state learner showed (way there, below).")
            + f" Greedy, the argmax cycles on some starts: {row['greedy']['mean']:.1f} and {control['greedy']['mean']:.1f}. "
            "The curriculum run's first 175k steps were a single-goal run of the same config made before its budget "
            "was set (only `name` and `total_timesteps` differed), continued in its run folder.",
            "",
        ]
    return lines


def curriculum_rule(results: dict, key: str = "curriculum_whole_area") -> str:
    """How the measured curriculum run widened the area (earlier runs followed a fixed step schedule)."""
    row = results.get(key, {})
    if row.get("advance") == "converged":
        return "widened on re-convergence, at steps " + ", ".join(f"{s:,}" for s in row.get("advanced_at", []))
    return "fixed step schedule" if row else "widened on re-convergence"


def training_stages(run: Path, window: int) -> list[dict]:
    """Table 3.2 the way the thesis measured it (Fig 3.5's moving average of training episodes): at each goal area,
    the last ``window`` training episodes the run had there -- the window its re-convergence rule watches."""
    series = _common.training_scalars(run, "episode/length", "curriculum/goal_area")
    area_steps = np.array([step for step, _ in series["curriculum/goal_area"]])
    areas = np.array([area for _, area in series["curriculum/goal_area"]])
    episodes = series["episode/length"]
    at_end = areas[np.clip(np.searchsorted(area_steps, [step for step, _ in episodes], side="right") - 1, 0, None)]
    stages = []
    for area in (0.0, 0.25, 0.5, 1.0):
        lengths = [(step, length) for (step, length), seen in zip(episodes, at_end) if abs(seen - area) < 1e-6][-window:]
        if lengths:
            values = np.array([length for _, length in lengths])
            stages.append({"goal_area": area, "episodes": len(values), "sim_steps": lengths[-1][0],
                           "mean_length": float(values.mean()), "std_length": float(values.std()),
                           "success_rate": float((values < 1000).mean())})
    return stages


FIGURE = _common.ROOT / "docs" / "img" / "rl_arm2d_curriculum.png"


def plot_training(results: dict, window: int = 100) -> bool:
    """Thesis Fig 3.5 for Table 3.2's pair: training-episode length, moving average over ``window`` episodes, with
    the curriculum's goal area beside it. Drawn from the runs' TensorBoard logs; False (image kept) if they are gone."""
    runs = {key: _common.ROOT / results[key]["run_dir"] for key in ("curriculum_whole_area", "no_curriculum_whole_area")
            if key in results}
    if len(runs) < 2 or not all((run / "tb").is_dir() for run in runs.values()):
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(8, 4.2))
    area_axis = axis.twinx()
    for (key, run), colour in zip(runs.items(), ("tab:blue", "tab:green")):
        series = _common.training_scalars(run, "episode/length", optional=("curriculum/goal_area",))
        steps = np.array([step for step, _ in series["episode/length"]])
        lengths = np.array([length for _, length in series["episode/length"]])
        smooth = np.convolve(lengths, np.ones(window) / window, mode="valid")
        axis.plot(steps[window - 1:], smooth, color=colour, lw=1.2,
                  label=("with" if key.startswith("curriculum") else "without") + " the curriculum")
        if key.startswith("curriculum") and "curriculum/goal_area" in series:
            area_steps, areas = zip(*series["curriculum/goal_area"])
            area_axis.plot(area_steps, areas, color="tab:orange", lw=1, ls="--", label="goal area (curriculum)")
    axis.axhline(25, color="grey", lw=0.8, ls=":", label="thesis, whole area (25)")
    axis.set(xlabel="simulator steps", ylabel=f"training episode length (mean of {window})", yscale="log",
             title="Arm2D from 32 px pictures, A3C: Table 3.2's pair as it trains (thesis Fig 3.5)")
    area_axis.set(ylabel="goal area (fraction of the play area)", ylim=(-0.02, 1.05))
    axis.grid(alpha=0.3)
    handles = [h for ax in (axis, area_axis) for h in ax.get_legend_handles_labels()[0]]
    axis.legend(handles, [h.get_label() for h in handles], fontsize=8, loc="center right")
    figure.tight_layout()
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(FIGURE, dpi=110)
    plt.close(figure)
    return True


def stage_rows(evaluations: list[dict]) -> list[str]:
    thesis = {0.0: "15 ± 3", 0.25: "42 ± 12", 0.5: "13 ± 2", 1.0: "25 ± 6"}
    names = {0.0: "single goal", 0.25: "1/4 of the area", 0.5: "1/2", 1.0: "whole area"}
    rows = []
    for area, label in names.items():
        at_area = [e for e in evaluations if abs(e["goal_area"] - area) < 1e-3]
        if at_area:
            last = at_area[-1]
            rows.append(f"| {label} | {last['mean_length']:.1f} ± {last['std_length']:.1f} ({last['success_rate']:.0%} reach) | "
                        f"{last['sim_steps']:,} | {thesis[area]} |")
    return rows or ["| not run yet | | | |"]


if __name__ == "__main__":
    main()

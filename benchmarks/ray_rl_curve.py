"""Table 3.2's deep-bottleneck curriculum run on Ray beside the local run: the learning curves.

    python experiments/rl_arm2d.py --only curriculum --address local   # the Ray run (resumable; ~1.5 h on 2 cores)
    python benchmarks/ray_rl_curve.py                                   # this comparison (seconds)

The local run is the one results/rl_arm2d.json holds (``curriculum_stages``: its evaluations every
50,000 steps, 20 episodes each; ``curriculum_whole_area``: 200 episodes at the end). The Ray run is the
same config with its two rollout workers as Ray actors: its finished rows (``*_ray``), or, while it
is still going, the evaluations in its latest checkpoint. Writes ``rl`` of results/ray_scaling.json,
docs/img/ray_rl_curve.png and the ``ray_rl`` section of docs/RESULTS.md. Seed noise: an evaluation of
20 episodes has a binomial standard error of up to 0.11 in its success rate; two runs of one config
differ by more than that early in training (asynchronous A3C is not repeatable even on one seed).
"""

from __future__ import annotations

import json
import math
import os
import sys

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "experiments"))  # _common: results and docs

import _common  # noqa: E402

RUNS = _common.ROOT / "runs" / "bench_ray"
NAME = "arm2d_curriculum_keypoints_bottleneck_deep"
FIGURE = _common.ROOT / "docs" / "img" / "ray_rl_curve.png"


def ray_evaluations(results: dict) -> tuple[list[dict], dict | None, list[int], str]:
    """The Ray run's evaluations, its final row if it finished, the steps its curriculum widened at,
    and where they came from."""
    if "curriculum_stages_ray" in results:
        final = results.get("curriculum_whole_area_ray") or {}
        return results["curriculum_stages_ray"], final or None, final.get("advanced_at", []), "finished"
    run = _common.latest_run(RUNS, NAME)
    if run is None:
        sys.exit(f"no Ray run in {RUNS}: python experiments/rl_arm2d.py --only curriculum --address local")
    latest = (run / "checkpoints" / "latest").read_text().strip()
    state = json.loads((run / "checkpoints" / latest / "state.json").read_text())
    return (state["metrics"]["evaluations"], None, (state.get("curriculum") or {}).get("advanced_at", []), f"in progress ({state['steps']:,} steps, {run.relative_to(_common.ROOT)})")


def first_at(evaluations: list[dict], rate: float) -> int | None:
    return next((e["sim_steps"] for e in evaluations if e["success_rate"] >= rate), None)


def plot(local: list[dict], ray: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (top, bottom) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    for rows, label, style in ((local, "local (2 worker processes)", "-o"), (ray, "Ray (2 rollout actors)", "-s")):
        steps = [e["sim_steps"] / 1e6 for e in rows]
        top.plot(steps, [e["success_rate"] for e in rows], style, markersize=3, label=label)
        bottom.plot(steps, [e["mean_length"] for e in rows], style, markersize=3, label=label)
    top.set_ylabel("success (20 episodes)")
    bottom.set_ylabel("actions per episode")
    bottom.set_yscale("log")
    bottom.set_xlabel("simulator steps (millions)")
    top.legend(loc="lower right")
    top.set_title("Table 3.2's curriculum run (deep bottleneck), local vs Ray")
    figure.tight_layout()
    figure.savefig(FIGURE, dpi=110)
    plt.close(figure)


def section(result: dict) -> str:
    """The curriculum-run-on-Ray section of docs/RESULTS.md, from results/ray_scaling.json's ``rl``."""
    row = result["rl"]
    local_final, ray_final = row["local_final"], row["ray_final"]
    lines = ["## Table 3.2's curriculum run on Ray", "",
             "`python experiments/rl_arm2d.py --only curriculum --address local`, then `python benchmarks/ray_rl_curve.py`: "
             "`configs/rl/rl_arm2d_curriculum_keypoints_bottleneck_deep.yaml` unchanged (2 workers, perception pre-trained, "
             "converged-rule curriculum, 2M steps), its rollout workers as Ray actors on a private cluster (127.0.0.1), "
             f"beside the local run of results/rl_arm2d.json. Ray run: {row['source']}.", "",
             "![learning curves](img/ray_rl_curve.png)", "",
             "| | local | Ray |", "|---|---|---|",
             f"| evaluations compared (same steps, 20 episodes each) | {row['compared_evaluations']} | |",
             f"| first evaluation at ≥ 95% success | {row['local_first_95']:,} steps | "
             f"{'not yet' if row['ray_first_95'] is None else format(row['ray_first_95'], ',') + ' steps'} |",
             f"| curriculum widened at | {', '.join(f'{s:,}' for s in row['local_advanced_at'] or [])} | "
             f"{', '.join(f'{s:,}' for s in row['ray_advanced_at']) or 'not yet'} |"]
    if ray_final is not None:
        lines.append(f"| whole area, 200 episodes sampled | {local_final['mean']:.2f} ± {local_final['std']:.2f} actions, "
                     f"{local_final['success_rate']:.0%} | {ray_final['mean']:.2f} ± {ray_final['std']:.2f}, "
                     f"{ray_final['success_rate']:.0%} |")
    if row["mean_abs_success_gap"] is not None:
        lines += ["", f"Success rates at the same steps differ by {row['mean_abs_success_gap']:.3f} on average; "
                  f"{row['within_two_standard_errors']} of {row['compared_evaluations']} evaluations lie within two standard "
                  "errors of their difference (20 episodes each)."]
    return "\n".join(lines)


def main() -> None:
    results = json.loads((_common.RESULTS / "rl_arm2d.json").read_text())
    local, local_final = results["curriculum_stages"], results["curriculum_whole_area"]
    ray, ray_final, ray_advanced, source = ray_evaluations(results)
    by_step = {round(e["sim_steps"], -3): e for e in local}
    pairs = [(by_step[round(e["sim_steps"], -3)], e) for e in ray if round(e["sim_steps"], -3) in by_step]
    gaps = [abs(a["success_rate"] - b["success_rate"]) for a, b in pairs]
    noise = [math.sqrt(max(a["success_rate"] * (1 - a["success_rate"]), 1 / 20) / 20 * 2) for a, _ in pairs]
    within = sum(gap <= 2 * n for gap, n in zip(gaps, noise))
    row = {"source": source, "compared_evaluations": len(pairs),
           "mean_abs_success_gap": round(sum(gaps) / len(gaps), 3) if gaps else None,
           "within_two_standard_errors": within,
           "local_first_95": first_at(local, 0.95), "ray_first_95": first_at(ray, 0.95),
           "local_advanced_at": local_final.get("advanced_at"),
           "ray_advanced_at": ray_advanced,
           "local_final": {k: local_final[k] for k in ("mean", "std", "success_rate", "sim_steps")},
           "ray_final": None if ray_final is None else {k: ray_final[k] for k in ("mean", "std", "success_rate", "sim_steps")},
           "local_curve": [[e["sim_steps"], e["goal_area"], e["success_rate"], round(e["mean_length"], 1)] for e in local],
           "ray_curve": [[e["sim_steps"], e["goal_area"], e["success_rate"], round(e["mean_length"], 1)] for e in ray]}
    path = _common.RESULTS / "ray_scaling.json"
    scaling = json.loads(path.read_text()) if path.is_file() else {}
    for key in ("benchmark", "machine"):
        scaling.pop(key, None)
    scaling["rl"] = row
    _common.write_result("ray_scaling", scaling)
    plot(local, ray)
    _common.write_section_of("ray_rl", section, "ray_scaling.json")
    print(json.dumps({k: v for k, v in row.items() if not k.endswith("curve")}, indent=1))


if __name__ == "__main__":
    main()

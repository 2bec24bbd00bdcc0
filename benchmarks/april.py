"""Thesis Tables 4.2-4.5: APRiL rows per env - ground truth, pixels with conditioned / partly
conditioned / unconditioned latents - with the simulator episodes each row used.

    python benchmarks/april.py [--only april_fetchreach_w1.0 ...] [--report-only]

Each name is a config in configs/ (configs/<name>.yaml); its run folder goes to runs/bench/april/.
Rows are merged into results/april.json as {env: {row: {avg_actions, std, success, sim_episodes}}}
so configs can be run one at a time. Reconstruction grids and heat maps are copied to docs/img/april/.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.dirname(__file__))

import _common  # noqa: E402

from binpick.april import AprilRun, load_april_config  # noqa: E402

CONFIGS = {
    "FetchReach": ["april_fetchreach_w1.0", "april_fetchreach_w0.5", "april_fetchreach_w0.0"],
    "Reacher": ["april_reacher_n4_m4", "april_reacher_n8_unconditioned"],
}
THESIS = {  # (table, {row: thesis average actions})
    "Reacher": ("4.2", {"random": 49.46, "ground_truth": 31.02, "pixels_ae_n8_m0_w0": 44.30, "pixels_ae_n4_m4_w1": 35.02}),
    "FetchReach": ("4.3", {"ground_truth": 3.10, "pixels_ae_n6_m6_w1": 12.42, "pixels_ae_n6_m6_w0.5": 17.06,
                           "pixels_ae_n6_m0_w0": 30.94}),
}
IMAGES = _common.ROOT / "docs" / "img" / "april"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", default=[name for names in CONFIGS.values() for name in names])
    parser.add_argument("--report-only", action="store_true", help="rewrite the docs table from the JSON, run nothing")
    parser.add_argument("--runs", default="runs/bench/april",
                        help="run folders; the latest run of a config there is resumed (or reused when finished)")
    parser.add_argument("--fresh", action="store_true", help="always start new run folders")
    args = parser.parse_args()
    path = _common.RESULTS / "april.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    for name in [] if args.report_only else args.only:
        config = load_april_config(_common.ROOT / "configs" / f"{name}.yaml")
        env = config.env.split("/")[1].removesuffix("-v0")
        existing = sorted((_common.ROOT / args.runs / config.name).glob("*/stages.json"))
        if existing and not args.fresh:
            run = AprilRun.resume(existing[-1].parent)
            print(f"{name}: continuing {run.run_dir} (done: {', '.join(run.stages) or 'nothing'})", flush=True)
        else:
            run = AprilRun.new(config, _common.ROOT / args.runs)
        rows = run.run(show_progress=True)["rows"]
        for row, values in rows.items():
            kept = results.setdefault(env, {}).get(row, {})
            results[env][row] = values | {"config": f"configs/{name}.yaml",
                                          "run_dir": str(run.run_dir.relative_to(_common.ROOT))}
            if row == "ground_truth" and kept and kept.get("config") != f"configs/{name}.yaml":
                results[env][row] = kept  # the first config's ground-truth row stays; the others share its policy
        IMAGES.mkdir(parents=True, exist_ok=True)
        for picture in run.run_dir.glob("*.png"):
            shutil.copy(picture, IMAGES / f"{name}_{picture.name}")
        print(name, json.dumps(rows), flush=True)
    if not args.report_only:
        results["peak_rss_mib"] = round(_common.peak_rss_mib(), 1)
        payload = {key: value for key, value in results.items() if key not in ("benchmark", "machine")}
        _common.write_result("april", payload)
    lines = ["## APRiL: train on state, deploy on pixels (issue 4, Tables 4.2-4.5)", "",
             "Average actions per episode (T = 50) over seeded evaluation episodes; simulator episodes = "
             "training episodes the row needed (random-policy image episodes for perception + RL episodes; "
             "evaluation episodes not counted). `python benchmarks/april.py` → `results/april.json`.", ""]
    for env, (table, thesis) in THESIS.items():
        rows = results.get(env, {})
        lines += [f"### {env} (thesis Table {table})", "", "| runtime input | ours | success | simulator episodes | thesis |",
                  "|---|---:|---:|---:|---:|"]
        for row, values in rows.items():
            lines.append(f"| {row} | {values['avg_actions']:.2f} ± {values['std']:.2f} | {values['success']:.0%} | "
                         f"{values['sim_episodes']:,} | {thesis.get(row, '–')} |")
        if not rows:
            lines.append("| not run yet | | | | |")
        lines.append("")
    _common.write_section("april", "\n".join(lines))


if __name__ == "__main__":
    main()

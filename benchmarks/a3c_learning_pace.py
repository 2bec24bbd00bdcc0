"""How fast, step for step, does A3C learn Arm2D's single goal from pictures and from the state?

    python benchmarks/a3c_learning_pace.py KEY=RUN_DIR [KEY=RUN_DIR ...] [--bucket 25000] [--until 400000]

The end-to-end pixel learner lags the state learner at the whole goal area; this asks where the lag
starts. It reads each A3C run's own training episodes (TensorBoard ``episode/length``: the policy acting
as it learns, sampling) and the auxiliary state loss, averaged over ``--bucket`` simulator steps, up to
``--until`` (the thesis's single-goal stage ends at 400k in configs/rl_arm2d_curriculum_*.yaml). Runs are
made with ``binpick rl train CONFIG [--steps N] [--set a3c.state_noise=0.06]``; the section in
docs/RESULTS.md names the ones measured. Writes results/a3c_learning_pace.json, docs/img/a3c_learning_pace.png
and its section of docs/RESULTS.md. Reads only event files (no weights); seconds.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, os.path.dirname(__file__))

import _common  # noqa: E402

IMAGE = _common.ROOT / "docs" / "img" / "a3c_learning_pace.png"
MIN_EPISODES = 10  # a bucket with fewer is the run's unfinished last one


def curve(run: Path, bucket: int, until: int) -> dict:
    """Mean training-episode length (and auxiliary state loss) per ``bucket`` steps of one run's TensorBoard."""
    series = _common.training_scalars(run, "episode/length", optional=("loss/state",))
    lengths, losses = defaultdict(list), defaultdict(list)
    for step, value in series["episode/length"]:
        if step < until:
            lengths[step // bucket].append(value)
    for step, value in series.get("loss/state", []):
        if step < until:
            losses[step // bucket].append(value)
    return {"run_dir": str(run.relative_to(_common.ROOT)) if run.is_relative_to(_common.ROOT) else str(run),
            "buckets": [{"from": index * bucket, "to": (index + 1) * bucket, "episodes": len(values),
                         "mean_length": sum(values) / len(values),
                         **({"state_loss": sum(losses[index]) / len(losses[index])} if losses.get(index) else {})}
                        for index, values in sorted(lengths.items()) if len(values) >= MIN_EPISODES]}


def plot(curves: dict, image: Path = IMAGE, title: str = "Arm2D, single goal: A3C from pictures and from the state") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(7, 4))
    for key, measured in curves.items():
        buckets = measured["buckets"]
        axis.plot([(b["from"] + b["to"]) / 2 for b in buckets], [b["mean_length"] for b in buckets], marker="o", label=key)
    axis.set(xlabel="simulator steps", ylabel="training episode length (actions)", yscale="log",
             title=title)
    axis.grid(alpha=0.3)
    axis.legend(fontsize=7)
    figure.tight_layout()
    image.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(image, dpi=110)
    plt.close(figure)


def table(curves: dict, bucket: int) -> list[str]:
    keys = list(curves)
    starts = sorted({b["from"] for measured in curves.values() for b in measured["buckets"]})
    rows = [f"| steps | {' | '.join(keys)} |", "|---|" + "---:|" * len(keys)]
    for start in starts:
        cells = []
        for key in keys:
            found = [b for b in curves[key]["buckets"] if b["from"] == start]
            cells.append(f"{found[0]['mean_length']:.1f}" if found else "")
        rows.append(f"| {start // 1000}k-{(start + bucket) // 1000}k | {' | '.join(cells)} |")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="KEY=RUN_DIR (an A3C run folder with tb/)")
    parser.add_argument("--bucket", type=int, default=25_000)
    parser.add_argument("--until", type=int, default=400_000)
    parser.add_argument("--note", default="", help="a paragraph for docs/RESULTS.md: what the runs are, what they show")
    args = parser.parse_args()
    curves = {key: curve(run, args.bucket, args.until) for key, run in _common.keyed_run_dirs(args.runs)}
    _common.write_result("a3c_learning_pace", {"bucket": args.bucket, "until": args.until, "runs": curves,
                                               "note": args.note, "peak_rss_mib": round(_common.peak_rss_mib(), 1)})
    plot(curves)
    _common.write_section("a3c_learning_pace", "\n".join([
        "## A3C's pace on Arm2D's single goal, from pictures and from the state",
        "",
        f"`python benchmarks/a3c_learning_pace.py KEY=RUN ...`: mean length of each run's own training episodes "
        f"(sampling, as it learns) per {args.bucket:,} simulator steps, at the single goal the curriculum starts with. "
        "Runs: " + "; ".join(f"{key}: `{measured['run_dir']}`" for key, measured in curves.items()) + ".",
        "",
        *table(curves, args.bucket),
        "",
        *([args.note, ""] if args.note else []),
        "![training episodes per step](img/a3c_learning_pace.png)",
    ]))
    for key, measured in curves.items():
        print(key, [round(b["mean_length"], 1) for b in measured["buckets"]])


if __name__ == "__main__":
    main()

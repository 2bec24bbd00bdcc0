"""Random-policy baselines: average episode length (actions until success, capped at T) ± std.

    python experiments/random_policy.py [--episodes 1000]

Thesis figures: Arm2D with a fixed goal 369 ± 341 (T=1000, Table 3.1); Reacher 49.46 ± 4.49
(T=50, Table 4.2). Also measured for the Fetch worlds, which the thesis does not report.
Writes results/random_policy.json and the random-baseline table of docs/RESULTS.md.
Arm2D runs state-only (``image=None``): a random policy ignores pixels, and the dynamics are the same.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import _common  # noqa: E402
from rich.progress import Progress  # noqa: E402

import binpick  # noqa: E402
from binpick.rl.common.evaluate import evaluate_policy, random_policy  # noqa: E402

CASES = [
    # env id, kwargs, thesis mean, thesis std, where in the thesis, share of --episodes
    ("binpick/Arm2D-v0", {"goal_conditioned": True, "image": None}, 369.0, 341.0, "Table 3.1 (fixed goal)", 1.0),
    ("binpick/Reacher-v0", {}, 49.46, 4.49, "Table 4.2", 1.0),
    ("binpick/FetchReach-v0", {}, None, None, "—", 0.2),
    ("binpick/FetchReachObstacle-v0", {}, None, None, "—", 0.2),
    ("binpick/FetchPickAndPlace-v0", {}, None, None, "—", 0.2),
]


def section(result: dict) -> str:
    """The random-baselines section of docs/RESULTS.md, from results/random_policy.json."""
    lines = [
        "## Random-policy baselines",
        "",
        "Average episode length = actions until success, capped at T; ± one standard deviation over "
        "seeded episodes (episode i uses seed i). Produced by `python experiments/random_policy.py` → "
        "`results/random_policy.json`.",
        "",
        "| env | T | episodes | ours: avg actions ± std | success | thesis | source |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for row in result["rows"]:
        thesis = "—" if row["thesis_mean_length"] is None else f"{row['thesis_mean_length']:g} ± {row['thesis_std_length']:g}"
        lines.append(f"| `{row['env_id']}` | {row['max_episode_steps']} | {row['episodes']} | "
                     f"{row['mean_length']:.2f} ± {row['std_length']:.2f} | {100 * row['success_rate']:.1f}% | "
                     f"{thesis} | {row['thesis_source']} |")
    lines += [
        "",
        "The thesis does not state its success radii. Arm2D's default tolerance (0.07, 7% of the arm's "
        "reach) and Reacher's (0.02 m) were chosen so that a random walk behaves like the thesis's random "
        "baseline; everything learnt later is compared against these same settings.",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rows = []
    with Progress() as progress:
        for env_id, kwargs, thesis_mean, thesis_std, where, share in CASES:
            episodes = max(10, int(args.episodes * share))
            env = binpick.make(env_id, **kwargs)
            unwrapped = env.unwrapped
            tolerance = getattr(unwrapped, "tolerance", getattr(unwrapped, "distance_threshold", None))
            task = progress.add_task(env_id, total=episodes)
            started = time.perf_counter()
            result = evaluate_policy(random_policy(env, args.seed), env, episodes=episodes, seed=args.seed,
                                     on_episode=lambda *_: progress.advance(task))
            env.close()
            rows.append({**result.to_dict(), "env_kwargs": kwargs, "success_tolerance": tolerance,
                         "thesis_mean_length": thesis_mean,
                         "thesis_std_length": thesis_std, "thesis_source": where,
                         "seconds": round(time.perf_counter() - started, 1),
                         "peak_rss_mib": round(_common.peak_rss_mib(), 1)})
            progress.console.print(result.summary())
    path = _common.write_result("random_policy", {"seed": args.seed, "rows": rows})
    print(f"wrote {path}")

    _common.write_section_of("random_policy", section, "random_policy.json")


if __name__ == "__main__":
    main()

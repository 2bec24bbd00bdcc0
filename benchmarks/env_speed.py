"""Env steps per second on this machine: without images, and with 64, 84 and 128 px RGB images.

    python benchmarks/env_speed.py [--seconds 3]

Writes results/env_speed.json and the env-speed table of docs/RESULTS.md. Random actions; the
episode is reset when it ends (reset time counts). Target: FetchReach >= 800 steps/s
without images and >= 80 steps/s with 84x84 images on a 2-core machine.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "experiments"))  # _common: results and docs

import _common  # noqa: E402

import binpick  # noqa: E402

SETTINGS = {"none": None, "64": 64, "84": 84, "128": 128}
TARGETS = {("binpick/FetchReach-v0", "none"): 800, ("binpick/FetchReach-v0", "84"): 80}


def env_kwargs(env_id: str, size: int | None) -> dict:
    if env_id.endswith("Arm2D-v0"):
        if size is None:
            return {"goal_conditioned": True, "image": None}
        return {"image_size": size}
    return {} if size is None else {"image": "rgb", "image_size": size}


def steps_per_second(env_id: str, size: int | None, seconds: float) -> tuple[float, int]:
    env = binpick.make(env_id, **env_kwargs(env_id, size))
    try:
        env.action_space.seed(0)
        env.reset(seed=0)
        for _ in range(20):  # warm-up: first renders and allocations
            env.step(env.action_space.sample())
        steps, started = 0, time.perf_counter()
        while time.perf_counter() - started < seconds:
            for _ in range(50):
                _, _, terminated, truncated, _ = env.step(env.action_space.sample())
                steps += 1
                if terminated or truncated:
                    env.reset()
        return steps / (time.perf_counter() - started), steps
    finally:
        env.close()


def section(result: dict) -> str:
    """The env-speed section of docs/RESULTS.md, from results/env_speed.json."""
    by_env: dict[str, dict[str, float]] = {}
    for row in result["rows"]:
        by_env.setdefault(row["env_id"], {})[row["image"]] = row["steps_per_s"]
    lines = [
        "## Environment speed",
        "",
        f"Steps per second with random actions, one process, `MUJOCO_GL={result['machine']['mujoco_gl']}` "
        f"(Mesa llvmpipe), {result['machine']['cpu_count']} cores; RGB image observations rendered every step. "
        "Produced by `python benchmarks/env_speed.py` → `results/env_speed.json`.",
        "",
        "| env | no image | 64×64 | 84×84 | 128×128 |",
        "|---|---:|---:|---:|---:|",
    ]
    for env_id, rates in by_env.items():
        lines.append(f"| `{env_id}` | " + " | ".join(f"{rates[k]:,.0f}" for k in SETTINGS) + " |")
    lines += ["", "| target | ours | met |", "|---|---:|---|"]
    for check in result["targets"]:
        what = "no image" if check["image"] == "none" else f"{check['image']}×{check['image']} images"
        lines.append(f"| {check['env_id']} ≥ {check['target_steps_per_s']} steps/s, {what} | "
                     f"{check['steps_per_s']:,.0f} | {'yes' if check['met'] else '**no**'} |")
    lines.append(f"\nPeak RSS of the whole run: {result['peak_rss_mib']:.0f} MiB.")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="timed seconds per env and setting")
    args = parser.parse_args()
    rows = []
    for env_id in binpick.ENV_IDS:
        for label, size in SETTINGS.items():
            rate, steps = steps_per_second(env_id, size, args.seconds)
            rows.append({"env_id": env_id, "image": label, "steps_per_s": round(rate, 1), "steps": steps,
                         "peak_rss_mib": round(_common.peak_rss_mib(), 1)})
            print(f"{env_id:32s} image={label:>4s}  {rate:8.1f} steps/s", flush=True)
    checks = []
    for (env_id, label), target in TARGETS.items():
        rate = next(r["steps_per_s"] for r in rows if r["env_id"] == env_id and r["image"] == label)
        checks.append({"env_id": env_id, "image": label, "target_steps_per_s": target, "steps_per_s": rate,
                       "met": rate >= target})
    path = _common.write_result("env_speed", {"seconds_per_setting": args.seconds, "rows": rows, "targets": checks,
                                              "peak_rss_mib": round(_common.peak_rss_mib(), 1)})
    print(f"wrote {path}")

    _common.write_section_of("env_speed", section, "env_speed.json")


if __name__ == "__main__":
    main()

"""ROS bridge round trip on this machine (thesis §6.1.1): a Fetch Reach env served by
``binpick ros serve``, driven over ROS by the scripted reach policy from ``binpick ros bench``, on a
master at 127.0.0.1.

    python benchmarks/ros_latency.py [--episodes 50]

Writes results/ros_latency.json ({median_ms, p95_ms, ...}) and the ROS section of docs/RESULTS.md.
A round trip is one action: goal sent -> server steps MuJoCo -> result back. The simulator's own
step time, measured without ROS, is recorded beside it. Target: median <= 5 ms.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "experiments"))  # _common: results and docs

import _common  # noqa: E402

CLI = [sys.executable, "-c", "from binpick.cli import main; main()"]


def sim_step_ms(steps: int = 300) -> float:
    import numpy as np

    from binpick.envs import make

    env = make("binpick/FetchReach-v0")
    env.reset(seed=0)
    times = []
    for _ in range(steps):
        started = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        times.append(1000 * (time.perf_counter() - started))
        if terminated or truncated:
            env.reset()
    env.close()
    return round(float(np.median(times)), 3)


def section(result: dict) -> str:
    """The ROS-bridge section of docs/RESULTS.md, from results/ros_latency.json."""
    lines = ["## ROS bridge (thesis §6.1.1)", "",
             f"`python benchmarks/ros_latency.py --episodes {result['episodes']}` → `results/ros_latency.json`. "
             "Fetch Reach served by `binpick ros serve` (actionlib.ActionServer), driven by `binpick ros bench` through "
             "`binpick/Ros-v0`, master on 127.0.0.1.", "",
             "| | ours | target |", "|---|---|---|",
             f"| round trip per action, median | {result['median_ms']:.2f} ms | ≤ 5 ms ({'met' if result['met'] else 'missed'}) |",
             f"| round trip per action, p95 | {result['p95_ms']:.2f} ms | — |",
             f"| MuJoCo step alone (no ROS), median | {result['sim_step_ms_without_ros']:.2f} ms | — |",
             f"| scripted reach through the bridge | {result['success_rate']:.0%} success, {result['mean_actions']:.2f} actions "
             f"({result['episodes']} episodes) | — |", "",
             f"Load average while measuring: {result['load_average']} on 2 cores."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=50)
    args = parser.parse_args()
    from binpick.integrations.ros1.master import RosMaster

    with RosMaster() as master, tempfile.TemporaryDirectory() as folder:
        server = subprocess.Popen(CLI + ["ros", "serve", "binpick/FetchReach-v0", "--namespace", "/binpick/fetch_reach",
                                         "--master", master.uri], env=master.environment,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            out = Path(folder) / "bench.json"
            subprocess.run(CLI + ["ros", "bench", "--namespace", "/binpick/fetch_reach", "--episodes", str(args.episodes),
                                  "--master", master.uri, "--out", folder, "--timeout", "60"],
                           env=master.environment, check=True, stdout=subprocess.DEVNULL)
            summary = json.loads(out.read_text())
        finally:
            server.terminate()
            server.wait(timeout=20)
    load = os.getloadavg()[0]
    result = {"median_ms": summary["median_ms"], "p95_ms": summary["p95_ms"], "round_trips": summary["round_trips"],
              "episodes": summary["episodes"], "success_rate": summary["success_rate"], "mean_actions": summary["mean_length"],
              "sim_step_ms_without_ros": sim_step_ms(), "target_median_ms": 5.0, "met": summary["median_ms"] <= 5.0,
              "load_average": round(load, 2), "policy": "scripted reach: clip(10 (goal - gripper), -1, 1)"}
    _common.write_result("ros_latency", result)
    print(_common.write_section_of("ros_latency", section, "ros_latency.json"))


if __name__ == "__main__":
    main()

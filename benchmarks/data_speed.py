"""Warehouse data generation speed on this machine: bin scenes per second without labels (one
process, 416 px, written to disk as a data set) and trial grasps per second with labels.

    python benchmarks/data_speed.py [--scenes 40] [--trial-scenes 6]

Writes results/data_speed.json ({scenes_per_s, grasp_trials_per_s, image_size, ...}) and the
data-speed section of docs/RESULTS.md. Target: >= 3 scenes/s per core at 416 px.
The load average is recorded: other jobs on the machine slow both figures.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "experiments"))  # _common: results and docs

import _common  # noqa: E402

from binpick.warehouse.dataset import generate_world, prepare_output, world_plan  # noqa: E402
from binpick.warehouse.generation import GenerateConfig, build_library  # noqa: E402


def scenes_per_second(scenes: int, size: int, domain: str = "default") -> tuple[float, int]:
    """One process making a data set without labels: compiles, settles, renders, annotates, writes.
    Scenes per second of process CPU time, so that other jobs on the machine do not count."""
    folder = Path(tempfile.mkdtemp(prefix="binpick_speed_"))
    try:
        config = GenerateConfig(out=str(folder / "data"), scenes=scenes, policies=[], workers=1, image_size=size, seed=1,
                                domain=domain, scenes_per_world=16 if domain == "random" else 8)
        library = build_library(config)
        out = prepare_output(config, library)
        started = time.process_time()
        made = 0
        for world in range(-(-scenes // config.scenes_per_world)):
            made += len(generate_world(config, world, out))
        return made / (time.process_time() - started), made
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def ray_scenes_per_second(scenes: int, size: int, workers: int) -> float:
    """Randomised scenes through Ray tasks on a private local cluster of ``workers`` CPUs (wall clock,
    Ray's start excluded: the cluster is up before the clock starts)."""
    import ray

    from binpick.core.cluster import start_ray
    from binpick.warehouse.dataset import DataGeneration

    folder = Path(tempfile.mkdtemp(prefix="binpick_ray_"))
    owns = start_ray(None, workers)
    try:
        config = GenerateConfig(out=str(folder / "data"), scenes=scenes, policies=[], workers=workers, image_size=size,
                                seed=2, domain="random", scenes_per_world=8, address="local")
        job = DataGeneration.new(config)
        started = time.perf_counter()
        job.run()
        return scenes / (time.perf_counter() - started)
    finally:
        if owns:
            ray.shutdown()
        shutil.rmtree(folder, ignore_errors=True)


def trials_per_second(scenes: int, size: int) -> tuple[float, int, float]:
    """Trial grasps (both policies, every target instance) in freshly settled scenes."""
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.gripper import make_policies
    from binpick.sim.mjcf import CameraSpec

    config = GenerateConfig(out="unused", scenes=scenes, image_size=size, seed=2)
    library = build_library(config)
    policies = make_policies(["x", "y"])
    trials, picked, seconds = 0, 0, 0.0
    for index in range(scenes):
        target, distractors, _ = world_plan(config, library, index)
        world = BinWorld(library[target], [library[d] for d in distractors], camera=CameraSpec(size=size), gripper=True)
        try:
            scene = world.scene(5, 2, seed=index)
            started = time.perf_counter()
            for policy in policies:
                for instance in scene.instances:
                    if instance.is_target:
                        world.restore(scene.state)
                        picked += policy.attempt(world, instance.slot)
                        trials += 1
            seconds += time.perf_counter() - started
        finally:
            world.close()
    return trials / seconds, trials, picked / max(trials, 1)


def section(result: dict) -> str:
    """The data-speed section of docs/RESULTS.md, from results/data_speed.json."""
    rate, random_rate, size = result["scenes_per_s"], result["randomised_scenes_per_s"], result["image_size"]
    ray_rates = result["ray_scenes_per_s"]
    return "\n".join([
        "## Warehouse data generation speed", "",
        "`python benchmarks/data_speed.py` → `results/data_speed.json`. One process (per core: scenes per second of its CPU time); scenes are settled, rendered "
        "(RGB, depth, segmentation, per-instance masks for the visible fraction), annotated and written as PNG + JSON.", "",
        "| | ours | target |", "|---|---|---|",
        f"| scenes/s without labels, {size} px, one core | {rate:.2f} | ≥ 3 ({'met' if rate >= 3 else 'missed'}) |",
        f"| domain-randomised scenes/s, {size} px, one core (`--domain random`) | {random_rate:.2f} | ≥ 3 ({'met' if random_rate >= 3 else 'missed'}) |",
        f"| randomised scenes/s through Ray, 1 / 2 local workers (wall clock) | {ray_rates['1']:.2f} / {ray_rates['2']:.2f} | — |",
        f"| trial grasps/s (scripted top-down, both policies) | {result['grasp_trials_per_s']:.2f} | — |", "",
        f"Load average while measuring: {result['load_average_1min']:.2f} on {result['machine']['cpu_count']} cores; "
        f"peak RSS {result['peak_rss_mib']:.0f} MiB.",
    ])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=40)
    parser.add_argument("--trial-scenes", type=int, default=6)
    parser.add_argument("--size", type=int, default=416)
    parser.add_argument("--ray-scenes", type=int, default=32)
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    rate, made = scenes_per_second(args.scenes, args.size)
    print(f"scenes/s without labels at {args.size} px, one process: {rate:.2f} ({made} scenes)")
    random_rate, random_made = scenes_per_second(args.scenes, args.size, "random")
    print(f"randomised scenes/s per core at {args.size} px: {random_rate:.2f} ({random_made} scenes)")
    ray_rates = {str(w): round(ray_scenes_per_second(args.ray_scenes, args.size, w), 3) for w in (1, 2)}
    print(f"randomised scenes/s through Ray (1, 2 local workers): {ray_rates}")
    trial_rate, trials, picked = trials_per_second(args.trial_scenes, args.size)
    print(f"trial grasps/s: {trial_rate:.2f} ({trials} trials, {picked:.0%} picked)")
    load = max(load_before, os.getloadavg()[0])
    result = {"scenes_per_s": round(rate, 3), "randomised_scenes_per_s": round(random_rate, 3), "ray_scenes_per_s": ray_rates,
              "grasp_trials_per_s": round(trial_rate, 3), "image_size": args.size,
              "scenes": made, "trials": trials, "trial_pick_rate": round(picked, 3), "processes": 1,
              "target_scenes_per_s_per_core": 3.0, "met": rate >= 3.0, "randomised_met": random_rate >= 3.0, "load_average_1min": round(load, 2),
              "peak_rss_mib": round(_common.peak_rss_mib(), 1)}
    _common.write_result("data_speed", result)
    _common.write_section_of("data_speed", section, "data_speed.json")


if __name__ == "__main__":
    main()

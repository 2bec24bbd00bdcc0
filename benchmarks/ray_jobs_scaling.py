"""The jobs besides the detector on Ray (loopback only), and faults: the pickability head and the
grasp-quality model on Ray Train, A3C with its rollout workers as Ray actors, each against a plain local
run with the same data, seed and budget; then one worker killed in a detector run and one rollout actor
killed in an A3C run, each against the same run uninterrupted.

    python benchmarks/ray_jobs_scaling.py [--scenes 120] [--epochs 20] [--a3c-steps 20000]

Makes a small labelled bin set with grasp trials (runs/data/bins_ray_labelled_<scenes>, resumable), then:
pickability (shipped rod_tiny_320 detector; windows cut once beforehand and given to every run, so the
rows time training alone) and grasp quality, each local with 2 threads, on 1 Ray Train worker of 2
threads and on 2 workers of 1 thread; A3C on Table 3.2's deep-bottleneck curriculum config (perception
pre-training off: it runs on the driver alike in every mode) locally with 2 worker processes and on Ray
with 1 and 2 rollout actors. Faults: the detector on runs/data/bins_ray (benchmarks/ray_train_scaling.py
makes it) for 4 epochs on 2 workers, one SIGKILLed after the first checkpoint; A3C on 2 actors, one
SIGKILLed a third of the way. Writes ``pickability``, ``grasp_quality``, ``a3c`` and ``faults`` of
results/ray_scaling.json and the ``ray_jobs`` section of docs/RESULTS.md. The machine's load average is
recorded: these rows share 2 cores with whatever else runs.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "experiments"))  # _common: results and docs

import _common  # noqa: E402

DATA = _common.ROOT / "runs" / "data" / "bins_ray_labelled"  # + _<scenes>
DETECTOR_DATA = _common.ROOT / "runs" / "data" / "bins_ray"
RUNS = _common.ROOT / "runs" / "ray_jobs"
RL_CONFIG = _common.ROOT / "configs" / "rl" / "rl_arm2d_curriculum_keypoints_bottleneck_deep.yaml"
DETECT_CONFIG = _common.ROOT / "configs" / "detection" / "rod_warehouse.yaml"
DEFAULTS = {"scenes": 120, "epochs": 20, "a3c_steps": 20000, "fault_epochs": 4}  # the command's arguments


def make_data(scenes: int) -> None:
    global DATA
    from binpick.core.config import from_dict
    from binpick.warehouse.dataset import DataGeneration
    from binpick.warehouse.generation import GenerateConfig

    DATA = DATA.with_name(f"{DATA.name}_{scenes}")
    if (DATA / "dataset.json").is_file() and len(list((DATA / "scenes").glob("*.json"))) >= scenes:
        return
    if (DATA / "dataset.json").is_file():
        DataGeneration.resume(DATA).run()
        return
    config = from_dict(GenerateConfig, {"out": str(DATA), "scenes": scenes, "policies": ["analytic"], "grasp_trials": 3,
                                        "workers": 2, "image_size": 256, "split_rule": "random", "val_fraction": 0.2,
                                        "scenes_per_world": 4}, where="benchmark")
    DataGeneration.new(config).run()


def ours(pid: int) -> bool:
    """Whether process ``pid`` descends from this one (a worker of this benchmark's private cluster)."""
    me = os.getpid()
    while pid > 1:
        if pid == me:
            return True
        try:
            pid = int(open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            return False
    return False


def timed(mode: str, job, threads: int) -> tuple[dict, float]:
    from binpick.core import jobs

    started = time.perf_counter()
    if mode == "local":
        metrics = job.run()
    else:
        metrics = jobs.run_job(job, address="local", workers=int(mode.split("_")[1]), threads=threads)
    return metrics, time.perf_counter() - started


def pickability(epochs: int) -> dict:
    from binpick.core.runs import SILENT
    from binpick.detection.pickability_training import PickabilityConfig, PickabilityTrainer

    config = PickabilityConfig(train=[str(DATA / "annotations_train.json")], val=str(DATA / "annotations_val.json"),
                               targets="pickable:analytic", epochs=epochs, batch_size=32, threads=2, name="pickability_ray")
    first = PickabilityTrainer.new(config, RUNS)
    windows = first._windows(SILENT)  # cut once; every run below reads them from its folder
    items = len(windows["train_labels"]) * epochs
    rows = {}
    for mode, threads in (("local", 2), ("workers_1", 2), ("workers_2", 1)):
        job = PickabilityTrainer.new(config, RUNS)
        shutil.copyfile(first.run_dir / "windows.safetensors", job.run_dir / "windows.safetensors")
        metrics, wall = timed(mode, job, threads)
        rows[mode] = {"val_auc": metrics["best_val_auc"], "windows": items, "wall_s": round(wall, 1),
                      "windows_per_s": round(items / wall, 1), "run": str(job.run_dir.relative_to(_common.ROOT))}
        print("pickability", mode, json.dumps(rows[mode]), flush=True)
    return rows


def grasp_quality(epochs: int) -> dict:
    from binpick.grasping.training import QualityTrainConfig, QualityTrainer, load_trials

    config = QualityTrainConfig(data=str(DATA), epochs=epochs, batch_size=32, threads=2, name="grasp_quality_ray")
    items = len(load_trials(str(DATA), "train")) * epochs
    rows = {}
    for mode, threads in (("local", 2), ("workers_1", 2), ("workers_2", 1)):
        job = QualityTrainer.new(config, RUNS)
        metrics, wall = timed(mode, job, threads)
        rows[mode] = {"val_auc": metrics["best_val_auc"], "trials": items, "wall_s": round(wall, 1),
                      "trials_per_s": round(items / wall, 1), "run": str(job.run_dir.relative_to(_common.ROOT))}
        print("grasp_quality", mode, json.dumps(rows[mode]), flush=True)
    return rows


def a3c_config(steps: int, workers: int):
    from binpick.rl.config import RLConfig
    from binpick.core.config import load_config

    return load_config(RLConfig, RL_CONFIG, {"total_timesteps": steps, "checkpoint_every": steps // 2, "a3c.workers": workers,
                                      "a3c.pretrain_pictures": 0, "eval.every": steps // 2, "eval.episodes": 3,
                                      "name": f"a3c_ray_{workers}"})


def a3c_run(steps: int, workers: int, on_ray: bool, on_update=None) -> dict:
    from binpick.integrations.ray.a3c import learn_on_ray
    from binpick.rl.a3c.train import A3CTrainer

    trainer = A3CTrainer.new(a3c_config(steps, workers), RUNS)
    metrics = trainer.run(learn=learn_on_ray("local", on_update) if on_ray else None)
    return {"sim_steps": metrics["sim_steps"], "evaluations_at": [e["sim_steps"] for e in metrics["evaluations"]],
            "final_success": metrics["final_success"], "wall_s": round(metrics["wall_seconds"], 1),
            "steps_per_s": round(metrics["sim_steps"] / metrics["wall_seconds"], 1),
            "worker_restarts": metrics.get("worker_restarts", 0), "lost_rollouts": metrics.get("lost_rollouts", 0),
            "run": str(trainer.run_dir.relative_to(_common.ROOT))}


def a3c(steps: int) -> dict:
    rows = {"local": a3c_run(steps, 2, on_ray=False)}
    print("a3c local", json.dumps(rows["local"]), flush=True)
    for workers in (1, 2):
        rows[f"workers_{workers}"] = a3c_run(steps, workers, on_ray=True)
        print("a3c", workers, json.dumps(rows[f"workers_{workers}"]), flush=True)
    return rows


def rollout_fault(steps: int, uninterrupted: dict) -> dict:
    killed: list[int] = []
    pids: list[int] = []

    def kill_one(trainer, actors) -> None:
        """Actor 1 SIGKILLed while a rollout of its is in flight (so that rollout is lost)."""
        if not pids:
            pids.extend(actors.pids())  # asked once: a pid call waits behind the actor's rollout
        if not killed and trainer.steps >= steps // 3 and 1 in actors.in_flight.values():
            os.kill(pids[1], signal.SIGKILL)
            killed.append(pids[1])

    faulty = a3c_run(steps, 2, on_ray=True, on_update=kill_one)
    same = faulty["sim_steps"] == uninterrupted["sim_steps"] and faulty["evaluations_at"] == uninterrupted["evaluations_at"]
    return {"killed": len(killed), "uninterrupted": {k: uninterrupted[k] for k in ("sim_steps", "evaluations_at")},
            "faulty": faulty, "same_final": bool(killed) and same}


def detector_fault(epochs: int) -> dict:
    from binpick.core import jobs

    if not (DETECTOR_DATA / "annotations_train.json").is_file():
        sys.exit(f"{DETECTOR_DATA} is missing: python benchmarks/ray_train_scaling.py makes it")
    overrides = {"data.train": str(DETECTOR_DATA / "annotations_train.json"), "data.val": str(DETECTOR_DATA / "annotations_val.json"),
                 "data.targets": "all", "train.epochs": epochs, "train.eval_every": 1, "train.workers": 0, "train.threads": 1}

    def run(name: str, kill: bool) -> tuple[dict, list[int]]:
        job = jobs.open_job(DETECT_CONFIG, runs=RUNS, overrides={**overrides, "name": name})
        killed: list[int] = []

        def killer() -> None:
            deadline = time.monotonic() + 1800
            while time.monotonic() < deadline and not list((job.run_dir / "checkpoints").glob("ckpt-*")):
                time.sleep(0.1)
            found = subprocess.run(["pgrep", "-f", "RayTrainWorker"], capture_output=True, text=True).stdout.split()
            pids = [pid for pid in found if ours(int(pid))]  # this benchmark's workers, no one else's
            if pids:
                os.kill(int(pids[-1]), signal.SIGKILL)
                killed.append(int(pids[-1]))

        watcher = threading.Thread(target=killer, daemon=True) if kill else None
        if watcher is not None:
            watcher.start()
        metrics = jobs.run_job(job, address="local", workers=2, threads=1)
        if watcher is not None:
            watcher.join(timeout=10)
        return metrics, killed

    plain, _ = run("rod_ray_fault_none", kill=False)
    faulty, killed = run("rod_ray_fault_killed", kill=True)

    def shape(metrics: dict) -> dict:
        return {"epochs": metrics["epochs"], "steps": metrics["steps"], "evaluated_epochs": [h["epoch"] for h in metrics["history"]
                                                                                          if h.get("ap50") is not None],
                "final_ap50": round(metrics["final"]["ap50"], 4)}

    same = {k: v for k, v in shape(plain).items() if k != "final_ap50"} == {k: v for k, v in shape(faulty).items() if k != "final_ap50"}
    return {"killed": len(killed), "uninterrupted": shape(plain), "faulty": shape(faulty), "same_final": bool(killed) and same}


def detector_efficiency(result: dict) -> str:
    """The detector's 2-over-1 ratio of benchmarks/ray_train_scaling.py, kept in the same results file."""
    detector = result.get("detector") or {}
    return f"{detector['efficiency_2_workers']:.2f}" if "efficiency_2_workers" in detector else "not measured yet"


def section(result: dict) -> str:
    """The other-jobs-on-Ray section of docs/RESULTS.md, from results/ray_scaling.json (its ``jobs_settings``: the
    command's arguments; the defaults where a file written before it kept them lacks it)."""
    settings = {**DEFAULTS, **result.get("jobs_settings", {})}
    lines = ["## The other jobs on Ray, and faults", "",
             f"`python benchmarks/ray_jobs_scaling.py --scenes {settings['scenes']} --epochs {settings['epochs']} "
             f"--a3c-steps {settings['a3c_steps']}`: "
             "a private Ray cluster on this 2-core machine (127.0.0.1); each job against a plain local run with the same "
             f"data, seed and budget. Load average while measuring: {result['load_average']} (other work shared the cores: "
             "the rates compare the modes, not the machine's best). Ray runs its worker processes at nice 15: under load "
             "they yield the cores to every normal-priority process, so rows measured beside other work (a high load "
             "average above) can differ several-fold for that reason alone; only rows measured on a quiet machine "
             "show scaling.", "",
             "| job | run | quality | items/s | wall s |", "|---|---|---|---|---|"]
    names = {"local": "local, 2 threads", "workers_1": "Ray, 1 worker × 2 threads", "workers_2": "Ray, 2 workers × 1 thread"}
    for job, quality, rate, what in (("pickability", "val_auc", "windows_per_s", "val ROC AUC"),
                                     ("grasp_quality", "val_auc", "trials_per_s", "val ROC AUC")):
        for mode, row in result[job].items():
            if isinstance(row, dict):
                lines.append(f"| {job} | {names[mode]} | {what} {row[quality]:.3f} | {row[rate]:.0f} | {row['wall_s']:.0f} |")
    a3c_names = {"local": "local, 2 worker processes", "workers_1": "Ray, 1 rollout actor", "workers_2": "Ray, 2 rollout actors"}
    for mode, row in result["a3c"].items():
        if isinstance(row, dict):
            lines.append(f"| A3C (Table 3.2 deep bottleneck) | {a3c_names[mode]} | success {row['final_success']:.0%} "
                         f"at {row['sim_steps']:,} steps | {row['steps_per_s']:.0f} | {row['wall_s']:.0f} |")
    eff = result["efficiency_2_over_1"]
    lines += ["", "Items per second: pickability windows, grasp trials or simulator steps trained on over the run's wall time "
              f"(Ray's start-up included). 2 workers over 1 on the same 2 cores: pickability {eff['pickability']:.2f}, "
              f"grasp quality {eff['grasp_quality']:.2f}, A3C {eff['a3c']:.2f} (detector, measured on a quiet machine: its own "
              f"section, {detector_efficiency(result)}). Two data-parallel processes on the same two cores cannot do more work than one using both "
              "(under other load a ratio far from 1 is the load's doing). A3C is different: with one rollout actor the "
              "actor waits while the learner applies its gradients and the learner waits for the next rollout, so one core "
              "idles; a second actor fills it. On N machines a data-parallel "
              "job gains while a step's compute outweighs its all-reduce, and A3C gains roughly with the actors' cores until "
              "the learner's one-rollout-at-a-time update saturates: a projection, not measured here.", "",
              "Faults (`faults` in results/ray_scaling.json):", ""]
    detector, rollouts = result["faults"]["detector"], result["faults"]["rollouts"]
    lines.append(f"- detector, 2 Ray Train workers, one SIGKILLed after the first checkpoint: {detector['faulty']['epochs']} epochs, "
                 f"{detector['faulty']['steps']} steps, evaluated at epochs {detector['faulty']['evaluated_epochs']} — uninterrupted: "
                 f"{detector['uninterrupted']['epochs']}, {detector['uninterrupted']['steps']}, "
                 f"{detector['uninterrupted']['evaluated_epochs']}; same: **{detector['same_final']}**.")
    lines.append(f"- A3C, 2 rollout actors, one SIGKILLed a third of the way: {rollouts['faulty']['sim_steps']:,} steps, "
                 f"evaluations at {rollouts['faulty']['evaluations_at']} ({rollouts['faulty']['worker_restarts']} restart, "
                 f"{rollouts['faulty']['lost_rollouts']} lost rollout(s) handed out again) — uninterrupted: "
                 f"{rollouts['uninterrupted']['sim_steps']:,}, {rollouts['uninterrupted']['evaluations_at']}; "
                 f"same: **{rollouts['same_final']}**.")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for name, default in DEFAULTS.items():
        parser.add_argument(f"--{name.replace('_', '-')}", type=int, default=default)
    args = parser.parse_args()
    make_data(args.scenes)
    path = _common.RESULTS / "ray_scaling.json"
    result = json.loads(path.read_text()) if path.is_file() else {}
    for key in ("benchmark", "machine"):
        result.pop(key, None)
    result["pickability"] = pickability(args.epochs)
    result["grasp_quality"] = grasp_quality(args.epochs)
    result["a3c"] = a3c(args.a3c_steps)
    result["faults"] = {"rollouts": rollout_fault(args.a3c_steps, result["a3c"]["workers_2"]),
                        "detector": detector_fault(args.fault_epochs)}
    result["efficiency_2_over_1"] = {
        "pickability": round(result["pickability"]["workers_2"]["windows_per_s"] / result["pickability"]["workers_1"]["windows_per_s"], 3),
        "grasp_quality": round(result["grasp_quality"]["workers_2"]["trials_per_s"] / result["grasp_quality"]["workers_1"]["trials_per_s"], 3),
        "a3c": round(result["a3c"]["workers_2"]["steps_per_s"] / result["a3c"]["workers_1"]["steps_per_s"], 3)}
    result["load_average"] = [round(x, 2) for x in os.getloadavg()]
    result["jobs_peak_rss_mib"] = _common.peak_rss_mib()
    result["jobs_settings"] = {name: getattr(args, name) for name in DEFAULTS}
    _common.write_result("ray_scaling", result)
    _common.write_section_of("ray_jobs", section, "ray_scaling.json")


if __name__ == "__main__":
    main()

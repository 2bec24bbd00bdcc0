"""`binpick train CONFIG` trains every kind of job, and a run stopped by Ctrl-C (SIGINT) continues with
`binpick train --resume RUN` to the same final count an uninterrupted run reaches: RL and APRiL's policy
to their simulator steps, the detector, pickability and grasp-quality trainers to their epochs, a data
set to its scenes. Each run is a real CLI process (forked by cli_zygote), interrupted once its first checkpoint is on disk."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml
import cli_zygote
from conftest import binpick_here
from synthetic_coco import make_coco

from binpick.core import jobs
from binpick.core.errors import ConfigError

TINY_SAC = {"env": "FetchReach", "algorithm": "sac", "min_action_scale": 0.4, "checkpoint_every": 50,
            "replay": {"capacity_episodes": 100, "her_additions": 1, "start_fraction": 0.01},
            "gp": {"enabled": True, "warmup_episodes": 2, "refit_every": 100, "imagined_per_real": 1, "batch_episodes": 8,
                   "iterations": 3, "max_points": 60},
            "sac": {"batch_size": 16, "net_arch": [8, 8]}, "eval": {"every": 100, "episodes": 1}}


def checkpointed(run: Path, stdout: list[str] = ()) -> bool:
    return any(not p.name.startswith(".partial") for p in run.glob("checkpoints/ckpt-*"))


def rl_setup(tmp: Path):
    config = {"task": "rl", "name": "tiny_rl", "total_timesteps": 300, **TINY_SAC}
    return config, 300, checkpointed


def april_setup(tmp: Path):
    policy = {"name": "tiny_policy", "total_timesteps": 300, **TINY_SAC}
    (tmp / "policy.yaml").write_text(yaml.safe_dump(policy))
    config = {"task": "april", "name": "tiny_april", "env": "FetchReach", "image": "grey", "collect": {"episodes": 2},
              "perception": {"kind": "ae", "latent": 6, "conditioned": 6, "omega": 1.0, "channels": 4},
              "perception_training": {"epochs": 1, "batch_size": 16},
              "policy": {"mode": "semantic", "rl_config": str(tmp / "policy.yaml"), "finetune_steps": 0},
              "eval": {"episodes": 1}}
    return config, 300, lambda run, stdout=(): any(not p.name.startswith(".partial") for p in run.glob("rl/**/checkpoints/ckpt-*"))


def detect_setup(tmp: Path):
    coco = make_coco(tmp / "coco", images=8, size=64, seed=1)
    config = {"task": "detect", "name": "tiny_detect",
              "data": {"train": str(coco), "val": str(coco), "targets": "all", "image_size": 64, "augment": False},
              "train": {"epochs": 8, "batch_size": 4, "warmup_steps": 1, "eval_every": 1, "workers": 0, "threads": 1}}
    return config, 8, checkpointed


def pickability_setup(tmp: Path):
    import torch

    from binpick.detection.model import DetectorNetwork, ModelSpec
    from binpick.detection.weights_file import save_detector

    train = make_coco(tmp / "train", images=24, seed=3, pickable=True, depth=True, pickable_rule="small")
    val = make_coco(tmp / "val", images=8, seed=4, pickable=True, depth=True, pickable_rule="small")
    torch.manual_seed(0)
    save_detector(DetectorNetwork(ModelSpec(), 128), tmp / "detector.safetensors")
    config = {"task": "pickability", "name": "tiny_pickability", "detector": str(tmp / "detector.safetensors"),
              "train": [str(train)], "val": str(val), "epochs": 8, "batch_size": 16, "width": 8, "threads": 1}
    return config, 8, checkpointed


def grasp_quality_setup(tmp: Path):
    from binpick.warehouse.dataset import DataGeneration
    from binpick.warehouse.generation import GenerateConfig

    data = tmp / "trials"
    DataGeneration.new(GenerateConfig(out=str(data), scenes=4, policies=[], grasp_trials=2, workers=1, image_size=128,
                                      copies=(2, 3), distractors=(0, 1), targets=["can", "procedural_box"],
                                      scenes_per_world=1, val_fraction=0.5)).run()
    config = {"task": "grasp_quality", "name": "tiny_quality", "data": str(data), "epochs": 8, "batch_size": 2, "threads": 1}
    return config, 8, checkpointed


def product_check_setup(tmp: Path):
    from binpick.warehouse.dataset import generate
    from binpick.warehouse.generation import GenerateConfig

    data = tmp / "bins"
    generate(GenerateConfig(out=str(data), scenes=4, policies=[], workers=1, image_size=128, copies=(2, 3), distractors=(1, 2),
                            domain="random", scenes_per_world=1, val_fraction=0.5, photo_views=2, seed=3))
    config = {"task": "product_check", "name": "tiny_check", "data": str(data), "epochs": 8, "batch_size": 8, "width": 8,
              "threads": 1}
    return config, 8, lambda run, stdout=(): (run / "verifier_checkpoint.safetensors").is_file()


def data_setup(tmp: Path):
    config = {"task": "data", "out": str(tmp / "bins"), "scenes": 6, "scenes_per_world": 1, "workers": 1, "image_size": 64,
              "policies": [], "copies": [2, 3], "distractors": [0, 1], "val_fraction": 0.34}
    return config, 6, lambda run, stdout=(): len(list(run.glob("scenes/*.json"))) >= 1


SETUPS = {"rl": rl_setup, "april": april_setup, "detect": detect_setup, "pickability": pickability_setup,
          "grasp_quality": grasp_quality_setup, "product_check": product_check_setup, "data": data_setup}


def run_folder(config: dict, runs: Path) -> Path | None:
    if config["task"] == "data":
        return Path(config["out"]) if Path(config["out"], "dataset.json").is_file() else None
    found = sorted(p for p in (runs / config["name"]).glob("*") if p.is_dir()) if (runs / config["name"]).is_dir() else []
    return found[-1] if found else None


def environment() -> dict[str, str]:
    """This test process's environment as it is now (imports made by earlier tests may have changed it)."""
    return {**os.environ, "OMP_NUM_THREADS": "1", "COLUMNS": "400"}


def interrupted(argv: list[str], cwd: Path, find_run, ready, group: bool = False) -> tuple[Path, str]:
    """Start ``binpick ARGV``, send SIGINT once ``ready(run_folder, stdout_lines)`` holds; it must end with exit
    code 130. Returns the run folder and its stderr."""
    import threading

    process = cli_zygote.popen(argv, cwd=cwd, env=environment(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=group, ctrl_c=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(process.stdout.readline, "")), daemon=True)
    reader.start()
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and process.poll() is None:
        run = find_run()
        if run is not None and ready(run, list(lines)):
            break
        time.sleep(0.02)
    assert process.poll() is None, f"{argv[:2]} ended before it could be interrupted:\n{process.stderr.read()[-2000:]}"
    if group:  # as a terminal's Ctrl-C: every process of the job (worker processes too) gets it
        os.killpg(process.pid, signal.SIGINT)
    else:
        process.send_signal(signal.SIGINT)
    stderr = process.stderr.read()
    process.wait(timeout=120)
    reader.join(timeout=10)
    assert process.returncode == 130, stderr[-2000:]
    return find_run(), stderr


@pytest.mark.parametrize("task", list(SETUPS))
def test_binpick_train_runs_each_job_and_resumes_it_after_ctrl_c_to_the_same_end(task, tmp_path):
    config, target, ready = SETUPS[task](tmp_path)
    path, runs = tmp_path / f"{task}.yaml", tmp_path / "runs"
    path.write_text(yaml.safe_dump(config))
    run, stderr = interrupted(["train", str(path), "--runs", str(runs)], tmp_path, lambda: run_folder(config, runs), ready)
    assert "continue with: binpick train --resume" in stderr and str(run) in " ".join(stderr.split()), stderr[-2000:]
    stopped_at = jobs.progress(run)
    assert stopped_at is None or stopped_at < target, f"{task} had finished ({stopped_at}) before Ctrl-C"
    assert jobs.job_kind_of_run(run).task == task
    if task != "data":  # a run folder names its job (a data set its manifest)
        assert yaml.safe_load((run / "config.yaml").read_text())["task"] == task
    resumed = binpick_here(["train", "--resume", run], cwd=tmp_path, env={"COLUMNS": "400"})
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"resuming {run} ({task})" in resumed.stdout.replace("\n", "")  # (folded at 80 columns)
    assert jobs.progress(run) == target, resumed.stdout[-2000:]


def test_a_config_names_its_task_once_and_a_wrong_one_is_one_line(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"task": "detct", "name": "x"}))
    with pytest.raises(ConfigError, match=r"task 'detct' is not a job \(did you mean 'detect'\?\)"):
        jobs.load_job_config(path)
    path.write_text(yaml.safe_dump({"name": "x"}))
    with pytest.raises(ConfigError, match="no 'task:' key"):
        jobs.load_job_config(path)
    path.write_text(yaml.safe_dump({"task": "rl", "total_timesteps": 100, "gp": {"bogus": 1}}))
    with pytest.raises(ConfigError, match="bogus"):
        jobs.load_job_config(path)
    kind, config = jobs.load_job_config(_write(tmp_path, {"task": "april"}), {"total_timesteps": 123, "task": "rl"})
    assert kind.task == "rl" and config.total_timesteps == 123
    result = binpick_here(["train", _write(tmp_path, {"task": "nope"})])
    assert result.returncode == 2 and result.stderr.count("\n") == 1 and "known: rl, april" in result.stderr


def _write(folder: Path, config: dict) -> Path:
    path = folder / f"{len(list(folder.glob('*.yaml')))}.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


CONFIGS = sorted(p for p in (Path(__file__).resolve().parents[1] / "configs").rglob("*.yaml") if p.parent.name not in ("rebuild", "cells"))
RECIPES = sorted((Path(__file__).resolve().parents[1] / "configs" / "rebuild").glob("*.yaml"))
CELLS = sorted((Path(__file__).resolve().parents[1] / "configs" / "cells").glob("*.yaml"))


@pytest.mark.parametrize("path", CONFIGS, ids=[p.stem for p in CONFIGS])
def test_every_config_in_the_repository_loads_as_its_job(path):
    kind, _ = jobs.load_job_config(path)
    assert path.parent.name == {"rl": "rl", "april": "april", "detect": "detection", "recurrent": "detection",
                                "pickability": "detection", "product_check": "detection", "grasp_quality": "grasping",
                                "data": "data"}[kind.task]


@pytest.mark.parametrize("path", CELLS, ids=[p.stem for p in CELLS])
def test_every_cell_file_in_the_repository_loads(path):
    from binpick.cell import Cell

    cell = Cell.load(path)  # cell files are not training jobs: read by --cell
    assert cell.name == path.stem and cell.widest > 0


@pytest.mark.parametrize("path", RECIPES, ids=[p.stem for p in RECIPES])
def test_every_rebuild_recipe_names_configs_that_load(path):
    import importlib.util
    import sys

    spec = importlib.util.spec_from_file_location("binpick_rebuild_tool", path.parents[2] / "tools" / "rebuild.py")
    rebuild = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = rebuild  # its dataclasses look their module up
    spec.loader.exec_module(rebuild)
    recipe = rebuild.Recipe.load(path.stem)
    assert recipe.steps
    for step in recipe.steps:
        if step.train:
            jobs.load_job_config(path.parents[2] / step.train)  # every config it trains loads as its job


def test_binpick_train_in_python_takes_overrides_as_keywords(tmp_path):
    import binpick

    config, _, _ = detect_setup(tmp_path)
    path = _write(tmp_path, config)
    metrics = binpick.train(path, runs=tmp_path / "runs", train__epochs=2)
    assert metrics["epochs"] == 2
    (run,) = (tmp_path / "runs" / "tiny_detect").iterdir()
    assert jobs.progress(run) == 2 and binpick.Detector.load(run).network is not None
    with pytest.raises(ConfigError, match="a resumed run keeps its config.yaml"):
        binpick.train(resume=run, train__epochs=3)


def _rl_verb(tmp: Path):
    """No periodic checkpoint before the end: only the interrupt's own keeps the steps."""
    config = {"name": "verb_rl", "total_timesteps": 400, **TINY_SAC, "checkpoint_every": 100_000}
    path = tmp / "rl.yaml"
    path.write_text(yaml.safe_dump(config))
    def started(run: Path, stdout: list[str]) -> bool:  # its first step reported (output is not a terminal: plain lines)
        return any(line.startswith("verb_rl: ") for line in stdout)

    return ["rl", "train", str(path), "--runs", str(tmp / "runs")], "rl train", 400, started


def _detect_verb(tmp: Path):
    config, target, ready = detect_setup(tmp)
    config.pop("task")
    path = tmp / "detect.yaml"
    path.write_text(yaml.safe_dump(config))
    return ["detect", "train", str(path), "--runs", str(tmp / "runs")], "train", target, ready


def _data_verb(tmp: Path):
    out = tmp / "bins"
    argv = ["data", "generate", "--out", str(out), "--scenes", "6", "--scenes-per-world", "1", "--workers", "1", "--size", "64",
            "--policies", "", "--copies", "2,3", "--distractors", "0,1"]
    return argv, "train", 6, lambda run, stdout=(): len(list(run.glob("scenes/*.json"))) >= 1


@pytest.mark.parametrize("verb", [_rl_verb, _detect_verb, _data_verb], ids=["rl-train", "detect-train", "data-generate"])
def test_ctrl_c_on_a_training_verb_keeps_its_work_and_prints_the_command_that_finishes_it(verb, tmp_path):
    argv, _, target, ready = verb(tmp_path)
    out = tmp_path / "bins" if argv[0] == "data" else None

    def find() -> Path | None:
        runs = sorted((tmp_path / "runs").glob("*/*")) if out is None else ([out] if (out / "dataset.json").is_file() else [])
        return runs[-1] if runs else None

    run, stderr = interrupted(argv, tmp_path, find, ready)
    message = " ".join(stderr.split())
    assert "continue with: binpick" in message, message
    command = message.split("continue with: ", 1)[1].split(" (the same options)")[0].split(", or ")[0].split()
    if argv[0] == "rl":  # the interrupt wrote the checkpoint: no periodic one comes before the end
        from binpick.core.runs import latest_checkpoint

        kept = int(latest_checkpoint(run / "checkpoints").name.removeprefix("ckpt-"))
        assert 0 < kept < target, kept
    else:
        kept = jobs.progress(run)
        assert kept is None or kept < target, kept
    resumed = binpick_here(command[1:] if command[1:2] != ["data"] else argv, cwd=tmp_path, env={"COLUMNS": "400"})
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert jobs.progress(run) == target


def test_ctrl_c_to_a_data_set_made_by_worker_processes_stops_them_all_at_once(tmp_path):
    """Ctrl-C reaches the workers too: they ignore it, the main process stops them (no lost world to wait for)."""
    argv, _, target, ready = _data_verb(tmp_path)
    argv[argv.index("--workers") + 1] = "2"
    argv[argv.index("--scenes") + 1] = "40"
    started = time.monotonic()
    run, stderr = interrupted(argv, tmp_path, lambda: tmp_path / "bins" if (tmp_path / "bins" / "dataset.json").is_file() else None,
                              ready, group=True)
    assert time.monotonic() - started < 120 and "continue with: binpick data generate" in " ".join(stderr.split())
    assert 1 <= jobs.progress(run) < 40


def test_policy_load_reads_what_a_run_folder_holds_and_refuses_a_run_without_a_policy(tmp_path):
    from binpick import Policy

    assert {task for task, kind in jobs.KINDS.items() if kind.policy} == {"rl", "april"}
    detector_run = tmp_path / "detector"
    detector_run.mkdir()
    (detector_run / "config.yaml").write_text("task: detect\nname: d\n")
    with pytest.raises(ConfigError, match=r"is a detect run, which has no policy to load \(runs that do: rl, april\)"):
        Policy.load(detector_run)
    with pytest.raises(ConfigError, match="neither a run folder nor a policy file"):
        Policy.load(tmp_path / "missing")
    with pytest.raises(ConfigError, match="has no env to load"):
        Policy.make_env(detector_run)


def test_a_job_whose_config_names_no_folder_makes_one_under_runs(tmp_path):
    from binpick.detection.recurrent_training import RecurrentTrainConfig
    from binpick.warehouse.dataset import open_dataset
    from binpick.warehouse.generation import GenerateConfig

    runs = tmp_path / "elsewhere"
    path = _write(tmp_path, {"task": "data", "scenes": 2, "scenes_per_world": 1, "workers": 1, "image_size": 64, "policies": [],
                             "copies": [2, 2], "distractors": [0, 0], "val_fraction": 0.5})
    result = binpick_here(["train", path, "--runs", runs], cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    (data,) = (runs / "data").iterdir()
    assert open_dataset(data)["scenes"] == 2 and jobs.job_kind_of_run(data).task == "data"
    recurrent = jobs.open_job(settings=RecurrentTrainConfig(train="a.json", val="b.json"), task="recurrent", runs=runs)
    assert recurrent.run_dir.parent == runs / "rod_recurrent" and jobs.job_kind_of_run(recurrent.run_dir).task == "recurrent"
    pinned = jobs.open_job(settings=RecurrentTrainConfig(train="a.json", val="b.json", out=str(tmp_path / "pinned")),
                           task="recurrent", runs=runs)
    assert pinned.run_dir == tmp_path / "pinned"  # a config that names its folder (a chain's next step reads it) keeps it
    assert jobs.job_kind_of_run(pinned.run_dir).task == "recurrent"  # and --resume finds what it holds
    with pytest.raises(ConfigError, match="products file .missing.yaml. does not exist"):
        jobs.open_job(settings=GenerateConfig(scenes=1, workers=1, products="missing.yaml"), task="data", runs=runs)
    assert len(list((runs / "data").iterdir())) == 1  # a data set that could not start leaves no folder


def test_the_old_policy_class_name_says_where_it_went():
    import binpick
    import binpick.rl

    for module in (binpick, binpick.rl):
        with pytest.raises(AttributeError, match="is now binpick.Policy"):
            module.TrainedPolicy  # noqa: B018

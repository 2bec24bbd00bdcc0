"""Every trainable thing as one kind of job, picked by the ``task:`` key of its config: the registry and
the one path every training entry point takes.

A :class:`JobKind` declares its task name, its config dataclass and job class (entry points,
``"module:Name"``, imported when first needed, as Gymnasium's registry names its envs: the core
imports nothing above it), the key of ``metrics.json`` that counts its progress, and how it runs on
a Ray cluster. :func:`open_job` is what ``binpick train``, the per-task commands (``binpick rl
train``, ``detect train``, ``april run`` ...), :func:`binpick.train` and ``Detector.train`` all
call: a new run from a config file (YAML, then overrides, validated once as the task's dataclass),
or a run folder resumed with its own config. :func:`run_job` runs it here or on Ray. Every run
folder records its ``task`` in its ``config.yaml``, so ``--resume`` needs no task.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from binpick.core.config import apply_overrides, from_dict, load_yaml
from binpick.core.errors import ConfigError
from binpick.core.runs import SILENT, RunCallback

TASK_KEY = "task"


@dataclass(frozen=True)
class JobKind:
    """One task: where its config dataclass and job class live, and how far a finished run came."""

    task: str
    what: str
    config: str  # "module:ConfigClass"
    job: str  # "module:JobClass" (new / resume / run)
    steps_key: str  # the key of metrics.json that counts its progress (steps, epochs, scenes)
    policy: str | None = None  # "module:function" (run folder, env id or None) -> binpick.core.policy.Policy
    env: str | None = None  # "module:function" (run folder) -> the env its policy acts in
    ray: str | None = None  # on a cluster: "train" (data-parallel Ray Train workers), "rl" (rollout or simulator actors),
    # "tasks" (a data set's worlds as Ray tasks)

    def config_class(self) -> type:
        return load_entry_point(self.config)

    def job_class(self) -> type:
        return load_entry_point(self.job)


KINDS: dict[str, JobKind] = {kind.task: kind for kind in [
    JobKind("rl", "reinforcement learning (SAC/DQN with GP + HER, A3C)", "binpick.rl.config:RLConfig",
            "binpick.rl.train:RLRun", "sim_steps", policy="binpick.rl.policy:load_run_policy",
            env="binpick.rl.policy:make_run_env", ray="rl"),
    JobKind("april", "APRiL: perception on the state, policy on the state, deployed on pixels",
            "binpick.april.config:AprilConfig", "binpick.april.pipeline:AprilRun", "policy_sim_steps",
            policy="binpick.april.policy:load_april_policy"),
    JobKind("detect", "repeated object detection (ROD, TDID)", "binpick.detection.config:DetectConfig",
            "binpick.detection.train:DetectorTrainer", "epochs", ray="train"),
    JobKind("recurrent", "the recurrent repeated-object detector (the thesis's rejected first design)",
            "binpick.detection.recurrent_training:RecurrentTrainConfig", "binpick.detection.recurrent_training:RecurrentRun",
            "images_seen"),
    JobKind("pickability", "the pickability head on detections", "binpick.detection.pickability_training:PickabilityConfig",
            "binpick.detection.pickability_training:PickabilityTrainer", "epochs", ray="train"),
    JobKind("product_check", "the learnt product check (the shop photo against a detection's window)",
            "binpick.detection.verifier_training:VerifierTrainConfig", "binpick.detection.verifier_training:VerifierTrainer",
            "epochs"),
    JobKind("grasp_quality", "the grasp-quality model on grasp trials", "binpick.grasping.training:QualityTrainConfig",
            "binpick.grasping.training:QualityTrainer", "epochs", ray="train"),
    JobKind("data", "a warehouse bin data set (scenes, labels, COCO)", "binpick.warehouse.generation:GenerateConfig",
            "binpick.warehouse.dataset:DataGeneration", "scenes", ray="tasks"),
]}


RAY_RUNNERS = {  # how a job runs on Ray, by its kind's ``ray`` (and an rl job's algorithm)
    "train": "binpick.integrations.ray.training:train_on_ray",
    "a3c": "binpick.integrations.ray.a3c:learn_on_ray",
    "sac": "binpick.integrations.ray.envs:RayVecEnv",
}


def load_entry_point(spec: str):
    """What ``"module:name"`` names, imported now (the registry names what lies above the core this way)."""
    module, _, name = spec.partition(":")
    return getattr(importlib.import_module(module), name)


def kind_of(task: Any, where: str) -> JobKind:
    """The job kind named by a config's ``task``; anything else is one line with the nearest names."""
    if isinstance(task, str) and task in KINDS:
        return KINDS[task]
    near = difflib.get_close_matches(str(task), KINDS, n=1)
    hint = f" (did you mean {near[0]!r}?)" if near else ""
    if task is None:
        raise ConfigError(f"{where}: no 'task:' key; give one of {', '.join(KINDS)}")
    raise ConfigError(f"{where}: task {task!r} is not a job{hint}; known: {', '.join(KINDS)}")


def load_job_config(path: str | Path, overrides: dict[str, Any] | None = None, task: str | None = None) -> tuple[JobKind, Any]:
    """The job kind and its validated config: ``task`` from the file (or an override), the rest
    validated once as that kind's config dataclass, overrides applied before validation. ``task``
    given (a per-task command): the file is that task's config, and its own ``task:``, where it has
    one, must agree."""
    path = Path(path)
    data = apply_overrides(load_yaml(path), overrides)
    given = data.pop(TASK_KEY, task)
    if task is not None and given != task:
        raise ConfigError(f"{path.name} is a {given!r} config; this command trains {task!r} (binpick train runs any)")
    kind = kind_of(given, path.name)
    return kind, from_dict(kind.config_class(), data, where=path.name)


def job_kind_of_run(run_dir: str | Path) -> JobKind:
    """Which job a run folder belongs to: a data set holds ``dataset.json``, APRiL ``stages.json``;
    the others hold the config they were started with, which only their own dataclass accepts."""
    run_dir = Path(run_dir)
    if (run_dir / "dataset.json").is_file():
        return KINDS["data"]
    if (run_dir / "stages.json").is_file():  # (before its first stage ends, its config.yaml tells)
        return KINDS["april"]
    if not (run_dir / "config.yaml").is_file():
        raise ConfigError(f"{str(run_dir)!r} is not a run folder (no config.yaml, stages.json or dataset.json)")
    data = load_yaml(run_dir / "config.yaml")
    if data.get(TASK_KEY) is not None:  # every run folder records it; runs from before guess below
        return kind_of(data[TASK_KEY], str(run_dir / "config.yaml"))
    fits = []
    for kind in KINDS.values():
        if kind.task == "data":
            continue
        try:
            from_dict(kind.config_class(), data, where="config.yaml")
        except (ConfigError, TypeError, ValueError):
            continue
        fits.append(kind)
    if len(fits) != 1:
        raise ConfigError(f"{str(run_dir / 'config.yaml')!r} is not the config of one job "
                          f"({'none' if not fits else ', '.join(k.task for k in fits)} accept it)")
    return fits[0]


def run_config(run_dir: str | Path, kind: JobKind) -> Any:
    """The validated config a run folder was started with (None for a data set or an APRiL run)."""
    if kind.task in ("data", "april"):
        return None
    from binpick.core.config import load_run_config

    return load_run_config(kind.config_class(), Path(run_dir))


def open_job(config: str | Path | None = None, resume: str | Path | None = None, *, task: str | None = None,
             runs: str | Path = "runs", overrides: dict[str, Any] | None = None, address: str | None = None, workers: int = 1,
             settings: Any = None):
    """The one way every training entry point starts a job: a new run of what ``config`` describes
    (``task``: what the caller trains; None: the file's ``task:`` says), its folder under ``runs``, or
    the run in ``resume`` continued with the config it was started with; ``settings``: a config already
    validated (a command that builds it from its own options, with ``task``). Refused in one line, before
    any folder is made: not exactly one of them, overrides on a resumed run, a folder that is no run (or
    another task's), a job or cluster address Ray cannot take (:func:`check_ray_job`)."""
    if settings is not None:
        if config is not None or resume is not None or task not in KINDS:
            raise ConfigError("give a validated config (settings) with its task, and no config file or --resume")
        kind = KINDS[task]
        check_ray_job(kind, address, workers, settings)
        return kind.job_class().new(settings, Path(runs))
    if (config is None) == (resume is None):
        raise ConfigError("give either a CONFIG file to start a run or --resume RUN_DIR to continue one")
    if resume is not None:
        if overrides:
            raise ConfigError("--set and other overrides apply to new runs; a resumed run keeps its config.yaml")
        kind = job_kind_of_run(resume)
        if task is not None and kind.task != task:
            raise ConfigError(f"{str(resume)!r} is a {kind.task} run; this command continues {task} runs (binpick train --resume any)")
        check_ray_job(kind, address, workers, run_config(resume, kind))
        return kind.job_class().resume(Path(resume))
    kind, settings = load_job_config(config, overrides, task)
    check_ray_job(kind, address, workers, settings)
    return kind.job_class().new(settings, Path(runs))


def kind_of_job(job) -> JobKind:
    """The kind of a job object: the task its class declares (``TASK``), else what its run folder holds."""
    task = getattr(type(job), "TASK", None)
    return KINDS[task] if task in KINDS else job_kind_of_run(job.run_dir)


def progress(run_dir: str | Path) -> int | None:
    """How far a run folder's job has come, in its own unit: simulator steps of RL (APRiL: of its
    policy stage), epochs of the trainers, scenes of a data set; None before anything is recorded."""
    from binpick.core.files import read_json

    run_dir = Path(run_dir)
    kind = job_kind_of_run(run_dir)
    if kind.task == "data":
        return len(list((run_dir / "scenes").glob("*.json")))
    if kind.task == "april":
        stages = read_json(run_dir / "stages.json") if (run_dir / "stages.json").is_file() else {}
        return (stages.get("policy") or {}).get("sim_steps")
    if not (run_dir / "metrics.json").is_file():
        return None
    value = read_json(run_dir / "metrics.json").get(kind.steps_key)
    return int(value) if isinstance(value, (int, float)) else None


ON_RAY = tuple(task for task, kind in KINDS.items() if kind.ray)  # the jobs --address takes


def check_ray_job(kind: JobKind, address: str | None, workers: int, config: Any = None) -> None:
    """One line, before any run folder is made, for a job, config or cluster address Ray cannot take
    (``config``: the job's validated config, where known)."""
    from binpick.core.config import check_range

    check_range("workers", workers, 1, 4096, integer=True)
    if address is None:
        if workers != 1:
            raise ConfigError("--workers goes with --address (a Ray cluster; local: one on this machine)")
        return
    if kind.task not in ON_RAY:
        raise ConfigError(f"--address runs {', '.join(ON_RAY)} jobs on Ray so far; a {kind.task} job trains here (without --address)")
    if kind.task == "rl":
        algorithm = getattr(config, "algorithm", "a3c")
        if algorithm not in ("a3c", "sac"):
            raise ConfigError(f"--address runs A3C's rollout workers and the sac learner's (GP + HER) simulators on Ray; "
                              f"this rl job ({algorithm}) trains here (without --address)")
        if algorithm == "a3c" and workers != 1:
            raise ConfigError("an A3C run's rollout workers are its a3c.workers, on Ray as here: --set a3c.workers=N instead of --workers")
    if kind.ray == "tasks" and workers != 1:
        raise ConfigError("a data set's scene workers are its workers setting, on Ray as here: --set workers=N instead of --workers")
    if address != "local":
        from binpick.core.cluster import check_ray_address

        check_ray_address(address)


def run_job(job, callback: RunCallback = SILENT, address: str | None = None, workers: int = 1, threads: int = 1) -> dict[str, Any]:
    """Run ``job`` here, or with ``address`` (``local``: a private cluster on this machine; ``auto``,
    ``HOST:PORT``, ``ray://HOST:PORT``) on Ray as its kind declares, with the same run folder,
    checkpoints and resume as here: trainers data-parallel on ``workers`` Ray Train workers of
    ``threads`` CPU threads each; A3C with its ``a3c.workers`` as actors; the sac learner (GP + HER)
    here, fed by ``workers`` simulator actors; a data set's worlds as Ray tasks (its ``workers`` at a time)."""
    kind = kind_of_job(job)
    check_ray_job(kind, address, workers, getattr(job, "config", None))
    if address is None:
        return job.run(callback)
    runner = job.config.algorithm if kind.ray == "rl" else kind.ray  # an rl job runs on Ray by its algorithm
    if runner == "tasks":
        callback.message(f"generating {job.run_dir} on Ray: {job.config.workers} world(s) at a time as tasks")
        return job.run(callback, address=address)
    if runner == "a3c":
        callback.message(f"training {job.run_dir} on Ray: {job.config.a3c.workers} rollout worker(s) as actors")
        return job.run(callback, learn=load_entry_point(RAY_RUNNERS["a3c"])(address))
    if runner == "sac":
        callback.message(f"training {job.run_dir} on Ray: {workers} simulator(s) as actors, the learner here")
        return job.run(callback, envs=load_entry_point(RAY_RUNNERS["sac"])(job.config, workers, None if address == "local" else address, job.env))
    callback.message(f"training {job.run_dir} on Ray: {workers} worker(s) of {threads} thread(s)")
    return load_entry_point(RAY_RUNNERS["train"])(job.run_dir, kind.job, workers, address, threads)


def train(config: str | Path | None = None, *, resume: str | Path | None = None, runs: str | Path = "runs",
          callback: RunCallback = SILENT, address: str | None = None, workers: int = 1, **overrides: Any) -> dict[str, Any]:
    """Train whatever ``config`` describes (``task:`` picks the job), or continue ``resume``'s run;
    keyword overrides use ``SECTION__KEY`` for ``SECTION.KEY`` (``train__epochs=2``, :func:`dotted`).
    With ``address``, on a Ray cluster (:func:`run_job`). Returns the job's metrics."""
    job = open_job(config, resume, runs=runs, overrides=dotted(overrides), address=address, workers=workers)
    return run_job(job, callback, address, workers)


def dotted(overrides: dict[str, Any]) -> dict[str, Any]:
    """Python keyword overrides (``train__epochs=2``) as the ``--set`` keys they stand for (``train.epochs``)."""
    return {key.replace("__", "."): value for key, value in overrides.items()}


def describe() -> list[tuple[str, str, list[str]]]:
    """(task, what it trains, its config's top-level keys) for every job kind: ``binpick train --list``."""
    return [(kind.task, kind.what, [f.name for f in dataclasses.fields(kind.config_class())]) for kind in KINDS.values()]


"""A training run made data-parallel on a Ray cluster with Ray Train (``TorchTrainer``, gloo on CPUs):
the detector, the pickability head and the grasp-quality model.

The driver makes (or finds) the run folder; each of the ``workers`` Ray Train workers opens the same
run from it (the job class's ``resume``: the latest checkpoint, or the start), joins the process group
and trains its part (``distribute()``, :mod:`binpick.core.data_parallel`). The run folder,
checkpoints, metrics, TensorBoard log and ``--resume`` are a local run's: rank 0 writes them. The workers read the data set
and write the run where the config and the run folder name them, so on several machines both must lie
on storage every machine sees at the same path (a shared filesystem); nothing passes through the driver.

A worker that dies is replaced by Ray Train (``FailureConfig``): the whole group restarts and resumes
from the last checkpoint, written after each epoch's evaluation, so no evaluation is lost or repeated.
A killed driver loses nothing either: ``binpick train --resume RUN --address ...`` continues. A worker
that stops on binpick's own error (a bad config value, a damaged data file) is not a fault a restart
mends (:data:`LASTING`): the error is kept in the run folder, the restarted group stops at once, and the
driver raises it as it was.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from binpick.core import errors
from binpick.core.errors import ConfigError, WorkerError

RESTARTS = 3  # worker-group restarts Ray Train makes after a worker dies


# errors no restart mends (a bad config value, a damaged or missing data file): kept, not retried
LASTING = (errors.ConfigError, errors.UnknownEnvError, errors.InputFileError)
WAIT_S = 6 * 3600  # how long a collective step waits for the others (rank 0 cutting pickability windows)


def _failure_file(run_dir: str | Path) -> Path:
    return Path(run_dir) / "ray" / "failed.json"


def _worker(settings: dict[str, Any]) -> None:
    """One Ray Train worker: the run from its folder, distributed, trained; rank 0 reports the metrics."""
    import torch
    import torch.distributed as dist

    from binpick.core.files import atomic_write_json

    failed = _failure_file(settings["run_dir"])
    # the group restarted after binpick's own error would fail the same way: if any worker sees the record,
    # all end here together, before any collective step of training, and the driver raises the error
    seen = torch.tensor([int(failed.is_file())])
    if dist.is_available() and dist.is_initialized():
        dist.all_reduce(seen, op=dist.ReduceOp.MAX)
    if seen.item():
        return
    try:
        _train(settings)
    except LASTING as error:
        atomic_write_json(failed, {"type": type(error).__name__, "message": str(error)})
        raise


def _train(settings: dict[str, Any]) -> None:
    import importlib

    import ray.train
    import torch

    module, _, name = settings["job"].partition(":")
    trainer = getattr(importlib.import_module(module), name).resume(Path(settings["run_dir"]))
    torch.set_num_threads(settings["threads"])
    if hasattr(trainer.config, "threads"):  # a trainer that sets its own threads takes the worker's
        from dataclasses import replace

        trainer.config = replace(trainer.config, threads=settings["threads"])
    metrics = trainer.distribute().run()
    ray.train.report({"epochs": trainer.epoch, **({"metrics": "metrics.json"} if metrics else {})})


def train_on_ray(run_dir: Path, job: str, workers: int, address: str | None = None, threads: int = 1) -> dict[str, Any]:
    """Train the run in ``run_dir`` (made by the job class's ``new``, or one to resume) on ``workers``
    Ray Train workers of ``threads`` CPU threads each; ``job`` names the job class
    (``module:Class``, one with ``resume`` and ``distribute``); ``address`` None or ``local``: a private
    cluster on this machine (127.0.0.1 only). Returns the run's metrics.json."""
    import json

    import ray.train
    from ray.train import FailureConfig, RunConfig, ScalingConfig
    from ray.train.torch import TorchConfig, TorchTrainer

    from binpick.core.cluster import start_ray

    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    failed = _failure_file(run_dir)
    failed.unlink(missing_ok=True)  # an error of an earlier session (fixed since, or this is a resume)
    started = start_ray(None if address in (None, "local") else address, workers * threads)
    try:
        trainer = TorchTrainer(
            _worker, train_loop_config={"run_dir": str(Path(run_dir).resolve()), "job": job, "threads": threads},
            torch_config=TorchConfig(backend="gloo", timeout_s=WAIT_S),
            scaling_config=ScalingConfig(num_workers=workers, use_gpu=False, resources_per_worker={"CPU": threads}),
            run_config=RunConfig(storage_path=str((Path(run_dir) / "ray").resolve()), name="train",
                                 failure_config=FailureConfig(max_failures=RESTARTS)))
        try:
            error = trainer.fit().error
        except ray.train.TrainingFailedError as failure:  # (Ray Train raises it once its restarts are spent)
            error = failure
        if failed.is_file():
            raise _as_raised(failed)
        if error is not None:
            last = (str(error).strip().splitlines() or [type(error).__name__])[-1]
            raise WorkerError(f"the Ray Train run failed: {last}; {run_dir} "
                              "resumes from its last checkpoint (binpick train --resume RUN --address ...)")
    finally:
        if started:
            ray.shutdown()
    return json.loads((Path(run_dir) / "metrics.json").read_text())


def _as_raised(failed: Path) -> Exception:
    """The binpick error a worker stopped on, as it was raised there."""
    from binpick.core.files import read_json

    record = read_json(failed)
    kind = getattr(errors, str(record.get("type")), None)
    if not (isinstance(kind, type) and issubclass(kind, errors.BinpickError)):
        kind = WorkerError
    return kind(str(record.get("message")))

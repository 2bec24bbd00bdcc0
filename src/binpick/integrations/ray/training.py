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
A killed driver loses nothing either: ``binpick train --resume RUN --address ...`` continues.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from binpick.core.errors import ConfigError

RESTARTS = 3  # worker-group restarts Ray Train makes after a worker dies


WAIT_S = 6 * 3600  # how long a collective step waits for the others (rank 0 cutting pickability windows)


def _worker(settings: dict[str, Any]) -> None:
    """One Ray Train worker: the run from its folder, distributed, trained; rank 0 reports the metrics."""
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

    from ray.train import FailureConfig, RunConfig, ScalingConfig
    from ray.train.torch import TorchConfig, TorchTrainer

    from binpick.cluster import start_ray

    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    started = start_ray(None if address in (None, "local") else address, workers * threads)
    try:
        trainer = TorchTrainer(
            _worker, train_loop_config={"run_dir": str(Path(run_dir).resolve()), "job": job, "threads": threads},
            torch_config=TorchConfig(backend="gloo", timeout_s=WAIT_S),
            scaling_config=ScalingConfig(num_workers=workers, use_gpu=False, resources_per_worker={"CPU": threads}),
            run_config=RunConfig(storage_path=str((Path(run_dir) / "ray").resolve()), name="train",
                                 failure_config=FailureConfig(max_failures=RESTARTS)))
        result = trainer.fit()
        if result.error is not None:
            raise ConfigError(f"the Ray Train run failed: {result.error}")
    finally:
        if started:
            import ray

            ray.shutdown()
    return json.loads((Path(run_dir) / "metrics.json").read_text())

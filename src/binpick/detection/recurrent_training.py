"""Training the recurrent detector (:mod:`binpick.detection.recurrent`) on the same COCO tasks, loader
and image budget as a small ROD: a loop you can read top to bottom.

The thesis's curriculum (§5.2.3): the segmentation loss alone first, then the repetition loss, then
the stop loss, while the number of roll-out steps grows. Budgets are counted in images seen, as the
ROD rows' are. A checkpoint (model, optimiser, schedule, history) is written atomically every
``checkpoint_every`` steps and at the end; a run resumes from it.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from binpick.core.config import check_range
from binpick.detection.recurrent import LossWeights, RecurrentDetector, RecurrentSpec, recurrent_loss
from binpick.core.errors import ConfigError
from binpick.core.runs import SILENT, RunCallback

CHECKPOINT = "recurrent_checkpoint.safetensors"
WEIGHTS = "recurrent.safetensors"
FORMAT_CHECKPOINT = "binpick.recurrent_detector_checkpoint"
FORMAT_WEIGHTS = "binpick.recurrent_detector"


@dataclass(frozen=True)
class RecurrentModelConfig:
    backbone: str = "tiny"
    hidden: list[int] = field(default_factory=lambda: [48, 32, 24])
    max_steps: int = 8
    latent: int = 32

    def spec(self) -> RecurrentSpec:
        spec = RecurrentSpec(self.backbone, tuple(self.hidden), self.max_steps, self.latent)
        spec.check()
        return spec


@dataclass(frozen=True)
class RecurrentLossConfig:
    stop: float = 1.0
    repetition: float = 0.1
    gamma: float = 0.9
    margin: float = 2.0

    def __post_init__(self) -> None:
        check_range("loss.stop", self.stop, 0.0, 1e3)
        check_range("loss.repetition", self.repetition, 0.0, 1e3)
        check_range("loss.gamma", self.gamma, 0.0, 1.0)
        check_range("loss.margin", self.margin, 0.0, 1e3, low_inclusive=False)

    def weights(self) -> LossWeights:
        return LossWeights(self.stop, self.repetition, self.gamma, self.margin)


@dataclass(frozen=True)
class RecurrentTrainConfig:
    train: str  # COCO annotations (binpick's or anyone's with shop photos not needed: crop queries)
    val: str
    targets: str = "all"  # all | pickable:<policy>
    name: str = "rod_recurrent"  # the run folder's name under --runs
    out: str | None = None  # None: a new run folder under --runs; a path pins the folder (a chain's next step names it)
    image_size: int = 320
    images: int = 16480  # the budget: images seen
    batch_size: int = 16
    lr: float = 1e-3
    photometric: bool = True
    val_tasks: int = 300  # val tasks scored at the end (the first ones)
    repetition_from: float = 0.2  # the budget's fraction at which the repetition loss joins
    stop_from: float = 0.4  # ... and the stop loss
    first_steps: int = 3  # roll-out steps in training at the start; they grow to model.max_steps by stop_from
    init_from: str = ""  # recurrent weights to start from (fine-tuning)
    checkpoint_every: int = 50  # optimiser steps
    threads: int = 2
    seed: int = 0
    model: RecurrentModelConfig = field(default_factory=RecurrentModelConfig)
    loss: RecurrentLossConfig = field(default_factory=RecurrentLossConfig)

    def __post_init__(self) -> None:
        check_range("image_size", self.image_size, 64, 1024, integer=True)
        check_range("images", self.images, 1, 100_000_000, integer=True)
        check_range("batch_size", self.batch_size, 1, 1024, integer=True)
        check_range("lr", self.lr, 1e-7, 1.0)
        check_range("val_tasks", self.val_tasks, 1, 1_000_000, integer=True)
        check_range("repetition_from", self.repetition_from, 0.0, 1.0)
        check_range("stop_from", self.stop_from, 0.0, 1.0)
        check_range("first_steps", self.first_steps, 1, 64, integer=True)
        check_range("checkpoint_every", self.checkpoint_every, 1, 1_000_000, integer=True)
        check_range("threads", self.threads, 1, 256, integer=True)
        if self.repetition_from > self.stop_from:
            raise ConfigError(f"repetition_from ({self.repetition_from}) must not come after stop_from ({self.stop_from}): "
                              "the thesis's curriculum brings the repetition loss in before the stop loss")
        if self.image_size % 32:
            raise ConfigError(f"image_size must be a multiple of 32 (the encoder's stride), got {self.image_size}")
        self.model.spec()


def load_recurrent(path: str | Path) -> RecurrentDetector:
    """A trained recurrent detector from its weights file (or a run folder holding one)."""
    from binpick.core import tensorfile

    path = Path(path)
    if path.is_dir():
        path = path / WEIGHTS
    tensors, meta, _ = tensorfile.load(path, FORMAT_WEIGHTS, "recurrent detector weights")
    try:
        spec = RecurrentSpec(**{**meta["spec"], "hidden": tuple(meta["spec"]["hidden"])})
        model = RecurrentDetector(spec, int(meta["image_size"]))
        model.load_state_dict(tensors)
    except (KeyError, TypeError, RuntimeError) as error:
        raise ConfigError(f"recurrent detector weights {str(path)!r} do not fit the network they describe ({str(error).splitlines()[0][:120]})") from None
    model.meta = meta
    return model.eval()


def save_recurrent(model: RecurrentDetector, path: Path, meta: dict[str, Any]) -> None:
    from binpick.core import tensorfile

    spec = asdict(model.spec)
    tensorfile.save(path, FORMAT_WEIGHTS, tensors=model.state_dict(),
                    meta={**meta, "spec": {**spec, "hidden": list(spec["hidden"])}, "image_size": model.image_size})


def recurrent_detect(model: RecurrentDetector):
    """``detect(batch)`` for :func:`binpick.detection.evaluate.collect`."""
    def detect(batch: dict) -> list[dict[str, torch.Tensor]]:
        return model.detect(batch["image"], batch["query_box"])
    return detect


def datasets(config: RecurrentTrainConfig):
    from binpick.detection.data import RepeatedInstances, TaskDataset

    train = TaskDataset(RepeatedInstances(config.train, targets=config.targets), config.image_size, "crop",
                        augment=True, seed=config.seed, photometric=config.photometric)
    val = TaskDataset(RepeatedInstances(config.val, targets=config.targets), config.image_size, "crop")
    return train, val


def evaluate_recurrent(model: RecurrentDetector, dataset, tasks: int | None = None, callback: RunCallback = SILENT) -> dict[str, Any]:
    from binpick.detection.evaluate import collect, summarise
    from binpick.detection.training_data import loader

    if tasks is not None and tasks < len(dataset):
        dataset = torch.utils.data.Subset(dataset, range(tasks))
    model.eval()
    with callback.task("recurrent: scoring", len(dataset)) as task:
        found = collect(recurrent_detect(model), loader(dataset, 8, False, 0, 0), progress=lambda n: task.update(advance=n))
    return summarise(found, model.image_size)


def _new_model(config: RecurrentTrainConfig) -> RecurrentDetector:
    """The run's network, from ``init_from``'s weights when it names a run of the same network."""
    model = RecurrentDetector(config.model.spec(), config.image_size)
    if config.init_from:
        start = load_recurrent(config.init_from)
        if start.spec != model.spec:
            raise ConfigError(f"init_from {config.init_from!r} is another network ({start.spec}); this run's model section asks for {model.spec}")
        model.load_state_dict(start.state_dict())
    return model


def _restore(checkpoint: Path, comparable: dict[str, Any], parts: dict[str, Any]) -> tuple[list[dict[str, float]], int]:
    """Model, optimiser and schedule from a checkpoint of the same configuration: ``(history, step)``."""
    from binpick.core import tensorfile
    from binpick.core.errors import InputFileError

    _, meta, state = tensorfile.load(checkpoint, FORMAT_CHECKPOINT, "recurrent checkpoint")
    if meta.get("config") != json.loads(json.dumps(comparable)):
        raise ConfigError(f"{checkpoint} was written by another configuration; give another out or delete it")
    where = f"recurrent checkpoint {str(checkpoint)!r}"
    tensorfile.restore(parts, state or {}, where)
    try:
        return list(meta["history"]), int(meta["step"])
    except (KeyError, TypeError, ValueError):
        raise InputFileError(f"{where} is damaged: no step or history in its metadata") from None


def _train_step(model: RecurrentDetector, optimiser, batch: dict[str, Any], config: RecurrentTrainConfig, progress: float,
                weights) -> tuple[int, dict[str, torch.Tensor]]:
    """One gradient step on a batch, rolled out for as many steps as the curriculum allows at ``progress``
    (the share of the budget done): ``(steps, losses)``."""
    steps = config.model.max_steps if progress >= config.stop_from else \
        min(config.model.max_steps, config.first_steps + int((config.model.max_steps - config.first_steps) * progress / max(config.stop_from, 1e-9)))
    # no step beyond the batch's most copies and one to learn to stop: the roll-out is the cost
    steps = min(steps, 1 + max(len(t) for t in batch["targets"]))
    model.train()
    out = model(batch["image"], batch["query_box"], steps)
    losses = recurrent_loss(model, out, batch["targets"], batch["other_products"], weights,
                            use_stop=progress >= config.stop_from, use_repetition=progress >= config.repetition_from)
    optimiser.zero_grad()
    losses["total"].backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
    optimiser.step()
    return steps, losses


def train_recurrent(config: RecurrentTrainConfig, callback: RunCallback = SILENT) -> dict[str, Any]:
    """Train (or resume) to the image budget; save ``<out>/recurrent.safetensors`` and ``metrics.json``."""
    from binpick.core import tensorfile
    from binpick.detection.data import collate

    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    train_set, val_set = datasets(config)
    if config.out is None:
        raise ConfigError("train_recurrent writes to config.out: give one (binpick train makes a run folder instead)")
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    model = _new_model(config)
    optimiser = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=1e-4)
    total_steps = max(1, config.images // config.batch_size)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimiser, config.lr, total_steps=total_steps, pct_start=0.05)
    history: list[dict[str, float]] = []
    step = 0
    checkpoint = out / CHECKPOINT
    # what the weights depend on (not threads, checkpointing or scoring) must match to resume
    comparable = {k: v for k, v in asdict(config).items() if k not in ("threads", "checkpoint_every", "val_tasks", "out", "name")}
    if checkpoint.is_file():
        history, step = _restore(checkpoint, comparable, {"model": model, "optimiser": optimiser, "schedule": schedule})

    def save_checkpoint() -> None:
        tensorfile.save(checkpoint, FORMAT_CHECKPOINT, meta={"config": comparable, "step": step, "history": history},
                        state={"model": model.state_dict(), "optimiser": optimiser.state_dict(), "schedule": schedule.state_dict()})

    weights = config.loss.weights()
    steps_per_epoch = len(train_set) // config.batch_size  # whole batches only, so every step sees batch_size images
    if steps_per_epoch == 0:
        raise ConfigError(f"batch_size {config.batch_size} is larger than the {len(train_set)} training tasks in {config.train}")
    started, sums, count = time.perf_counter(), {}, 0
    with callback.task("recurrent: images", total_steps * config.batch_size, done=step * config.batch_size) as task:
        while step < total_steps:
            epoch, offset = divmod(step, steps_per_epoch)
            train_set.set_epoch(epoch)
            # each epoch's order comes from the seed, so a resumed run skips the batches it saw
            order = torch.randperm(len(train_set), generator=torch.Generator().manual_seed(config.seed + epoch)).tolist()
            batches = torch.utils.data.DataLoader(torch.utils.data.Subset(train_set, order[offset * config.batch_size:]),
                                                  batch_size=config.batch_size, shuffle=False, drop_last=True, collate_fn=collate)
            for batch in batches:
                if step >= total_steps:
                    break
                steps, losses = _train_step(model, optimiser, batch, config, step / total_steps, weights)
                schedule.step()
                step += 1
                count += 1
                for key, value in losses.items():
                    sums[key] = sums.get(key, 0.0) + float(value.detach())
                task.update(advance=config.batch_size)
                if step % config.checkpoint_every == 0 or step == total_steps:
                    row = {"images_seen": step * config.batch_size, "steps": steps,
                           **{key: round(value / count, 4) for key, value in sums.items()},
                           "seconds": round(time.perf_counter() - started, 1)}
                    history.append(row)
                    sums, count, started = {}, 0, time.perf_counter()
                    save_checkpoint()
                    callback.message(json.dumps(row))
    val = evaluate_recurrent(model, val_set, config.val_tasks, callback)
    metrics = {"val": {k: v for k, v in val.items() if k not in ("pr", "ap50_by_scale", "gt_by_scale")},
               "images_seen": step * config.batch_size, "history": history}
    save_recurrent(model, out / WEIGHTS, {"trained_on": config.train, "targets": config.targets, "images_seen": step * config.batch_size,
                                          "val_ap50": val["ap50"]})
    from binpick.core.files import atomic_write_text

    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=2))
    return metrics


class RecurrentRun:
    """The recurrent detector's training as a job (:class:`binpick.core.runs.Job`): a new run folder under
    ``runs`` (or the config's ``out``, where it pins one) holding the weights, ``metrics.json``, the
    checkpoint and the config it was started with."""

    TASK = "recurrent"  # its kind of job (binpick.core.jobs)

    def __init__(self, config: RecurrentTrainConfig) -> None:
        self.config, self.run_dir = config, Path(config.out)

    @classmethod
    def new(cls, config: RecurrentTrainConfig, runs: Path = Path("runs")) -> RecurrentRun:
        """A new run folder under ``runs/<name>/``; a config whose ``out`` names a folder goes there (a run
        there with another config is refused when it resumes)."""
        from dataclasses import replace

        from binpick.core.runs import new_run, pinned_run

        if config.out is None:
            return cls(replace(config, out=str(new_run(Path(runs), config, cls.TASK))))
        pinned_run(config.out, config, cls.TASK)
        return cls(config)

    @classmethod
    def resume(cls, run_dir: Path) -> RecurrentRun:
        """Continue the run in ``run_dir`` with the config it was started with."""
        from binpick.core.config import load_run_config

        from dataclasses import replace

        return cls(replace(load_run_config(RecurrentTrainConfig, run_dir), out=str(run_dir)))

    def run(self, callback: RunCallback = SILENT) -> dict[str, Any]:
        return train_recurrent(self.config, callback)

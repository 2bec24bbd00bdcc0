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

from binpick.core import tensorfile
from binpick.core.config import check_range
from binpick.core.data_parallel import ALONE
from binpick.core.epochs import EpochTrainer
from binpick.core.files import atomic_write_text
from binpick.detection.data import collate
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


class RecurrentTrainer(EpochTrainer):
    """Training to the image budget on the epoch loop every supervised job shares: an epoch is the rest of
    its batches (each epoch's order from the seed, so a resumed run skips what it saw), a row of the history
    and a checkpoint every ``checkpoint_every`` steps within it; the val set is scored once, at the end
    (the roll-out is what costs)."""

    unset = float("-inf")  # no epoch is judged: nothing picks a best

    def __init__(self, config: RecurrentTrainConfig, run_dir: Path) -> None:
        torch.manual_seed(config.seed)
        torch.set_num_threads(config.threads)
        self.config, self.run_dir, self.group = config, Path(run_dir), ALONE
        self.train_set, self.val_set = datasets(config)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.model = _new_model(config)
        self.optimiser = torch.optim.AdamW(self.model.parameters(), lr=config.lr, weight_decay=1e-4)
        self.total_steps = max(1, config.images // config.batch_size)
        self.schedule = torch.optim.lr_scheduler.OneCycleLR(self.optimiser, config.lr, total_steps=self.total_steps, pct_start=0.05)
        self.steps_per_epoch = len(self.train_set) // config.batch_size  # whole batches only: every step sees batch_size images
        if self.steps_per_epoch == 0:
            raise ConfigError(f"batch_size {config.batch_size} is larger than the {len(self.train_set)} training tasks in {config.train}")
        # what the weights depend on (not threads, checkpointing, scoring, the folder or its name) must match to resume
        self.comparable = {k: v for k, v in asdict(config).items() if k not in ("threads", "checkpoint_every", "val_tasks", "out", "name")}
        self.history, self.step, self.best = [], 0, self.unset
        if (self.run_dir / CHECKPOINT).is_file():
            self.history, self.step = _restore(self.run_dir / CHECKPOINT, self.comparable,
                                               {"model": self.model, "optimiser": self.optimiser, "schedule": self.schedule})
        self.epoch = self.step // self.steps_per_epoch
        self.callback = SILENT

    def run(self, callback: RunCallback = SILENT) -> dict[str, Any]:
        config, self.callback = self.config, callback
        self.sums, self.count, self.started = {}, 0, time.perf_counter()
        self.run_epochs(callback, "recurrent: images", -(-self.total_steps // self.steps_per_epoch))
        images = self.step * config.batch_size
        val = evaluate_recurrent(self.model, self.val_set, config.val_tasks, callback)
        metrics = {"val": {k: v for k, v in val.items() if k not in ("pr", "ap50_by_scale", "gt_by_scale")},
                   "images_seen": images, "history": self.history}
        save_recurrent(self.model, self.run_dir / WEIGHTS, {"trained_on": config.train, "targets": config.targets,
                                                             "images_seen": images, "val_ap50": val["ap50"]})
        atomic_write_text(self.run_dir / "metrics.json", json.dumps(metrics, indent=2))
        return metrics

    def progress(self, epochs: int) -> tuple[int, int]:
        return self.total_steps * self.config.batch_size, self.step * self.config.batch_size

    def train_epoch(self) -> dict[str, Any]:
        config = self.config
        offset = self.step - self.epoch * self.steps_per_epoch  # batches of this epoch a resumed run already saw
        self.train_set.set_epoch(self.epoch)
        order = torch.randperm(len(self.train_set), generator=torch.Generator().manual_seed(config.seed + self.epoch)).tolist()
        batches = torch.utils.data.DataLoader(torch.utils.data.Subset(self.train_set, order[offset * config.batch_size:]),
                                              batch_size=config.batch_size, shuffle=False, drop_last=True, collate_fn=collate)
        weights = config.loss.weights()
        for batch in batches:
            if self.step >= self.total_steps:
                break
            steps, losses = _train_step(self.model, self.optimiser, batch, config, self.step / self.total_steps, weights)
            self.schedule.step()
            self.step += 1
            self.count += 1
            for key, value in losses.items():
                self.sums[key] = self.sums.get(key, 0.0) + float(value.detach())
            self.task.update(self.step * config.batch_size)
            if self.step % config.checkpoint_every == 0 or self.step == self.total_steps:
                self._record(steps)
        return {}

    def _record(self, steps: int) -> None:
        """A row of the history (mean losses since the last row), TensorBoard, a checkpoint."""
        row = {"images_seen": self.step * self.config.batch_size, "steps": steps,
               **{key: round(value / self.count, 4) for key, value in self.sums.items()},
               "seconds": round(time.perf_counter() - self.started, 1)}
        self.history.append(row)
        for key, value in self.sums.items():
            self.writer.add_scalar(f"loss/{key}", value / self.count, self.step)
        self.sums, self.count, self.started = {}, 0, time.perf_counter()
        self.checkpoint()
        self.callback.message(json.dumps(row))

    def evaluate(self) -> dict[str, Any]:
        return {}

    def recorded(self, row: dict[str, Any]) -> dict[str, Any] | None:
        return None  # the history holds a row per checkpoint, not per epoch

    def status(self, row: dict[str, Any]) -> str:
        return f"epoch {self.epoch}"

    def save_best(self, row: dict[str, Any]) -> None:
        """Nothing: the model at the end of the budget is the one saved."""

    def checkpoint(self) -> None:
        tensorfile.save(self.run_dir / CHECKPOINT, FORMAT_CHECKPOINT,
                        meta={"config": self.comparable, "step": self.step, "history": self.history},
                        state={"model": self.model.state_dict(), "optimiser": self.optimiser.state_dict(),
                               "schedule": self.schedule.state_dict()})


def train_recurrent(config: RecurrentTrainConfig, callback: RunCallback = SILENT) -> dict[str, Any]:
    """Train (or resume) to the image budget; save ``<out>/recurrent.safetensors`` and ``metrics.json``."""
    if config.out is None:
        raise ConfigError("train_recurrent writes to config.out: give one (binpick train makes a run folder instead)")
    return RecurrentTrainer(config, Path(config.out)).run(callback)


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

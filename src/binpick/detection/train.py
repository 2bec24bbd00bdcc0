"""Training a repeated-object detector, top to bottom (CleanRL style): data, anchors, model, loop,
evaluation, checkpoints.

A run folder ``runs/<name>/<time>/`` holds ``config.yaml``, TensorBoard events (``tb/``), atomic
checkpoints (``checkpoints/``, one per epoch: a kill loses at most the epoch in progress),
``metrics.json`` and the final ``model.safetensors`` that ``binpick detect eval/predict`` read.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
import yaml

from binpick import tensorfile
from binpick.config import load_run_config, to_dict
from binpick.detection.config import DetectConfig
from binpick.detection.data import RepeatedInstances, TaskDataset, collate, trained_products
from binpick.detection.evaluate import collect, summarise
from binpick.detection.losses import rod_loss
from binpick.detection.model import ANCHORS_PER_LEVEL, DetectorNetwork, ModelSpec
from binpick.detection.ops import box_iou
from binpick.errors import ConfigError, InputFileError
from binpick.files import atomic_write_json, require_fields
from binpick.runs import SILENT, RunCallback, Task, commit_checkpoint, latest_checkpoint, new_run_dir


# ---------------------------------------------------------------------- weights on disk
FORMAT = "binpick-detector-2"  # safetensors + JSON; "binpick-detector-1" was a torch pickle (.pt)
WEIGHTS_FILE = "model.safetensors"
CHECKPOINT_FORMAT = "binpick-detector-checkpoint-1"


def save_detector(model: DetectorNetwork, path: Path, extra: dict[str, Any] | None = None, half: bool = False) -> None:
    """Write weights (safetensors) and what rebuilds the network (JSON) atomically: a crash leaves the
    previous file or the new one. ``half`` stores float16 weights (half the size; loading turns them
    back into float32). ``extra`` must be JSON data (config, products trained on, ...)."""
    weights = model.state_dict()
    if half:
        weights = {k: v.half() if v.is_floating_point() and k != "anchors" else v for k, v in weights.items()}
    meta = {"spec": asdict(model.spec), "image_size": model.image_size, "query_size": model.query_size, **(extra or {})}
    tensorfile.save(path, FORMAT, tensors=weights, meta=meta)


def _weights_path(path: Path) -> Path:
    """A file as given; a run folder's ``model.safetensors`` (or an older run's ``model.pt``)."""
    if path.is_dir():
        for name in (WEIGHTS_FILE, "model.pt"):
            if (path / name).is_file():
                return path / name
        raise InputFileError(f"no detector weights in {str(path)!r} (no {WEIGHTS_FILE}): is the run finished?")
    if not path.is_file():
        raise InputFileError(f"no detector weights at {str(path)!r}")
    return path


def _read_detector_file(path: Path) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Weights and metadata; older ``.pt`` files only through ``torch.load(weights_only=True)``."""
    if not tensorfile.is_safetensors(path):  # an older binpick .pt: plain tensors only
        data = tensorfile.load_legacy_torch(path, "detector weights")
        if not isinstance(data, dict) or data.get("format") != "binpick-detector-1":
            raise InputFileError(f"{str(path)!r} is not a binpick detector checkpoint")
        weights = data.get("weights")
        meta = {k: v for k, v in data.items() if k not in ("weights", "format")}
    else:
        weights, meta, _ = tensorfile.load(path, FORMAT, "detector weights")
    where = f"detector weights {str(path)!r}"
    require_fields({"weights": weights, **meta}, {"weights": dict, "spec": dict, "image_size": int}, where)
    return weights, meta


def load_detector(path: str | Path) -> DetectorNetwork:
    """A detector saved by :func:`save_detector` (or a run folder holding ``model.safetensors``)."""
    path = _weights_path(Path(path))
    weights, meta = _read_detector_file(path)
    try:
        spec = ModelSpec(**{**meta["spec"], "scales": tuple(meta["spec"]["scales"])})
        model = DetectorNetwork(spec, int(meta["image_size"]), int(meta.get("query_size", 96)))
    except (TypeError, KeyError, ValueError) as error:
        raise InputFileError(f"detector weights {str(path)!r} describe no valid network ({error})") from None
    try:
        missing, unexpected = model.load_state_dict(weights, strict=False)
    except RuntimeError:  # tensors of other shapes
        missing, unexpected = ["(shapes differ)"], []
    if missing or unexpected:
        raise InputFileError(f"{str(path)!r} holds weights of another architecture "
                             f"({len(missing)} missing, {len(unexpected)} unexpected tensors)")
    model.trained_config = meta.get("config") or {}
    model.trained_products = meta.get("trained_products")
    model.eval()
    return model


# ---------------------------------------------------------------------- anchors
def kmeans_anchors(sizes: np.ndarray, clusters: int = 3 * ANCHORS_PER_LEVEL, iterations: int = 50, seed: int = 0) -> np.ndarray:
    """YOLOv3's anchor priors: k-means of box sizes (w, h) under the 1 - IoU distance, smallest first."""
    rng = np.random.default_rng(seed)
    sizes = np.asarray(sizes, dtype=np.float64)
    if len(sizes) < clusters:
        raise ConfigError(f"need at least {clusters} boxes to fit anchors, got {len(sizes)}")
    centres = sizes[rng.choice(len(sizes), clusters, replace=False)]
    for _ in range(iterations):
        boxes = torch.tensor(np.c_[np.zeros((len(sizes), 2)), sizes])
        anchors = torch.tensor(np.c_[np.zeros((clusters, 2)), centres])
        nearest = box_iou(boxes, anchors).argmax(1).numpy()
        updated = np.array([np.median(sizes[nearest == k], axis=0) if np.any(nearest == k) else centres[k] for k in range(clusters)])
        if np.allclose(updated, centres):
            break
        centres = updated
    return centres[np.argsort(centres.prod(1))]


def fit_anchors(dataset: TaskDataset) -> torch.Tensor:
    """Anchors from the training boxes, in the pixels of the resized images the model sees."""
    from PIL import Image

    with Image.open(dataset.source.tasks[0].file) as image:
        scale = dataset.size / float(max(image.size))  # a data set's images share one size
    sizes = [a["bbox"][2:4] for task in dataset.source.tasks for a in task.annotations]
    return torch.tensor(kmeans_anchors(np.array(sizes) * scale), dtype=torch.float32).view(3, ANCHORS_PER_LEVEL, 2)


# ---------------------------------------------------------------------- the run
def make_datasets(config: DetectConfig) -> tuple[TaskDataset, TaskDataset]:
    data = config.data
    train_source = RepeatedInstances(data.train, data.images, data.targets, exclude_categories=data.exclude_categories)
    val_source = RepeatedInstances(data.val, data.images, data.targets)
    query_mode = config.model.query
    train = TaskDataset(train_source, data.image_size, query_mode, data.query_size, augment=data.augment, seed=config.train.seed)
    val = TaskDataset(val_source, data.image_size, query_mode, data.query_size, augment=False, seed=config.train.seed + 1)
    return train, val


def loader(dataset: TaskDataset, batch_size: int, shuffle: bool, workers: int, seed: int) -> torch.utils.data.DataLoader:
    generator = torch.Generator().manual_seed(seed)
    return torch.utils.data.DataLoader(dataset, batch_size=batch_size, shuffle=shuffle, num_workers=workers,
                                       collate_fn=collate, generator=generator, persistent_workers=False)


def detector_detect(model: DetectorNetwork) -> Callable[[dict], list[dict[str, torch.Tensor]]]:
    def detect(batch: dict) -> list[dict[str, torch.Tensor]]:
        results, _ = model.detect(batch["image"], batch["query_box"], batch["query_image"])
        return results
    return detect


def evaluate_model(model: DetectorNetwork, dataset: TaskDataset, batch_size: int = 8, progress=None) -> dict[str, Any]:
    model.eval()
    batches = loader(dataset, batch_size, shuffle=False, workers=0, seed=0)
    return summarise(collect(detector_detect(model), batches, progress), dataset.size)


class DetectorTrainer:
    """``DetectorTrainer.new(config, runs).run()`` trains a new run; ``DetectorTrainer.resume(RUN)``
    continues one from its latest checkpoint (see :class:`binpick.runs.Job`)."""

    def __init__(self, config: DetectConfig, resume: Path | None = None, runs: Path = Path("runs")) -> None:
        self.config = config
        torch.manual_seed(config.train.seed)
        torch.set_num_threads(config.train.threads)
        self.train_set, self.val_set = make_datasets(config)  # bad data: one line, before any folder exists
        self.model = DetectorNetwork(config.model.spec(), config.data.image_size, config.data.query_size)
        self.optimizer = torch.optim.AdamW(self.model.parameters(), lr=config.train.lr, weight_decay=config.train.weight_decay)
        self.steps_per_epoch = -(-len(self.train_set) // config.train.batch_size)
        self.total_steps = self.steps_per_epoch * config.train.epochs
        self.epoch, self.step, self.history = 0, 0, []
        checkpoint = latest_checkpoint(resume / "checkpoints") if resume is not None else None
        if checkpoint is not None:
            self._load_checkpoint(checkpoint)
        else:
            self.model.anchors.copy_(fit_anchors(self.train_set))
        if config.train.fast_cpu:
            self.model.to(memory_format=torch.channels_last)
        self.run_dir = resume if resume is not None else new_run_dir(Path(runs), config.name, yaml.safe_dump(to_dict(config), sort_keys=False))

    @classmethod
    def new(cls, config: DetectConfig, runs: Path = Path("runs")) -> DetectorTrainer:
        """A new run folder under ``runs/<name>/``, made once the data are known to be good."""
        return cls(config, runs=runs)

    @classmethod
    def resume(cls, run_dir: Path) -> DetectorTrainer:
        """Continue ``run_dir`` from its latest checkpoint (from the start if it has none)."""
        return cls(load_run_config(DetectConfig, run_dir), resume=Path(run_dir))

    def _load_checkpoint(self, checkpoint: Path) -> None:
        """Model, optimiser, epoch, step and history; any damage is one line naming the file."""
        if (checkpoint / "state.safetensors").is_file() or not (checkpoint / "state.pt").is_file():
            path = checkpoint / "state.safetensors"
            _, meta, state = tensorfile.load(path, CHECKPOINT_FORMAT, "detector checkpoint")
            state = state or {}
        else:  # written before binpick stored checkpoints as safetensors
            path = checkpoint / "state.pt"
            state = meta = tensorfile.load_legacy_torch(path, "detector checkpoint")
            if not isinstance(state, dict):
                raise InputFileError(f"detector checkpoint {str(path)!r} is damaged: not a mapping")
        where = f"detector checkpoint {str(path)!r}"
        require_fields(meta, {"epoch": int, "step": int, "history": list}, where)
        require_fields(state, {"model": dict, "optimizer": dict}, where)
        tensorfile.restore({"model": self.model, "optimizer": self.optimizer}, state, where)
        self.epoch, self.step, self.history = meta["epoch"], meta["step"], meta["history"]

    def forward(self, batch: dict) -> dict:
        """The model's outputs in float32; with ``fast_cpu`` computed in bfloat16, channels-last."""
        fast = self.config.train.fast_cpu
        images = batch["image"].contiguous(memory_format=torch.channels_last) if fast else batch["image"]
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=fast):
            out = self.model(images, batch["query_box"], batch["query_image"])
        return {"raw": [r.float() for r in out["raw"]], "heatmaps": [None if h is None else h.float() for h in out["heatmaps"]]}

    def learning_rate(self) -> float:
        """Linear warm-up, then cosine decay to 5% of ``lr``."""
        train = self.config.train
        if self.step < train.warmup_steps:
            return train.lr * (self.step + 1) / train.warmup_steps
        progress = min(1.0, (self.step - train.warmup_steps) / max(1, self.total_steps - train.warmup_steps))
        return train.lr * (0.05 + 0.95 * 0.5 * (1 + np.cos(np.pi * progress)))

    def run(self, callback: RunCallback = SILENT) -> dict[str, Any]:
        with callback.task(self.config.name, self.total_steps, self.step) as task:
            metrics = self._train(task)
        callback.message(f"wrote {self.run_dir / WEIGHTS_FILE}")
        return metrics

    def _train(self, task: Task) -> dict[str, Any]:
        from torch.utils.tensorboard import SummaryWriter

        config, weights = self.config, self.config.loss
        writer = SummaryWriter(str(self.run_dir / "tb"))
        status = ""
        try:
            while self.epoch < config.train.epochs:
                self.train_set.set_epoch(self.epoch)
                self.model.train()
                sums = {}
                for batch in loader(self.train_set, config.train.batch_size, True, config.train.workers, config.train.seed + self.epoch):
                    for group in self.optimizer.param_groups:
                        group["lr"] = self.learning_rate()
                    out = self.forward(batch)
                    losses = rod_loss(self.model, out, batch["targets"], weights)
                    self.optimizer.zero_grad(set_to_none=True)
                    losses["total"].backward()
                    torch.nn.utils.clip_grad_norm_(self.model.parameters(), 10.0)
                    self.optimizer.step()
                    self.step += 1
                    for key, value in losses.items():
                        sums[key] = sums.get(key, 0.0) + float(value.detach())
                        writer.add_scalar(f"loss/{key}", float(value.detach()), self.step)
                    task.update(self.step, status=f"epoch {self.epoch + 1}/{config.train.epochs} {status}")
                self.epoch += 1
                record = {"epoch": self.epoch, "step": self.step,
                          **{f"loss_{k}": v / self.steps_per_epoch for k, v in sums.items()}}
                if self.epoch % config.train.eval_every == 0 or self.epoch == config.train.epochs:
                    metrics = evaluate_model(self.model, self.val_set, config.train.batch_size)
                    record |= {k: metrics[k] for k in ("ap50", "map", "ap50_all", "ap50_unpickable")}
                    for key in ("ap50", "map", "ap50_all", "ap50_unpickable"):
                        if metrics[key] is not None:
                            writer.add_scalar(f"val/{key}", metrics[key], self.epoch)
                self.history.append(record)
                self._checkpoint()
                if record.get("ap50") is not None:
                    status = f"· val AP50 {record['ap50']:.3f}"
        finally:
            writer.close()
        save_detector(self.model, self.run_dir / WEIGHTS_FILE,
                      {"config": to_dict(config), "trained_products": trained_products(config.data.train)})
        final = self.history[-1] if self.history else {}
        metrics = {"name": config.name, "epochs": self.epoch, "steps": self.step, "final": final, "history": self.history}
        atomic_write_json(self.run_dir / "metrics.json", metrics)
        return metrics

    def _checkpoint(self) -> None:
        def write(folder: Path) -> None:
            tensorfile.save(folder / "state.safetensors", CHECKPOINT_FORMAT,
                            state={"model": self.model.state_dict(), "optimizer": self.optimizer.state_dict()},
                            meta={"epoch": self.epoch, "step": self.step, "history": self.history})

        commit_checkpoint(self.run_dir / "checkpoints", self.epoch, write)

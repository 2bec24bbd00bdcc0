"""Training a repeated-object detector, top to bottom (CleanRL style): data, anchors, model, loop,
evaluation, checkpoints.

A run folder ``runs/<name>/<time>/`` holds ``config.yaml``, TensorBoard events (``tb/``), atomic
checkpoints (``checkpoints/``, at each epoch's end and every ``train.checkpoint_minutes`` within one: a kill
loses minutes; a resumed epoch trains on the batches it had not reached),
``metrics.json`` and the final ``model.safetensors`` that ``binpick detect eval/predict`` read.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from binpick.core import tensorfile
from binpick.core.config import load_run_config, to_dict
from binpick.core.data_parallel import ALONE, Group
from binpick.core.epochs import EpochTrainer
from binpick.detection.config import DetectConfig
from binpick.detection.data import TaskDataset, collate
from binpick.detection.evaluate import collect, summarise
from binpick.detection.losses import rod_loss
from binpick.detection.training_data import fit_anchors, learnt_products, loader, make_datasets, trained_domains
from binpick.detection.model import DetectorNetwork
from binpick.detection.weights_file import CHECKPOINT_FORMAT, WEIGHTS_FILE, load_detector, save_detector
from binpick.core.errors import ConfigError, InputFileError
from binpick.core.files import atomic_write_json, require_fields
from binpick.core.runs import (
    SILENT,
    RunCallback,
    commit_checkpoint,
    latest_checkpoint,
    new_run,
)


def detector_detect(model: DetectorNetwork) -> Callable[[dict], list[dict[str, torch.Tensor]]]:
    def detect(batch: dict) -> list[dict[str, torch.Tensor]]:
        device = model.anchors.device
        depth = batch["depth"].to(device) if "depth" in batch else None
        results, _ = model.detect(batch["image"].to(device), batch["query_box"].to(device), batch["query_image"].to(device),
                                  depth=depth)
        return [{k: v.cpu() for k, v in r.items()} for r in results]
    return detect


def evaluate_model(model: DetectorNetwork, dataset: TaskDataset, batch_size: int = 8, progress=None) -> dict[str, Any]:
    model.eval()
    batches = loader(dataset, batch_size, shuffle=False, workers=0, seed=0)
    return summarise(collect(detector_detect(model), batches, progress), dataset.size)


class DetectorTrainer(EpochTrainer):
    """``DetectorTrainer.new(config, runs).run()`` trains a new run; ``DetectorTrainer.resume(RUN)``
    continues one from its latest checkpoint (see :class:`binpick.core.runs.Job`). The epoch loop is the
    one every supervised job shares (:class:`~binpick.core.epochs.EpochTrainer`); the detector adds
    checkpoints within an epoch, a time budget, evaluation every ``eval_every`` epochs and early stopping."""

    TASK = "detect"  # its kind of job (binpick.core.jobs)
    metric = "ap50"
    unset = float("-inf")  # an epoch not evaluated, or with no AP50, is never the best
    scalars = {key: f"val/{key}" for key in ("ap50", "map", "ap50_all", "ap50_unpickable")}

    def __init__(self, config: DetectConfig, resume: Path | None = None, runs: Path = Path("runs")) -> None:
        self.config = config
        torch.manual_seed(config.train.seed)
        torch.set_num_threads(config.train.threads)
        self.train_set, self.val_set = make_datasets(config)  # bad data: one line, before any folder exists
        self.model = DetectorNetwork(config.model.spec(), config.data.image_size, config.data.query_size)
        self.optimizer = torch.optim.AdamW(self.model.parameters(), lr=config.train.lr, weight_decay=config.train.weight_decay)
        self.steps_per_epoch = -(-len(self.train_set) // config.train.batch_size)
        self.total_steps = self.steps_per_epoch * config.train.epochs
        self.time_used = 0.0  # of train.max_minutes in this invocation (the learning rate anneals by it too)
        self.group = ALONE  # data-parallel training (distribute()): this process's place among others
        self.epoch, self.step, self.history = 0, 0, []
        self.resumed_batches, self.resumed_sums = 0, {}  # a checkpoint within an epoch: batches trained, loss sums
        checkpoint = latest_checkpoint(resume / "checkpoints") if resume is not None else None
        if checkpoint is not None:
            self._load_checkpoint(checkpoint)
        elif config.train.init_from:
            self._start_from(Path(config.train.init_from))
        else:
            self.model.anchors.copy_(fit_anchors(self.train_set))
        self.device = torch.device(config.train.device)
        if self.device.type == "cuda" and not torch.cuda.is_available():
            raise ConfigError("train.device is cuda but torch sees no GPU; use train.device=cpu")
        self.model.to(self.device)
        self.optimizer.load_state_dict(self.optimizer.state_dict())  # moves optimiser state to the model's device
        if config.train.fast_cpu or self.device.type == "cuda":
            self.model.to(memory_format=torch.channels_last)
        self.best = max((h["ap50"] for h in self.history if h.get("ap50") is not None), default=-1.0)
        self.run_dir = resume if resume is not None else new_run(Path(runs), config, self.TASK)

    @classmethod
    def new(cls, config: DetectConfig, runs: Path = Path("runs")) -> DetectorTrainer:
        """A new run folder under ``runs/<name>/``, made once the data are known to be good."""
        return cls(config, runs=runs)

    @classmethod
    def resume(cls, run_dir: Path) -> DetectorTrainer:
        """Continue ``run_dir`` from its latest checkpoint (from the start if it has none)."""
        return cls(load_run_config(DetectConfig, run_dir), resume=Path(run_dir))

    def distribute(self) -> DetectorTrainer:
        """Train as one of the processes of a ``torch.distributed`` group (Ray Train starts them, gloo
        on CPUs; :mod:`binpick.core.data_parallel`): every process starts from rank 0's weights, reads
        its shard of each epoch (a :class:`~torch.utils.data.DistributedSampler` on the run's seed) in
        batches of ``batch_size / world`` and averages its gradients with the others', so a step sees
        the config's batch size and the learning-rate schedule is the single process's. Rank 0 alone
        evaluates and writes (checkpoints, TensorBoard, weights); the others follow its decision to stop."""
        self.group = Group.joined()
        self.group.split(self.config.train.batch_size, "train.batch_size")
        self.group.share([*self.model.parameters(), *self.model.buffers()])
        return self

    def _loader(self, skip: int = 0) -> torch.utils.data.DataLoader:
        """This process's batches of the epoch (all of them, or its shard in distributed training) in an
        order drawn from the seed and the epoch, after the first ``skip`` batches (those a checkpoint
        within the epoch already trained on: a resumed epoch sees the rest, no batch twice)."""
        train = self.config.train
        group = self.group
        if group.world == 1:
            order = torch.randperm(len(self.train_set), generator=torch.Generator().manual_seed(train.seed + self.epoch)).tolist()
            return torch.utils.data.DataLoader(self.train_set, batch_size=train.batch_size, sampler=order[skip * train.batch_size:],
                                               num_workers=train.workers, collate_fn=collate, persistent_workers=False)
        sampler = torch.utils.data.DistributedSampler(self.train_set, group.world, group.rank, shuffle=True, seed=train.seed)
        sampler.set_epoch(self.epoch)
        share = group.split(train.batch_size)
        return torch.utils.data.DataLoader(self.train_set, batch_size=share, sampler=list(sampler)[skip * share:],
                                           num_workers=train.workers, collate_fn=collate)

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
        batches, sums = meta.get("batches_in_epoch", 0), meta.get("sums") or {}
        if isinstance(batches, bool) or not isinstance(batches, int) or batches < 0 or not isinstance(sums, dict) \
                or not all(isinstance(v, (int, float)) for v in sums.values()):
            raise InputFileError(f"{where} is damaged: batches_in_epoch must be a whole number and sums numbers")
        self.resumed_batches, self.resumed_sums = batches, {str(k): float(v) for k, v in sums.items()}

    def _start_from(self, path: Path) -> None:
        """Weights of a pre-trained detector (same architecture), its anchors included: fine-tuning."""
        pretrained = load_detector(path)
        mine, theirs = self.model.spec, pretrained.spec  # the query kind and scales hold no weights
        if (theirs.backbone, theirs.method, theirs.layout) != (mine.backbone, mine.method, mine.layout):
            raise ConfigError(f"train.init_from {str(path)!r} is a {theirs.backbone} {theirs.method} {theirs.layout} "
                              f"network; this run's model section asks for another")
        if theirs.depth and not mine.depth:
            raise ConfigError(f"train.init_from {str(path)!r} reads depth; set model.depth: true to fine-tune it")
        # colour-only weights into a depth-reading network: its depth encoder starts at zero (no effect)
        # a pickability head is a second stage of its own (binpick detect pickability): not carried into fine-tuning
        weights = {k: v for k, v in pretrained.state_dict().items() if not k.startswith("pickability.")}
        missing, _ = self.model.load_state_dict(weights, strict=not (mine.depth and not theirs.depth))
        if any(not key.startswith("depth_encoder.") for key in missing):
            raise ConfigError(f"train.init_from {str(path)!r} lacks tensors of this network ({len(missing)} missing)")

    def scaled(self, batch: dict) -> dict:
        """Multi-scale training: the batch resized to a random size in ``data.train_sizes`` (a
        multiple of 32, drawn per step from the run's seed), boxes and query boxes with it."""
        sizes = self.config.data.train_sizes
        batch = {**batch, "image": batch["image"].to(self.device, non_blocking=True),
                 "query_box": batch["query_box"].to(self.device), "query_image": batch["query_image"].to(self.device),
                 **({"photo": batch["photo"].to(self.device)} if "photo" in batch else {}),
                 **({"depth": batch["depth"].to(self.device)} if "depth" in batch else {}),
                 "targets": [t.to(self.device) for t in batch["targets"]]}
        if not sizes:
            return batch
        rng = np.random.default_rng([self.config.train.seed, self.step])
        size = int(rng.integers(sizes[0] // 32, sizes[1] // 32 + 1)) * 32
        current = batch["image"].shape[-1]
        if size == current:
            return batch
        factor = size / current
        batch["image"] = torch.nn.functional.interpolate(batch["image"], size=(size, size), mode="bilinear", align_corners=False)
        if "depth" in batch:
            batch["depth"] = torch.nn.functional.interpolate(batch["depth"], size=(size, size), mode="bilinear", align_corners=False)
        batch["query_box"] = batch["query_box"] * factor
        batch["targets"] = [t * factor for t in batch["targets"]]
        return batch

    def forward(self, batch: dict) -> dict:
        """The model's outputs in float32; with ``fast_cpu`` (or on a GPU) computed in bfloat16, channels-last."""
        fast = self.config.train.fast_cpu or self.device.type == "cuda"
        images = batch["image"].contiguous(memory_format=torch.channels_last) if fast else batch["image"]
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=fast):
            query_image = batch["photo"] if self.model.spec.query == "photo" and "photo" in batch else batch["query_image"]
            out = self.model(images, batch["query_box"], query_image, batch.get("depth"))
        return {"raw": [r.float() for r in out["raw"]], "heatmaps": [None if h is None else h.float() for h in out["heatmaps"]]}

    def learning_rate(self) -> float:
        """Linear warm-up, then cosine decay to 5% of ``lr`` by the last step or by ``max_minutes``,
        whichever comes first (why the time budget anneals too: docs/notes.md, "Tuning notes")."""
        train = self.config.train
        if self.step < train.warmup_steps:
            return train.lr * (self.step + 1) / train.warmup_steps
        progress = min(1.0, max(self.time_used, (self.step - train.warmup_steps) / max(1, self.total_steps - train.warmup_steps)))
        return train.lr * (0.05 + 0.95 * 0.5 * (1 + np.cos(np.pi * progress)))

    def run(self, callback: RunCallback = SILENT) -> dict[str, Any]:
        self.run_epochs(callback, self.config.name, self.config.train.epochs)
        metrics = self.finish() if self.group.lead else {}
        callback.message(f"wrote {self.run_dir / WEIGHTS_FILE}")
        return metrics

    def open_writer(self, started: float | None = None) -> None:
        """TensorBoard, and the clock of the time budget (``started``: a loop that drives several trainers
        gives them one start)."""
        super().open_writer()
        self.status_text, self.stale, self.improved, self.epoch_ended = "", 0, False, None
        self.started = self.saved = started if started is not None else time.monotonic()

    def elapsed(self) -> float:
        """Seconds of the time budget used: at the epoch's end when a joint loop fixed it for all its rows."""
        return (self.epoch_ended if self.epoch_ended is not None else time.monotonic()) - self.started

    def progress(self, epochs: int) -> tuple[int, int]:
        return self.total_steps, self.step

    def train_epoch(self) -> dict[str, Any]:
        """The epoch's batches (those a checkpoint within it had not reached), with checkpoints every
        ``checkpoint_minutes`` and an end as soon as the time budget is spent."""
        train = self.config.train
        self.train_set.set_epoch(self.epoch)
        self.model.train()
        sums, batches = dict(self.resumed_sums), self.resumed_batches  # a checkpoint within the epoch: its sums
        self.resumed_sums, self.resumed_batches = {}, 0
        for batch in self._loader(skip=batches):
            self.note_time(time.monotonic() - self.started)
            self.train_step(batch, sums)
            batches += 1
            self.task.update(self.step, status=f"epoch {self.epoch + 1}/{train.epochs} loss {sums['total'] / batches:.3f} "
                                               f"{self.status_text}")
            if self.group.agree(self.out_of_time(time.monotonic() - self.started)):
                break  # the epoch ends here: evaluate, keep the best, checkpoint
            if train.checkpoint_minutes > 0 and time.monotonic() - self.saved > 60 * train.checkpoint_minutes and self.group.lead:
                self._checkpoint(batches, sums)  # within the epoch: a kill loses minutes, not the epoch
                self.saved = time.monotonic()
        return self.epoch_figures(sums)

    def epoch_figures(self, sums: dict[str, float]) -> dict[str, Any]:
        """An epoch's row before evaluation: steps, images and the mean of each loss."""
        return {"step": self.step, "images_seen": self.step * self.config.train.batch_size,
                **{f"loss_{k}": v / self.steps_per_epoch for k, v in sums.items()}}

    def evaluate(self) -> dict[str, Any]:
        """Val AP every ``eval_every`` epochs, at the last and when the time budget is spent; nothing otherwise."""
        train = self.config.train
        self.improved, self.spent = False, self.out_of_time(self.elapsed())
        if not (self.epoch % train.eval_every == 0 or self.epoch == train.epochs or self.spent):
            return {}
        metrics = evaluate_model(self.model, self.val_set, train.batch_size)
        return {k: metrics[k] for k in ("ap50", "map", "ap50_all", "ap50_unpickable")}

    def save_best(self, row: dict[str, Any]) -> None:
        self.stale, self.improved = 0, True
        if self.config.train.keep_best:
            self._save(self.run_dir / "best.safetensors")

    def checkpoint(self) -> None:
        self._checkpoint()

    def status(self, row: dict[str, Any]) -> str:
        if row.get("ap50") is not None:
            self.status_text = f"· val AP50 {row['ap50']:.3f} (best {self.best:.3f})"
        return f"epoch {self.epoch}/{self.config.train.epochs} {self.status_text}"

    def stop_after(self, row: dict[str, Any] | None) -> bool:
        """Out of time, or no better val AP50 for ``patience`` evaluations (early stopping)."""
        if row is None:  # another rank: rank 0 decides
            return self.out_of_time(self.elapsed())
        if "ap50" in row and not self.improved:
            self.stale += 1
        patience = self.config.train.patience
        return self.spent or bool(patience and self.stale >= patience)

    def train_step(self, batch: dict, sums: dict[str, float]) -> None:
        """One optimiser step on ``batch`` (as the loader gives it); losses add into ``sums``."""
        for group in self.optimizer.param_groups:
            group["lr"] = self.learning_rate()
        batch = self.scaled(batch)
        out = self.forward(batch)
        losses = rod_loss(self.model, out, batch["targets"], self.config.loss)
        self.optimizer.zero_grad(set_to_none=True)
        losses["total"].backward()
        self.group.average_gradients(self.model.parameters())
        torch.nn.utils.clip_grad_norm_(self.model.parameters(), 10.0)
        self.optimizer.step()
        self.step += 1
        for key, value in losses.items():
            sums[key] = sums.get(key, 0.0) + float(value.detach())
            if self.writer is not None:
                self.writer.add_scalar(f"loss/{key}", float(value.detach()), self.step)

    def out_of_time(self, elapsed: float) -> bool:
        limit = self.config.train.max_minutes
        return limit > 0 and elapsed > 60 * limit

    def note_time(self, elapsed: float) -> None:
        limit = self.config.train.max_minutes
        self.time_used = elapsed / (60 * limit) if limit > 0 else 0.0

    def finish(self) -> dict[str, Any]:
        """The final weights (the best val AP50's with ``keep_best``) and ``metrics.json``."""
        best = self.run_dir / "best.safetensors"
        if self.config.train.keep_best and best.is_file():
            self.model.load_state_dict(load_detector(best).state_dict())
        self._save(self.run_dir / WEIGHTS_FILE)
        final = self.history[-1] if self.history else {}
        metrics = {"name": self.config.name, "epochs": self.epoch, "steps": self.step, "final": final, "history": self.history}
        atomic_write_json(self.run_dir / "metrics.json", metrics)
        return metrics

    def _save(self, path: Path) -> None:
        """The deployable weights, with the config, the products and the scene domain trained on."""
        self.model.cpu()
        try:
            save_detector(self.model, path, {"config": to_dict(self.config),
                                             "trained_products": learnt_products(self.config),
                                             "trained_domains": trained_domains(self.config)})
        finally:
            self.model.to(self.device)

    def _checkpoint(self, batches: int = 0, sums: dict[str, float] | None = None) -> None:
        """Model, optimiser, epoch, step and history; within an epoch also the batches it has trained on
        and their loss sums (``batches`` > 0), so that a resume trains on the epoch's other batches."""
        def write(folder: Path) -> None:
            tensorfile.save(folder / "state.safetensors", CHECKPOINT_FORMAT,
                            state={"model": self.model.state_dict(), "optimizer": self.optimizer.state_dict()},
                            meta={"epoch": self.epoch, "step": self.step, "history": self.history,
                                  "batches_in_epoch": batches, "sums": dict(sums or {})})

        commit_checkpoint(self.run_dir / "checkpoints", self.step, write)

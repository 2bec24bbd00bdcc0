"""Teaching a detector's pickability head (:mod:`binpick.detection.pickability`), top to bottom.

The detector stays as it is; the head learns, from windows around every labelled copy of the training
files (the copies a policy picked: 1, those it could not: 0; boxes moved a little, as detections are),
which copies the policy picks; with ``query`` it also sees the query and learns from the detector's own
detections (``proposals``) which boxes hold a picked copy of the ordered product. A run folder
``runs/<name>/<time>/`` holds ``config.yaml``, the windows cut once (``windows.safetensors``: a resumed
run does not cut them again), TensorBoard events, a checkpoint per epoch, ``metrics.json`` and
``model.safetensors``: the detector with the head of the best val ROC AUC inside, which
``binpick detect eval/predict``, ``Detector.load`` and the pipeline read.
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch

from binpick.core import tensorfile
from binpick.core.config import check_range, load_run_config
from binpick.core.data_parallel import ALONE, Group
from binpick.detection.data import RepeatedInstances, TaskDataset, check_disjoint
from binpick.detection.model import DetectorNetwork
from binpick.detection.pickability import PickabilityHead, head_auc, join_windows, labelled_windows, train_epoch
from binpick.core.errors import ConfigError
from binpick.core.epochs import EpochTrainer
from binpick.core.files import atomic_write_text
from binpick.core.runs import SILENT, RunCallback, commit_checkpoint, latest_checkpoint, new_run

CHECKPOINT_FORMAT = "binpick-pickability-checkpoint-1"
WINDOWS_FORMAT = "binpick-pickability-windows-2"


@dataclass(frozen=True)
class PickabilityConfig:
    detector: str = "rod_tiny_320"  # the weights whose detections it re-scores: a shipped name, a file or a run folder
    train: list[str] = field(default_factory=lambda: ["runs/data/bins_2000/annotations_train.json"])  # COCO files
    val: str = "runs/data/bins_2000/annotations_val.json"
    name: str = "pickability"
    targets: str = "pickable:y"  # the policy whose picks it learns (as the detector's data.targets)
    depth: bool = True  # read the height map as well as colour
    width: int = 32  # channels of the first convolution
    query: bool = False  # also compare each window with the query: copies of other products score low
    distractors: bool = False  # also windows of the other products in each image, labelled 0 (for a head with query)
    factorised: bool = False  # with query: p = picks it (window alone) x same product (window and query), each on its own labels
    init: str = ""  # start from the head inside this detector file (same kind and width), e.g. a shorter run's
    epochs: int = 8
    batch_size: int = 128
    lr: float = 0.001  # the peak of a cosine schedule with one epoch of warm-up
    weight_decay: float = 0.0001
    jittered: int = 1  # extra copies of each window with the box moved (detections are not exact)
    proposals: int = 0  # also the detector's own best detections per image (score >= 0.05), labelled by IoU (train and val)
    threads: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.train or not all(isinstance(f, str) for f in self.train):
            raise ConfigError(f"train must be a list of COCO files, got {self.train!r}")
        if not self.targets.startswith("pickable:"):
            raise ConfigError(f"targets must be pickable:<policy> (pickability needs labels), got {self.targets!r}")
        check_range("width", self.width, 4, 256, integer=True)
        check_range("epochs", self.epochs, 1, 10_000, integer=True)
        check_range("batch_size", self.batch_size, 2, 65_536, integer=True)
        check_range("lr", self.lr, 0.0, 1.0, low_inclusive=False)
        check_range("weight_decay", self.weight_decay, 0.0, 1.0)
        check_range("jittered", self.jittered, 0, 16, integer=True)
        check_range("proposals", self.proposals, 0, 100, integer=True)
        check_range("threads", self.threads, 1, 256, integer=True)
        if self.factorised and not self.query:
            raise ConfigError("factorised needs query: true (its second question is whether the window holds the query's product)")


def _learning_rate(config: PickabilityConfig, step: int, per_epoch: int) -> float:
    """Linear warm-up over the first epoch, then a cosine down to zero: a pure function of the step,
    so a resumed run continues the same schedule."""
    total = config.epochs * per_epoch
    if step < per_epoch:
        return config.lr * (step + 1) / per_epoch
    return config.lr * 0.5 * (1 + math.cos(math.pi * (step - per_epoch) / max(1, total - per_epoch)))


class _Schedule:
    def __init__(self, optimiser: torch.optim.Optimizer, config: PickabilityConfig, per_epoch: int, step: int) -> None:
        self.optimiser, self.config, self.per_epoch, self.step_count = optimiser, config, per_epoch, step
        self._apply()

    def _apply(self) -> None:
        for group in self.optimiser.param_groups:
            group["lr"] = _learning_rate(self.config, self.step_count, self.per_epoch)

    def step(self) -> None:
        self.step_count += 1
        self._apply()


class PickabilityTrainer(EpochTrainer):
    """One training run of a detector's pickability head (see the module docstring)."""

    TASK = "pickability"  # its kind of job (binpick.core.jobs)

    def __init__(self, config: PickabilityConfig, run_dir: Path) -> None:
        from binpick.detection.detector import Detector

        self.config, self.run_dir = config, Path(run_dir)
        from binpick.detection.weights_file import read_detector_file, weights_path

        detector = Detector.load(config.detector)
        # what the saved detector says about itself (config, products, domains), carried into every save
        self.detector_meta = {k: v for k, v in read_detector_file(weights_path(detector.source))[1].items()
                              if k not in ("spec", "image_size", "query_size")}
        self.network: DetectorNetwork = detector.network
        torch.manual_seed(config.seed)
        kind = "rgbd" if config.depth else "rgb"
        self.network.spec = replace(self.network.spec, pickability=kind, pickability_width=config.width,
                                    pickability_query=config.query, pickability_factorised=config.factorised)
        self.network.pickability = PickabilityHead(config.depth, config.width, config.query, config.factorised)
        self.head = self.network.pickability
        self.optimiser = torch.optim.AdamW(self.head.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        self.epoch, self.best, self.history = 0, -1.0, []
        self.group = ALONE  # data-parallel training (distribute()): this process's place among others
        checkpoint = latest_checkpoint(self.run_dir / "checkpoints")
        if checkpoint is None and config.init:
            self._start_from(config.init)
        if checkpoint is not None:
            _, meta, state = tensorfile.load(checkpoint / "state.safetensors", CHECKPOINT_FORMAT, "pickability checkpoint")
            self.head.load_state_dict(state["head"])
            self.optimiser.load_state_dict(state["optimiser"])
            self.epoch, self.best, self.history = int(meta["epoch"]), float(meta["best_auc"]), list(meta["history"])

    def _start_from(self, weights: str) -> None:
        """The head of another detector as the starting point (the same kind and width): a file, a
        run folder (its model, or the best head so far of a run still going or stopped), or a folder of
        runs (its newest)."""
        from binpick.detection.detector import Detector

        path = Path(weights)
        if path.is_dir():
            runs = [path] + sorted((p for p in path.iterdir() if p.is_dir()), reverse=True)
            found = [run / name for run in runs for name in ("model.safetensors", "best.safetensors") if (run / name).is_file()]
            if not found:
                raise ConfigError(f"init: no model.safetensors or best.safetensors in {weights} or the runs inside it")
            path = found[0]
        other = Detector.load(path).network.pickability
        if other is None:
            raise ConfigError(f"init: {weights} holds no pickability head")
        try:  # a factorised head may start from a query head: its `same` question from that head, `pick` afresh
            missing, unexpected = self.head.load_state_dict(other.state_dict(), strict=False)
        except RuntimeError:
            missing, unexpected = ["(shapes differ)"], []
        if unexpected or any(not key.startswith("pick.") for key in missing):
            raise ConfigError(f"init: the head in {weights} is not of this config's kind (depth, query, width)")

    def distribute(self) -> PickabilityTrainer:
        """Train as one process of a data-parallel group (:mod:`binpick.core.data_parallel`; Ray Train
        starts it): rank 0 cuts the windows into the run folder once while the others wait, then every
        process reads them, trains on its part of each batch (the same order and flips in all) with
        gradients averaged; rank 0 evaluates and writes. Batch norm keeps each process's statistics (as
        PyTorch's DDP does on CPUs), so with several processes a step is close to, not equal to, one
        process's."""
        self.group = Group.joined()
        self.group.split(self.config.batch_size)
        self.group.share([*self.head.parameters(), *self.head.buffers()])
        return self

    @classmethod
    def new(cls, config: PickabilityConfig, runs: Path = Path("runs")) -> PickabilityTrainer:

        for file in [*config.train, config.val]:
            if not Path(file).is_file():
                raise ConfigError(f"annotations file {file!r} does not exist (binpick data generate makes them)")
        if config.init and not Path(config.init).exists():
            raise ConfigError(f"init: {config.init!r} does not exist (a detector file, a run folder or a folder of runs)")
        return cls(config, new_run(Path(runs), config, cls.TASK))

    @classmethod
    def resume(cls, run_dir: Path) -> PickabilityTrainer:
        return cls(load_run_config(PickabilityConfig, run_dir), Path(run_dir))

    # ------------------------------------------------------------------ data
    def _sources(self) -> tuple[list[RepeatedInstances], RepeatedInstances]:
        config = self.config
        val = RepeatedInstances(config.val, targets=config.targets)
        train = [RepeatedInstances(f, targets=config.targets) for f in config.train]
        for source in train:
            check_disjoint(source, val)
        return train, val

    def _windows(self, callback: RunCallback) -> dict[str, torch.Tensor]:
        """Windows of the training and val copies: cut once per run, then read from the run folder."""
        path = self.run_dir / "windows.safetensors"
        if path.is_file():
            tensors, _, _ = tensorfile.load(path, WINDOWS_FORMAT, "pickability windows")
            return tensors
        train, val = self._sources()
        parts = {}
        proposals = self._proposals if self.config.proposals else None
        for split, sources, jittered in (("train", train, self.config.jittered), ("val", [val], 0)):
            sets = [self.task_set(source) for source in sources]
            with callback.task(f"cutting {split} windows", sum(len(s) for s in sets)) as task:
                cut = join_windows([labelled_windows(s, lambda n: task.update(advance=n), jittered, self.config.seed, proposals,
                                                     self.config.distractors) for s in sets])
            parts.update({f"{split}_{name}": tensor for name, tensor in cut.items()})
        if not len(parts["train_labels"]) or not len(parts["val_labels"]):
            raise ConfigError(f"no copies labelled {self.config.targets} in the train or val files: "
                              "generate them with that policy (binpick data generate --policies ...)")
        tensorfile.save(path, WINDOWS_FORMAT, tensors=parts, meta={"train": self.config.train, "val": self.config.val})
        return parts

    def task_set(self, source) -> TaskDataset:
        """One data file's tasks as this detector sees them at ``predict``: its image size and query
        kind, shop photos framed on their product where it frames them (its proposals and the head's
        queries come from these), the height map where the head or detector reads it."""
        return TaskDataset(source, self.network.image_size, self.network.spec.query, self.network.query_size,
                           depth=self.config.depth or self.network.spec.depth, frame_photos=self.network.spec.frames_photos)

    @torch.no_grad()
    def _proposals(self, sample: dict) -> torch.Tensor:
        """The detector's own best detections on a sample, its head switched off."""
        head, self.network.pickability = self.network.pickability, None
        try:
            self.network.eval()
            depth = sample["depth"][None] if self.network.spec.depth else None
            results, _ = self.network.detect(sample["image"][None], sample["query_box"][None], sample["query_image"][None],
                                             score_threshold=0.05, depth=depth)
        finally:
            self.network.pickability = head
        return results[0]["boxes"][:self.config.proposals]

    # ------------------------------------------------------------------ the loop
    def run(self, callback: RunCallback = SILENT) -> dict[str, Any]:
        config = self.config
        torch.set_num_threads(config.threads)
        group = self.group
        if group.lead:
            windows = self._windows(callback)
        group.wait()  # rank 0 has cut the windows (or found them); the others read them now
        if not group.lead:
            windows = self._windows(callback)

        def split(name: str) -> dict[str, torch.Tensor]:
            return {key[len(name) + 1:]: value for key, value in windows.items() if key.startswith(name + "_")}

        if config.factorised and "train_same" not in windows:
            raise ConfigError(f"{self.run_dir / 'windows.safetensors'} was cut before windows said which hold the query's product: "
                              "delete it to cut them again (a factorised head needs that label)")

        labels = windows["train_labels"]
        self.train_windows = len(labels)
        callback.message(f"{len(labels)} training windows ({labels.mean().item():.0%} pickable), "
                         f"{len(windows['val_labels'])} val windows")
        per_epoch = max(1, len(labels) // config.batch_size)
        self.schedule = _Schedule(self.optimiser, config, per_epoch, self.epoch * per_epoch)
        self.train_split, self.val_split = split("train"), split("val")
        self.run_epochs(callback, f"pickability head ({len(labels)} windows)", config.epochs)
        if not group.lead:
            return {}
        best = self.run_dir / "best.safetensors"
        if best.is_file():  # kept: a resumed finished run writes the same model again
            copy = self.run_dir / "model.safetensors.tmp"
            shutil.copyfile(best, copy)
            copy.replace(self.run_dir / "model.safetensors")
        else:
            self._save(self.run_dir / "model.safetensors")
        metrics = {"name": config.name, "epochs": self.epoch, "best_val_auc": round(self.best, 4), "history": self.history}
        atomic_write_text(self.run_dir / "metrics.json", json.dumps(metrics, indent=2))
        return metrics

    def _save(self, path: Path) -> None:
        from binpick.detection.weights_file import save_detector

        extra = dict(self.detector_meta)
        extra["pickability"] = {"detector": str(self.config.detector), "train": self.config.train, "val": self.config.val,
                                "targets": self.config.targets, "query": self.config.query, "proposals": self.config.proposals,
                                "distractors": self.config.distractors, "factorised": self.config.factorised, "init": self.config.init, "epoch": self.epoch, "val_auc": round(self.best, 4),
                                "train_windows": getattr(self, "train_windows", None)}
        self.head.eval()
        save_detector(self.network, path, extra, half=True)

    def train_epoch(self) -> dict[str, Any]:
        generator = torch.Generator().manual_seed(self.config.seed * 10_007 + self.epoch)
        return {"loss": train_epoch(self.head, self.optimiser, self.schedule, self.train_split, generator, self.config.batch_size,
                                    group=self.group)}

    def evaluate(self) -> dict[str, Any]:
        return {"val_auc": head_auc(self.head, self.val_split)}

    def save_best(self, row: dict[str, Any]) -> None:
        self._save(self.run_dir / "best.safetensors")

    def recorded(self, row: dict[str, Any]) -> dict[str, Any]:
        return row | {"val_auc": round(row["val_auc"], 4)}

    def checkpoint(self) -> None:
        state = {"head": self.head.state_dict(), "optimiser": self.optimiser.state_dict()}
        meta = {"epoch": self.epoch, "best_auc": self.best, "history": self.history}
        commit_checkpoint(self.run_dir / "checkpoints", self.epoch,
                          lambda folder: tensorfile.save(folder / "state.safetensors", CHECKPOINT_FORMAT, meta=meta, state=state))

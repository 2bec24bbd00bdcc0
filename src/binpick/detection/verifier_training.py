"""Training the product check (:mod:`binpick.detection.verifier`) on a binpick data set, as one job
(``binpick train`` with ``task: product_check``) on the epoch loop every supervised job shares.

Pairs (:mod:`binpick.detection.verifier_pairs`) come from each scene's ground truth, their colours cast
and scaled well beyond the training lights (a warehouse's light is not the renderer's) and their boxes
jittered (detections are not ground truth); val pairs of look-alikes (another product in the ordered
product's colours) measure how far shape counts where colour cannot tell (docs/notes.md: as trained, it
did not lift them). Temperature scaling on the val worlds' pairs makes the output a probability.
Checkpoints are written atomically after each epoch; a run resumes.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.nn import functional as F

from binpick.core import tensorfile
from binpick.core.config import check_range, load_run_config
from binpick.core.data_parallel import ALONE
from binpick.core.epochs import EpochTrainer
from binpick.core.files import atomic_write_text
from binpick.detection.verifier import ProductVerifier, VerifierNet
from binpick.detection.verifier_pairs import batch, collect, fixed_pairs
from binpick.core.errors import ConfigError
from binpick.core.runs import SILENT, RunCallback, new_run, pinned_run

CHECKPOINT = "verifier_checkpoint.safetensors"


@dataclass(frozen=True)
class VerifierTrainConfig:
    data: str  # a binpick data set (``binpick data generate``), best with --domain random --photo-views N
    name: str = "product_check"  # the run folder's name under --runs (binpick train)
    out: str | None = None  # None: a new run folder under --runs; a path pins the folder (experiments/verify.py train --out)
    scenes: int = 8000  # train scenes read (the first ones); val scenes: every val-split scene among the first ``scenes``
    epochs: int = 8
    batch_size: int = 128
    lr: float = 2e-3
    width: int = 16
    min_visible: float = 0.3  # instances less visible than this are left out
    repainted: float = 0.0  # share of negatives repainted in the photo's colours (0: none; it did not help: docs/notes.md)
    threads: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        check_range("scenes", self.scenes, 1, 10_000_000, integer=True)
        check_range("epochs", self.epochs, 1, 1000, integer=True)
        check_range("batch_size", self.batch_size, 2, 4096, integer=True)
        check_range("lr", self.lr, 1e-6, 1.0)
        check_range("width", self.width, 8, 256, integer=True)
        check_range("min_visible", self.min_visible, 0.0, 1.0)
        check_range("repainted", self.repainted, 0.0, 1.0)
        check_range("threads", self.threads, 1, 256, integer=True)
        if self.width % 8:
            raise ConfigError(f"width must be a multiple of 8 (GroupNorm groups), got {self.width}")


@torch.no_grad()
def logits_of(net: VerifierNet, pairs, chunk: int = 512) -> torch.Tensor:
    photos, windows, colours, _ = pairs
    net.eval()
    return torch.cat([net(photos[i:i + chunk], windows[i:i + chunk], colours[i:i + chunk]) for i in range(0, len(photos), chunk)])


def fit_temperature(logits: torch.Tensor, labels: torch.Tensor) -> float:
    """Temperature scaling (Guo et al. 2017): the T that minimises val log-loss of logits / T."""
    log_t = torch.zeros((), requires_grad=True)
    optimiser = torch.optim.LBFGS([log_t], lr=0.1, max_iter=100)

    def closure():
        optimiser.zero_grad()
        loss = F.binary_cross_entropy_with_logits(logits / log_t.exp(), labels)
        loss.backward()
        return loss

    optimiser.step(closure)
    return float(log_t.detach().exp().clamp(0.05, 20.0))


def scores(probabilities: np.ndarray, labels: np.ndarray, threshold: float = 0.5) -> dict[str, float]:
    """AUC, accuracy, both acceptance rates at ``threshold`` and the calibration error (10 bins)."""
    positive, negative = probabilities[labels == 1], probabilities[labels == 0]
    if not len(positive) or not len(negative):
        return {}
    from binpick.core.metrics import roc_auc

    auc = roc_auc(labels, probabilities)  # the Mann-Whitney statistic, ties counted half, as grasp quality's
    bins = np.minimum((probabilities * 10).astype(int), 9)
    ece = sum(abs(probabilities[bins == b].mean() - labels[bins == b].mean()) * (bins == b).mean() for b in range(10) if (bins == b).any())
    return {"auc": round(float(auc), 4), "accuracy": round(float(((probabilities >= threshold) == labels).mean()), 4),
            "right_accepted": round(float((positive >= threshold).mean()), 4),
            "wrong_accepted": round(float((negative >= threshold).mean()), 4), "ece": round(float(ece), 4),
            "pairs": int(len(labels)), "positives": int(len(positive))}


# ---------------------------------------------------------------------- the loop
class VerifierTrainer(EpochTrainer):
    """One training run of the product check: the epoch loop every supervised job shares
    (:class:`~binpick.core.epochs.EpochTrainer`), then temperature scaling and the weights. The model of
    the last epoch is the one calibrated and saved (the val figures pick no epoch: they are its report)."""

    TASK = "product_check"  # its kind of job (binpick.core.jobs)
    scalars = {"loss": "train/loss", "val_auc": "val/roc_auc", "val_look_alike_auc": "val/look_alike_auc"}

    def __init__(self, config: VerifierTrainConfig, run_dir: Path) -> None:
        self.config, self.run_dir = config, Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.group = ALONE
        self.net = VerifierNet(config.width)
        self.optimiser = torch.optim.AdamW(self.net.parameters(), lr=config.lr, weight_decay=1e-4)
        self.train_set = self.val_pairs = self.look_alikes = None
        self.epoch, self.best, self.history = 0, -1.0, []

    @classmethod
    def new(cls, config: VerifierTrainConfig, runs: Path = Path("runs")) -> VerifierTrainer:
        if not (Path(config.data) / "scenes").is_dir():
            raise ConfigError(f"data {config.data!r} is not a data set folder (binpick data generate --domain random --photo-views N)")
        if config.out is not None:
            return cls(config, pinned_run(config.out, config, cls.TASK))
        return cls(config, new_run(Path(runs), config, cls.TASK))

    @classmethod
    def resume(cls, run_dir: Path) -> VerifierTrainer:
        return cls(load_run_config(VerifierTrainConfig, run_dir), Path(run_dir))

    def _load(self, callback: RunCallback) -> None:
        """The windows and pairs, the schedule over the run's steps, and the last whole epoch's checkpoint."""
        config = self.config
        self.train_set = collect(config.data, ("train",), config.scenes, config.min_visible, callback)
        val = collect(config.data, ("val",), config.scenes, config.min_visible, callback)
        self.val_pairs = fixed_pairs(val, config.seed + 1)
        self.look_alikes = fixed_pairs(val, config.seed + 2, repaint=1.0)  # every negative in the ordered product's colours
        self.steps_per_epoch = max(1, len(self.train_set.windows) // config.batch_size)
        self.schedule = torch.optim.lr_scheduler.OneCycleLR(self.optimiser, config.lr, total_steps=config.epochs * self.steps_per_epoch,
                                                            pct_start=0.1)
        checkpoint = self.run_dir / CHECKPOINT
        if checkpoint.is_file():  # resume: the model, optimiser, schedule and history of the last whole epoch
            _, meta, state = tensorfile.load(checkpoint, FORMAT_CHECKPOINT, "verifier checkpoint")
            if _comparable(meta.get("config", {})) != _comparable(asdict(config)):
                raise ConfigError(f"{checkpoint} was written by another configuration; give another --out or delete it")
            tensorfile.restore({"net": self.net, "optimiser": self.optimiser, "schedule": self.schedule}, state or {},
                               f"verifier checkpoint {str(checkpoint)!r}")
            self.history, self.epoch = list(meta["history"]), int(meta["epoch"])
            self.best = float(meta.get("best", -1.0))

    def run(self, callback: RunCallback = SILENT) -> dict[str, Any]:
        config = self.config
        torch.set_num_threads(config.threads)
        self._load(callback)
        self.run_epochs(callback, "verifier epochs", config.epochs)
        net, val_pairs, look_alikes = self.net, self.val_pairs, self.look_alikes
        net.temperature.fill_(fit_temperature(logits_of(net, val_pairs), val_pairs[3]))
        metrics = {"val": scores(torch.sigmoid(logits_of(net, val_pairs)).numpy(), val_pairs[3].numpy()),
                   "val_look_alike": scores(torch.sigmoid(logits_of(net, look_alikes)).numpy(), look_alikes[3].numpy()),
                   "temperature": round(float(net.temperature), 4), "train_windows": int(len(self.train_set.windows)),
                   "train_products": len(self.train_set.photos), "epochs": self.epoch, "history": self.history}
        ProductVerifier(net).save(self.run_dir / "product_verifier.safetensors",
                                  {"trained_on": Path(config.data).name, "metrics": metrics["val"]})
        atomic_write_text(self.run_dir / "metrics.json", json.dumps(metrics, indent=2))
        return metrics

    def train_epoch(self) -> dict[str, Any]:
        config, net, train = self.config, self.net, self.train_set
        # each epoch's shuffle and augmentation from its own seed: a resumed run goes on exactly as the
        # uninterrupted run (one generator for the whole run would restart at the resumed epoch)
        rng = np.random.default_rng([config.seed, self.epoch])
        net.train()
        order = rng.permutation(len(train.windows))
        total, started = 0.0, time.perf_counter()
        for step in range(self.steps_per_epoch):
            photos, windows, colours, labels = batch(train, order[step * config.batch_size:(step + 1) * config.batch_size], rng, True,
                                                     config.repainted)
            loss = F.binary_cross_entropy_with_logits(net(photos, windows, colours), labels)
            self.optimiser.zero_grad()
            loss.backward()
            self.optimiser.step()
            self.schedule.step()
            total += loss.item()
        return {"loss": round(total / self.steps_per_epoch, 4), "seconds": round(time.perf_counter() - started, 1)}

    def evaluate(self) -> dict[str, Any]:
        probabilities = torch.sigmoid(logits_of(self.net, self.val_pairs)).numpy()
        look_alikes = torch.sigmoid(logits_of(self.net, self.look_alikes)).numpy()
        return {**{f"val_{k}": v for k, v in scores(probabilities, self.val_pairs[3].numpy()).items()},
                "val_look_alike_auc": scores(look_alikes, self.look_alikes[3].numpy()).get("auc")}

    def save_best(self, row: dict[str, Any]) -> None:
        """Nothing: the last epoch's model is calibrated and saved (the shipped check was chosen so)."""

    def checkpoint(self) -> None:
        tensorfile.save(self.run_dir / CHECKPOINT, FORMAT_CHECKPOINT,
                        meta={"config": asdict(self.config), "epoch": self.epoch, "best": self.best, "history": self.history},
                        state={"net": self.net.state_dict(), "optimiser": self.optimiser.state_dict(),
                               "schedule": self.schedule.state_dict()})


def _comparable(config: dict[str, Any]) -> dict[str, Any]:
    """What the weights depend on: not threads, nor where the run is written or what it is called."""
    return {k: v for k, v in config.items() if k not in ("threads", "out", "name")}


def train_verifier(config: VerifierTrainConfig, callback: RunCallback = SILENT) -> dict[str, Any]:
    """Train (or resume) in ``config.out``, calibrate, save ``product_verifier.safetensors`` and its metrics
    (``binpick train`` with ``task: product_check`` and no ``out`` makes a run folder instead)."""
    if config.out is None:
        raise ConfigError("train_verifier writes to config.out: give one (binpick train makes a run folder instead)")
    return VerifierTrainer(config, Path(config.out)).run(callback)


FORMAT_CHECKPOINT = "binpick.product_verifier_checkpoint"

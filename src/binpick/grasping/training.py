"""Training a grasp-quality network on simulated trials (``binpick data generate --grasp-trials N``):
the jaws' (``tool: jaws``) or the suction cup's (``tool: suction``, trials made with ``--gripper
suction`` or ``both``).

A job in binpick's run layer: ``QualityTrainer.new(config, runs).run(callback)`` or
``QualityTrainer.resume(run_dir)``; a checkpoint per epoch, TensorBoard scalars, the weights with the
best validation ROC AUC kept as ``best.safetensors`` and written as ``model.safetensors`` at the end,
with a calibration fitted on the validation trials (a temperature and a bias, Platt scaling): the
planner ranks the two tools' grasps by these probabilities, so they must mean what they say.
Splits come from the data set: train, val (other worlds) and test (held-out product categories).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from binpick.core import tensorfile
from binpick.core.config import check_range, load_run_config
from binpick.core.data_parallel import ALONE, Group
from binpick.core.errors import ConfigError, InputFileError
from binpick.core.files import atomic_write_text, inside, read_json
from binpick.core.metrics import calibration_error, fit_platt, roc_auc
from binpick.core.depth import read_depth
from binpick.core.epochs import EpochTrainer
from binpick.grasping.camera import PinholeCamera
from binpick.grasping.candidates import describe
from binpick.grasping.instance import Surface, instance_surface
from binpick.grasping.frame import DepthFrame
from binpick.grasping.quality import FEATURES, GraspQuality, GraspQualityNet, MapSpec, grasp_features, height_map
from binpick.grippers import TOOLS
from binpick.core.runs import SILENT, RunCallback, commit_checkpoint, latest_checkpoint, new_run

CHECKPOINT_FORMAT = "binpick-grasp-quality-checkpoint-1"


@dataclass(frozen=True)
class QualityTrainConfig:
    data: str | list[str]  # a data set made with --grasp-trials, or several (their trials pooled)
    name: str = "grasp_quality"
    epochs: int = 30
    batch_size: int = 128
    lr: float = 0.001
    weight_decay: float = 0.0001
    width: int = 16  # channels of the first convolution
    threads: int = 2
    seed: int = 0
    tool: str = "jaws"  # whose trials and model: jaws or suction
    balance: bool = True  # weigh the classes equally in the loss (the calibration fitted afterwards undoes the shift)
    init_from: str | None = None  # weights to start from (a model.safetensors or shipped weights of the same tool): more trials on a trained model

    def __post_init__(self) -> None:
        from binpick.core.config import check_choice

        check_choice("tool", self.tool, TOOLS)
        check_range("epochs", self.epochs, 1, 10_000, integer=True)
        check_range("batch_size", self.batch_size, 2, 65_536, integer=True)
        check_range("lr", self.lr, 0.0, 1.0, low_inclusive=False)
        check_range("weight_decay", self.weight_decay, 0.0, 1.0)
        check_range("width", self.width, 1, 256, integer=True)
        check_range("threads", self.threads, 1, 256, integer=True)
        if isinstance(self.data, list) and not self.data:
            raise ConfigError("data must name at least one data set")

    @property
    def data_sets(self) -> list[str]:
        return [self.data] if isinstance(self.data, str) else list(self.data)


@dataclass
class TrialSet:
    maps: np.ndarray  # (N, size, size) float32
    features: np.ndarray  # (N, F) float32
    labels: np.ndarray  # (N,) float32, 1: lifted and held
    products: list[str]

    def __len__(self) -> int:
        return len(self.labels)


def load_trials(data: str | Path | list, split: str, spec=None, tool: str = "jaws") -> TrialSet:
    """Every recorded trial of ``tool`` in the data set's ``split`` scenes (of several data sets: all of
    theirs), as height maps, features and outcomes."""
    if spec is None:
        spec = MapSpec() if tool == "jaws" else _suction_spec()
    if isinstance(data, (list, tuple)):
        parts = [load_trials(one, split, spec, tool) for one in data]
        return TrialSet(np.concatenate([p.maps for p in parts]), np.concatenate([p.features for p in parts]),
                        np.concatenate([p.labels for p in parts]), [name for p in parts for name in p.products])
    data = Path(data)
    scenes = sorted((data / "scenes").glob("*.json"))
    if not scenes:
        raise InputFileError(f"{str(data)!r} holds no scenes: make them with binpick data generate --grasp-trials N")
    maps, features, labels, products = [], [], [], []
    card = data / "dataset.json"  # the hand the trials were made with (a both-hand's fingers ride above its cup)
    gripper = (read_json(card, "data-set card").get("config") or {}).get("gripper", "jaws") if card.is_file() else "jaws"
    for path in scenes:
        record = read_json(path, "scene file")
        if record.get("split") != split or not record.get("grasp_trials"):
            continue
        camera = PinholeCamera.from_record(record["camera"])
        frame = DepthFrame.from_depth(read_depth(inside(data, record["depth_file"], "depth image")), camera)
        boxes = {a["slot"]: a["bbox"] for a in record["annotations"]}
        surfaces: dict[int, Surface | None] = {}
        for trial in record["grasp_trials"]:
            if trial.get("tool", "jaws") != tool:
                continue
            # what the executed grasp (position, yaw) was, described by today's candidate code
            slot = trial["slot"]
            if slot not in surfaces:
                surfaces[slot] = instance_surface(frame, boxes[slot])
            surface = surfaces[slot]
            if surface is None:
                continue
            position = np.array(trial["position"])
            if tool == "suction":
                from binpick.grasping.suction import describe_suction
                from binpick.grasping.suction_quality import suction_maps

                described = describe_suction(frame, surface, position[None, :2], gripper=gripper)
                if not described:
                    continue
                maps.append(suction_maps(frame, [described[0].position], spec)[0])
                features.append(described[0].seal.vector())
                labels.append(float(trial["success"]))
                products.append(trial["product"])
                continue
            candidate = describe(frame, surface, position, trial["yaw"], position[2])
            maps.append(height_map(frame, position, trial["yaw"], surface.top, surface.support, spec))
            clearance = candidate.clearance if np.isfinite(candidate.clearance) else -0.05
            features.append(grasp_features(candidate.width, clearance, position[2], surface.top, surface.support))
            labels.append(float(trial["success"]))
            products.append(trial["product"])
    size = spec.size
    count = FEATURES if tool == "jaws" else _suction_features()
    return TrialSet(np.array(maps, dtype=np.float32).reshape(-1, size, size), np.array(features, dtype=np.float32).reshape(-1, count),
                    np.array(labels, dtype=np.float32), products)


def _suction_spec():
    from binpick.grasping.suction_quality import SuctionMapSpec

    return SuctionMapSpec()


def _suction_features() -> int:
    from binpick.grasping.suction import FEATURES as SUCTION_FEATURES

    return SUCTION_FEATURES


def new_model(tool: str, width: int):
    """An untrained quality model for ``tool``: the jaws' GQ-CNN-style network or the suction cup's."""
    if tool == "jaws":
        return GraspQuality(GraspQualityNet(MapSpec().size, width), MapSpec(), width)
    from binpick.grasping.suction_quality import SuctionMapSpec, SuctionQuality, SuctionQualityNet

    return SuctionQuality(SuctionQualityNet(SuctionMapSpec().size, width), SuctionMapSpec(), width)


def load_model(tool: str, path: Path):
    if tool == "jaws":
        return GraspQuality.load(path)
    from binpick.grasping.suction_quality import SuctionQuality

    return SuctionQuality.load(path)


def logits_of(model, maps: np.ndarray, features: np.ndarray) -> np.ndarray:
    """The model's raw logits (before any calibration)."""
    with torch.no_grad():
        return model.net(torch.from_numpy(maps)[:, None], torch.from_numpy(features)).numpy()


class QualityTrainer(EpochTrainer):
    """One training run of the grasp-quality network (see the module docstring)."""

    TASK = "grasp_quality"  # its kind of job (binpick.core.jobs)

    def __init__(self, config: QualityTrainConfig, run_dir: Path) -> None:
        self.config, self.run_dir = config, Path(run_dir)
        torch.manual_seed(config.seed)
        self.quality = new_model(config.tool, config.width)
        self.optimizer = torch.optim.AdamW(self.quality.net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        self.epoch, self.best, self.history = 0, -1.0, []
        self.group = ALONE  # data-parallel training (distribute()): this process's place among others
        if config.init_from is not None:
            start = load_model(config.tool, Path(config.init_from))
            if start.width != config.width:
                raise ConfigError(f"init_from {config.init_from!r} has width {start.width}, the config {config.width}")
            self.quality.net.load_state_dict(start.net.state_dict())
        checkpoint = latest_checkpoint(self.run_dir / "checkpoints")
        if checkpoint is not None:
            _, meta, state = tensorfile.load(checkpoint / "state.safetensors", CHECKPOINT_FORMAT, "grasp-quality checkpoint")
            self.quality.net.load_state_dict(state["net"])
            self.optimizer.load_state_dict(state["optimizer"])
            self.epoch, self.best, self.history = int(meta["epoch"]), float(meta["best_auc"]), list(meta["history"])

    def distribute(self) -> QualityTrainer:
        """Train as one process of a data-parallel group (:mod:`binpick.core.data_parallel`; Ray Train
        starts it): every process reads the trials, draws the same order and flips, trains on its part
        of each batch with gradients averaged (the single process's step); rank 0 evaluates and writes."""
        self.group = Group.joined()
        self.group.split(self.config.batch_size)
        self.group.share([*self.quality.net.parameters(), *self.quality.net.buffers()])
        return self

    @classmethod
    def new(cls, config: QualityTrainConfig, runs: Path = Path("runs")) -> QualityTrainer:

        for data in config.data_sets:
            if not (Path(data) / "scenes").is_dir():
                raise ConfigError(f"data {data!r} is not a data set folder (binpick data generate --grasp-trials N)")
        if config.init_from is not None and not Path(config.init_from).is_file():
            raise ConfigError(f"init_from {config.init_from!r} is not a weights file")
        return cls(config, new_run(Path(runs), config, cls.TASK))

    @classmethod
    def resume(cls, run_dir: Path) -> QualityTrainer:
        return cls(load_run_config(QualityTrainConfig, run_dir), Path(run_dir))

    def run(self, callback: RunCallback = SILENT) -> dict[str, Any]:
        config = self.config
        torch.set_num_threads(config.threads)
        callback.message(f"reading {config.tool} trials from {', '.join(config.data_sets)}")
        train, val = load_trials(config.data_sets, "train", tool=config.tool), load_trials(config.data_sets, "val", tool=config.tool)
        if len(train) < config.batch_size or len(val) == 0:
            raise ConfigError(f"{config.data!r} has {len(train)} train and {len(val)} val trials: "
                              f"too few (more scenes, or a larger --grasp-trials)")
        positive = float(train.labels.mean())
        weight = torch.tensor((1 - positive) / max(positive, 1e-3) if config.balance else 1.0)
        self.loss_fn, self.val = nn.BCEWithLogitsLoss(pos_weight=weight), val
        self.train_set = torch.from_numpy(train.maps), torch.from_numpy(train.features), torch.from_numpy(train.labels)
        self.run_epochs(callback, f"{config.tool} quality ({len(train)} trials)", config.epochs)
        if not self.group.lead:
            return {}
        best = load_model(config.tool, self.run_dir / "best.safetensors")
        calibration = calibrate(best, val)
        best.meta["calibration"] = calibration
        best.save(self.run_dir / "model.safetensors", {"data": config.data_sets, "train_trials": len(train), "tool": config.tool,
                                                       "train_success_rate": round(positive, 4)})
        metrics = {"name": config.name, "tool": config.tool, "epochs": self.epoch,
                   "best_val_auc": self.best if self.best >= 0 else None, "calibration": calibration,
                   "history": self.history}
        atomic_write_text(self.run_dir / "metrics.json", json.dumps(metrics, indent=2))
        return metrics

    def train_epoch(self) -> dict[str, Any]:
        config, group = self.config, self.group
        maps, features, labels = self.train_set
        # each epoch's shuffle and flips from its own seed: a run resumed at any epoch goes on
        # exactly as the uninterrupted run (one generator for the whole run would restart there)
        rng = np.random.default_rng([config.seed, self.epoch])
        net = self.quality.net.train()
        order = torch.from_numpy(rng.permutation(len(labels)))
        losses = []
        for start in range(0, len(order) - config.batch_size + 1, config.batch_size):
            batch = group.part(order[start:start + config.batch_size])
            x = maps[batch][:, None]
            # the jaws are symmetric: a grasp mirrored along or across them is the same grasp;
            # a round cup sees the same surface turned or mirrored
            if rng.random() < 0.5:
                x = x.flip(3)
            if rng.random() < 0.5:
                x = x.flip(2)
            if config.tool == "suction":
                x = torch.rot90(x, int(rng.integers(4)), dims=(2, 3))
            loss = self.loss_fn(net(x, features[batch]), labels[batch])
            self.optimizer.zero_grad()
            loss.backward()
            group.average_gradients(net.parameters())
            self.optimizer.step()
            losses.append(loss.item())
        return {"loss": float(np.mean(losses))}

    def evaluate(self) -> dict[str, Any]:
        self.quality.net.eval()
        return {"val_auc": roc_auc(self.val.labels, logits_of(self.quality, self.val.maps, self.val.features))}

    def save_best(self, row: dict[str, Any]) -> None:
        self.quality.save(self.run_dir / "best.safetensors", {"val_auc": row["val_auc"], "epoch": self.epoch})

    def checkpoint(self) -> None:
        state = {"net": self.quality.net.state_dict(), "optimizer": self.optimizer.state_dict()}
        meta = {"epoch": self.epoch, "best_auc": self.best, "history": self.history}
        commit_checkpoint(self.run_dir / "checkpoints", self.epoch,
                          lambda folder: tensorfile.save(folder / "state.safetensors", CHECKPOINT_FORMAT, meta=meta, state=state))


def calibrate(model, trials: TrialSet) -> dict[str, float]:
    """Platt scaling on ``trials`` (the validation split): the temperature and bias that make the
    model's probabilities match the observed success, with the calibration error before and after."""
    logits = logits_of(model, trials.maps, trials.features)
    before = 1.0 / (1.0 + np.exp(-logits))
    temperature, bias = fit_platt(logits, trials.labels)
    after = 1.0 / (1.0 + np.exp(-(logits / temperature + bias)))
    return {"temperature": round(temperature, 4), "bias": round(bias, 4), "trials": len(trials),
            "ece_before": round(calibration_error(trials.labels, before), 4), "ece_after": round(calibration_error(trials.labels, after), 4)}

"""Train an auto-perception network on collected (image, semantic state) pairs, save and load it.

Training is plain minibatch Adam on L_VP; the data are the random-policy episodes APRiL collects
(thesis §4.2: "the perception network is trained independently on data collected with an initial
random walk policy"). A held-out tenth reports how well the latent predicts s̄ on unseen images.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from binpick.core import tensorfile
from binpick.core.config import check_choice
from binpick.core.errors import ConfigError, InputFileError
from binpick.core.files import require_fields
from binpick.april.perception.autoencoder import AutoPerception, PerceptionConfig
from binpick.core.runs import SILENT, RunCallback


def train_perception(
    config: PerceptionConfig,
    images: np.ndarray,
    states: np.ndarray,
    epochs: int = 20,
    batch_size: int = 64,
    learning_rate: float = 1e-3,
    schedule: str = "constant",
    seed: int = 0,
    callback: RunCallback = SILENT,
    initial: AutoPerception | None = None,
    points: np.ndarray | None = None,
) -> tuple[AutoPerception, dict[str, Any]]:
    """A network trained on ``images`` (N, H, W, C) uint8 and ``states`` (N, d); returns it and its history.

    With ``initial`` training continues from that network (and keeps its state statistics).
    ``schedule``: ``constant`` learning rate, or ``cosine`` decay to 0 over all epochs.
    ``points`` (N, 2K): where s̄'s goal lies in each view, for ``goal_keypoints`` (:meth:`AutoPerception.loss`).
    """
    check_choice("schedule", schedule, ["constant", "cosine"])
    if len(images) != len(states) or len(images) < 2:
        raise ConfigError(f"perception training needs matching images and states, got {len(images)} and {len(states)}")
    if points is not None and len(points) != len(images):
        raise ConfigError(f"perception training needs the goal's place in view for every image, got {len(points)} "
                          f"for {len(images)}")
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(images))
    held_out = order[: max(1, len(images) // 10)]
    train = order[len(held_out):]
    if initial is None:
        model = AutoPerception(config, images.shape[1:], states.shape[1])
        model.set_state_statistics(states[train])
        if config.foreground_weight:
            model.set_background(images[train])
    else:
        model = initial
    optimizer = torch.optim.Adam(model.parameters(), lr=learning_rate)
    history: dict[str, Any] = {"epochs": [], "train_images": len(train), "held_out_images": len(held_out)}
    steps_per_epoch = max(1, len(train) // batch_size)
    decay = (torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=epochs * steps_per_epoch)
             if schedule == "cosine" else None)
    with callback.task("perception", epochs) as task:
        for epoch in range(epochs):
            model.train()
            shuffled = rng.permutation(train)
            sums = {"total": 0.0, "recon": 0.0, "cond": 0.0, "kl": 0.0}
            for step in range(steps_per_epoch):
                batch = shuffled[step * batch_size:(step + 1) * batch_size]
                losses = model.loss(images[batch], states[batch], None if points is None else points[batch])
                optimizer.zero_grad()
                losses["total"].backward()
                optimizer.step()
                if decay is not None:
                    decay.step()
                for key in sums:
                    sums[key] += float(losses[key].detach()) / steps_per_epoch
            row = {"epoch": epoch + 1, **sums, **held_out_error(model, images[held_out], states[held_out],
                                                                None if points is None else points[held_out])}
            history["epochs"].append(row)
            status = f"L_recon {sums['recon']:.4f}"
            if row["state_mae"] is not None:
                status += f" · held-out s̄ error {row['state_mae']:.4f}"
            if row.get("goal_point_mae") is not None:
                status += f" · goal keypoints {row['goal_point_mae']:.4f}"
            task.update(epoch + 1, status=status)
            callback.message(f"perception epoch {epoch + 1}/{epochs}: {status}")
    return model, history


def held_out_error(model: AutoPerception, images: np.ndarray, states: np.ndarray,
                   points: np.ndarray | None = None) -> dict[str, float | None]:
    """Mean absolute error of φ_enc(I)^{1:m} against s̄ on images the network did not train on
    (None when nothing is conditioned, m = 0: JSON has no NaN); with ``points`` also the goal
    keypoints' (image units, [-1, 1])."""
    m = model.config.conditioned
    if not m:
        return {"state_mae": None}
    with torch.no_grad():  # one pass gives φ_enc(I) and, with goal keypoints, their places
        passes = [model._encode(model._pixels(images[i:i + 256]), sample=False) for i in range(0, len(images), 256)]
        predicted = model.features(torch.cat([mu for _, mu, *_ in passes])).numpy()
    errors = {"state_mae": float(np.abs(predicted[:, :m] - states[:, :m]).mean())}
    if points is not None and model.config.goal_keypoints:
        found = torch.cat([places for *_, places in passes]).numpy()
        errors["goal_point_mae"] = float(np.abs(found - points).mean())
    return errors


FORMAT = "binpick-perception-1"
PERCEPTION_FILE = "perception.safetensors"


def perception_path(folder: Path) -> Path:
    """The perception weights in a run folder: ``perception.safetensors``, or an older run's ``.pt``."""
    folder = Path(folder)
    legacy = folder / "perception.pt"
    return legacy if legacy.is_file() and not (folder / PERCEPTION_FILE).is_file() else folder / PERCEPTION_FILE


def save_perception(model: AutoPerception, path: Path) -> None:
    """Weights (safetensors) and what rebuilds the network (JSON), written atomically."""
    meta = {"config": asdict(model.config), "image_shape": list(model.image_shape), "state_dim": model.state_dim}
    tensorfile.save(path, FORMAT, tensors=model.state_dict(), meta=meta)


def load_perception(path: Path) -> AutoPerception:
    """A network saved by :func:`save_perception`; older ``.pt`` files only as plain tensors."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no perception checkpoint at {path}")
    if not tensorfile.is_safetensors(path):  # an older binpick .pt: plain tensors only
        data = tensorfile.load_legacy_torch(path, "perception checkpoint")
        if not isinstance(data, dict):
            raise InputFileError(f"perception checkpoint {str(path)!r} is damaged: not a mapping")
        weights, meta = data.get("weights"), data
    else:
        weights, meta, _ = tensorfile.load(path, FORMAT, "perception checkpoint")
    where = f"perception checkpoint {str(path)!r}"
    require_fields({"weights": weights, **meta}, {"weights": dict, "config": dict, "image_shape": (list, tuple),
                                                  "state_dim": int}, where)
    try:
        model = AutoPerception(PerceptionConfig(**meta["config"]), tuple(meta["image_shape"]), meta["state_dim"])
        model.load_state_dict(weights)
    except (TypeError, ValueError, RuntimeError) as error:
        raise InputFileError(f"{where} describes no valid network ({str(error).splitlines()[0][:120]})") from None
    model.eval()
    return model

"""Detector weights on disk: safetensors with JSON metadata (the network's spec and sizes, checked
before any tensor is read), loaded without running code."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from binpick.core import tensorfile
from binpick.detection.model import DetectorNetwork, ModelSpec
from binpick.core.errors import InputFileError
from binpick.core.files import require_fields

FORMAT = "binpick-detector-2"  # safetensors + JSON; "binpick-detector-1" was a torch pickle (.pt)
WEIGHTS_FILE = "model.safetensors"
CHECKPOINT_FORMAT = "binpick-detector-checkpoint-1"


def save_detector(model: DetectorNetwork, path: Path, extra: dict[str, Any] | None = None, half: bool = False) -> None:
    """Write weights (safetensors) and what rebuilds the network (JSON) atomically: a crash leaves the
    previous file or the new one. ``half`` stores float16 weights (half the size; loading turns them
    back into float32). ``extra`` must be JSON data (config, products trained on, ...)."""
    if model.inference_only:
        raise ValueError("an inference copy of a detector (batch norms folded) cannot be saved: save the network it was made from")
    weights = model.state_dict()
    if half:
        weights = {k: v.half() if v.is_floating_point() and k != "anchors" else v for k, v in weights.items()}
    meta = {"spec": asdict(model.spec), "image_size": model.image_size, "query_size": model.query_size, **(extra or {})}
    tensorfile.save(path, FORMAT, tensors=weights, meta=meta)


def weights_path(path: Path) -> Path:
    """A file as given; a run folder's ``model.safetensors`` (or an older run's ``model.pt``)."""
    if path.is_dir():
        for name in (WEIGHTS_FILE, "model.pt"):
            if (path / name).is_file():
                return path / name
        raise InputFileError(f"no detector weights in {str(path)!r} (no {WEIGHTS_FILE}): is the run finished?")
    if not path.is_file():
        raise InputFileError(f"no detector weights at {str(path)!r}")
    return path


def read_detector_file(path: Path) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
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


def check_network_sizes(meta: dict, path: Path) -> None:
    """Sizes a weights file's metadata asks for, checked before a network is built: a file asking for
    a 10-million-pixel input or a million channels is refused, not allocated."""
    where = f"detector weights {str(path)!r}"
    for key, low, high in (("image_size", 32, 4096), ("query_size", 16, 1024)):
        value = meta.get(key, low)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise InputFileError(f"{where}: {key} must be a whole number from {low} to {high}, got {str(value)[:40]}")
    numbers = [v for value in meta["spec"].values() for v in (value if isinstance(value, (list, tuple)) else [value])
               if isinstance(v, (int, float)) and not isinstance(v, bool)]
    if any(not abs(v) <= 4096 for v in numbers):
        raise InputFileError(f"{where}: its network description asks for sizes past 4096 (channels, layers, scales)")


def load_detector(path: str | Path) -> DetectorNetwork:
    """A detector saved by :func:`save_detector` (or a run folder holding ``model.safetensors``)."""
    path = weights_path(Path(path))
    weights, meta = read_detector_file(path)
    check_network_sizes(meta, path)
    try:
        spec = ModelSpec(**{**meta["spec"], "scales": tuple(meta["spec"]["scales"]),  # JSON lists -> the spec's tuples
                            "photo_sizes": tuple(meta["spec"].get("photo_sizes", ()))})
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
    model.trained_domains = meta.get("trained_domains") or ["default"]  # before domains existed: the default scene
    threshold = meta.get("score_threshold")
    model.score_threshold = float(threshold) if isinstance(threshold, (int, float)) and 0 <= threshold <= 1 else None
    model.eval()
    return model

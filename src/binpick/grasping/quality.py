"""A grasp-quality network in the spirit of Dex-Net 2.0's GQ-CNN: the depth around a candidate, as a
height map in the grasp's own frame (columns along the closing direction, rows along the jaws, heights
relative to the fingertips), plus the candidate's width, depth and clearance -> the probability that
the grasp lifts the instance and holds it. Trained on trials executed in simulation
(``binpick data generate --grasp-trials N``; :mod:`binpick.grasping.training`).

Small on purpose: a few tens of thousands of weights, every candidate of an order scored in one batch.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from binpick.grasping.candidates import GraspCandidate, JawGripper
from binpick.grasping.instance import surface_heights
from binpick.grasping.frame import DepthFrame

FORMAT = "binpick-grasp-quality-1"
SHIPPED = Path(__file__).parent / "weights" / "grasp_quality.safetensors"  # trained by experiments/grasp.py
HEIGHT_SCALE = 0.05  # metres per unit of the height map


@dataclass(frozen=True)
class MapSpec:
    size: int = 32  # cells per side
    extent: float = 0.16  # metres per side (5 mm cells): both open fingers and some room beyond


def height_maps(frame: DepthFrame, positions, yaws, tops, supports, spec: MapSpec = MapSpec()) -> np.ndarray:
    """(N, size, size) float32 for N grasps: surface heights around each grasp minus its fingertips'
    height, in units of HEIGHT_SCALE (holes filled as the frame fills them); cells outside the camera's
    view read as the support surface's height."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    yaws = np.asarray(yaws, dtype=float).reshape(-1)
    d = np.stack([np.cos(yaws), np.sin(yaws)], axis=1)
    j = np.stack([-d[:, 1], d[:, 0]], axis=1)
    steps = (np.arange(spec.size) - (spec.size - 1) / 2) * spec.extent / spec.size
    grid = (positions[:, None, None, :2] + steps[None, None, :, None] * d[:, None, None, :]
            + steps[None, :, None, None] * j[:, None, None, :])  # rows: jaw axis
    z_ref = np.repeat(np.asarray(tops, dtype=float).reshape(-1), spec.size * spec.size)
    heights, _ = surface_heights(frame, grid.reshape(-1, 2), z_ref)
    heights = heights.reshape(len(positions), spec.size, spec.size)
    heights = np.where(np.isfinite(heights), heights, np.asarray(supports, dtype=float).reshape(-1, 1, 1))
    return np.clip((heights - positions[:, 2, None, None]) / HEIGHT_SCALE, -1.0, 4.0).astype(np.float32)


def height_map(frame: DepthFrame, position, yaw: float, top: float, support: float, spec: MapSpec = MapSpec()) -> np.ndarray:
    """(size, size) float32: one grasp's height map (:func:`height_maps`)."""
    return height_maps(frame, [position], [yaw], [top], [support], spec)[0]


def grasp_features(width: float, clearance: float, tips: float, top: float, support: float,
                   gripper: JawGripper = JawGripper()) -> np.ndarray:
    """The candidate's numbers the height map shows only coarsely (5 mm cells)."""
    return np.array([width / gripper.opening, (top - tips) / HEIGHT_SCALE, (top - support) / (2 * HEIGHT_SCALE),
                     np.clip(clearance, -0.05, 0.05) / HEIGHT_SCALE], dtype=np.float32)


FEATURES = 4


class GraspQualityNet(nn.Module):
    """Height map (1 x size x size) + features -> a logit of grasp success."""

    def __init__(self, size: int = 32, width: int = 16) -> None:
        super().__init__()
        self.conv = nn.Sequential(
            nn.Conv2d(1, width, 5, padding=2), nn.ReLU(), nn.MaxPool2d(2),
            nn.Conv2d(width, 2 * width, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
            nn.Conv2d(2 * width, 2 * width, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2))
        self.head = nn.Sequential(nn.Linear(2 * width * (size // 8) ** 2 + FEATURES, 64), nn.ReLU(), nn.Linear(64, 1))

    def forward(self, maps: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        return self.head(torch.cat([self.conv(maps).flatten(1), features], dim=1)).squeeze(1)


def map_settings(meta: dict, path, what: str, size: int, extent: float, width: int) -> tuple[int, float, int]:
    """A quality model's height-map size (cells), extent (m) and network width from its weights' JSON,
    checked: a file whose header says ``size: "abc"``, ``width: -5`` or ``extent: NaN`` is one line,
    not a traceback or a model that scores every grasp 1.0."""
    import math

    from binpick.core.errors import InputFileError

    def number(key: str, default, kind, low, high):
        value = meta.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind is int and value != int(value)) \
                or not math.isfinite(value) or not low <= value <= high:
            raise InputFileError(f"{what} weights {str(path)!r}: {key} must be {'a whole number' if kind is int else 'a number'} "
                                 f"from {low} to {high}, got {value!r}")
        return kind(value)

    calibration = meta.get("calibration")
    if calibration is not None:
        if not isinstance(calibration, dict):
            raise InputFileError(f"{what} weights {str(path)!r}: calibration must be a mapping, got {calibration!r}")
        number_of = {"temperature": (1.0, 0.05, 20.0), "bias": (0.0, -20.0, 20.0)}
        for key, (default, low, high) in number_of.items():
            value = calibration.get(key, default)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not low <= value <= high:
                raise InputFileError(f"{what} weights {str(path)!r}: calibration {key} must be a number from {low} to {high}, got {value!r}")
    return number("size", size, int, 8, 256), number("extent", extent, float, 0.01, 1.0), number("width", width, int, 1, 256)


class GraspQuality:
    """``GraspQuality.load(path).score(frame, candidates)``: success probabilities."""

    def __init__(self, net: GraspQualityNet | None = None, spec: MapSpec = MapSpec(), width: int = 16, meta: dict | None = None) -> None:
        self.spec, self.width = spec, width
        self.net = net if net is not None else GraspQualityNet(spec.size, width)
        self.net.eval()
        self.meta = meta or {}

    def inputs(self, frame: DepthFrame, candidates: list[GraspCandidate]) -> tuple[np.ndarray, np.ndarray]:
        maps = height_maps(frame, [c.position for c in candidates], [c.yaw for c in candidates], [c.top for c in candidates],
                           [c.support for c in candidates], self.spec)
        features = np.stack([grasp_features(c.width, c.clearance, c.position[2], c.top, c.support) for c in candidates])
        return maps, features

    @property
    def calibration(self) -> tuple[float, float]:
        """(temperature, bias): probability = sigmoid(logit / temperature + bias); (1, 0) for weights
        trained before calibration (their classes reweighted: their probabilities run low)."""
        calibration = self.meta.get("calibration") or {}
        return float(calibration.get("temperature", 1.0)), float(calibration.get("bias", 0.0))

    @torch.no_grad()
    def probabilities(self, maps: np.ndarray, features: np.ndarray) -> np.ndarray:
        temperature, bias = self.calibration
        logits = self.net(torch.from_numpy(maps)[:, None], torch.from_numpy(features))
        return torch.sigmoid(logits / temperature + bias).numpy()

    def score(self, frame: DepthFrame, candidates: list[GraspCandidate]) -> np.ndarray:
        if not candidates:
            return np.zeros(0)
        return self.probabilities(*self.inputs(frame, candidates))

    def save(self, path: str | Path, meta: dict | None = None) -> Path:
        from binpick.core import tensorfile

        document = {"size": self.spec.size, "extent": self.spec.extent, "width": self.width, **self.meta, **(meta or {})}
        return tensorfile.save(path, FORMAT, tensors=self.net.state_dict(), meta=document)

    @classmethod
    def load(cls, path: str | Path) -> GraspQuality:
        from binpick.core import tensorfile
        from binpick.core.errors import InputFileError

        tensors, meta, _ = tensorfile.load(path, FORMAT, "grasp-quality weights")
        size, extent, width = map_settings(meta, path, "grasp-quality", 32, 0.16, 16)
        quality = cls(None, MapSpec(size, extent), width, meta)
        try:
            quality.net.load_state_dict({k: v.float() for k, v in tensors.items()})
        except RuntimeError as error:
            raise InputFileError(f"grasp-quality weights {str(path)!r} do not fit the network ({str(error).splitlines()[0][:100]})") from None
        quality.net.eval()
        return quality

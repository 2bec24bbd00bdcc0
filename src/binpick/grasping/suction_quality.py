"""A suction-quality network: the depth under and around the cup, as a height map relative to the lip
(2.5 mm cells over 6 cm), plus the seal-and-wrench features (:class:`binpick.grasping.suction.SuctionFeatures`)
-> the probability that the cup seals, lifts the product and holds it through the carry. Trained on
suction trials executed in simulation (``binpick data generate --gripper suction --grasp-trials N``;
:mod:`binpick.grasping.training` with ``tool: suction``), its output calibrated on held-back trials
(a temperature and a bias kept with the weights), so it can be ranked against the jaws' model.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from binpick.grasping.candidates import GraspCandidate
from binpick.grasping.instance import surface_heights
from binpick.grasping.frame import DepthFrame
from binpick.grasping.quality import map_settings
from binpick.grasping.suction import FEATURES

FORMAT = "binpick-suction-quality-1"
SHIPPED = Path(__file__).parent / "weights" / "suction_quality.safetensors"  # trained by experiments/grasp.py
HEIGHT_SCALE = 0.01  # metres per unit of the height map: millimetres matter under a cup


@dataclass(frozen=True)
class SuctionMapSpec:
    size: int = 24  # cells per side
    extent: float = 0.06  # metres per side: the 3 cm cup and a lip's width round it


def suction_maps(frame: DepthFrame, positions, spec: SuctionMapSpec = SuctionMapSpec()) -> np.ndarray:
    """(N, size, size) float32: the surface round each cup position, relative to its lip, in units of
    HEIGHT_SCALE (clipped to -3..3: a neighbour's drop or rise beyond that says only "an edge")."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    steps = (np.arange(spec.size) - (spec.size - 1) / 2) * spec.extent / spec.size
    grid = positions[:, None, None, :2] + np.stack(np.meshgrid(steps, steps, indexing="xy"), axis=-1)[None]
    heights, _ = surface_heights(frame, grid.reshape(-1, 2), np.repeat(positions[:, 2], spec.size * spec.size))
    heights = heights.reshape(len(positions), spec.size, spec.size) - positions[:, 2, None, None]
    return np.clip(np.nan_to_num(heights / HEIGHT_SCALE, nan=-3.0), -3.0, 3.0).astype(np.float32)


class SuctionQualityNet(nn.Module):
    """Height map (1 x size x size) + features -> a logit of suction success."""

    def __init__(self, size: int = 24, width: int = 12) -> None:
        super().__init__()
        self.conv = nn.Sequential(
            nn.Conv2d(1, width, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
            nn.Conv2d(width, 2 * width, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
            nn.Conv2d(2 * width, 2 * width, 3, padding=1), nn.ReLU(), nn.AdaptiveAvgPool2d(3))
        self.head = nn.Sequential(nn.Linear(2 * width * 9 + FEATURES, 48), nn.ReLU(), nn.Linear(48, 1))

    def forward(self, maps: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        return self.head(torch.cat([self.conv(maps).flatten(1), features], dim=1)).squeeze(1)


class SuctionQuality:
    """``SuctionQuality.load(path).score(frame, candidates)``: calibrated success probabilities of
    suction candidates (:func:`binpick.grasping.suction.suction_candidates`)."""

    def __init__(self, net: SuctionQualityNet | None = None, spec: SuctionMapSpec = SuctionMapSpec(), width: int = 12,
                 meta: dict | None = None) -> None:
        self.spec, self.width = spec, width
        self.net = net if net is not None else SuctionQualityNet(spec.size, width)
        self.net.eval()
        self.meta = dict(meta or {})

    @property
    def calibration(self) -> tuple[float, float]:
        """(temperature, bias): probability = sigmoid(logit / temperature + bias)."""
        calibration = self.meta.get("calibration") or {}
        return float(calibration.get("temperature", 1.0)), float(calibration.get("bias", 0.0))

    def inputs(self, frame: DepthFrame, candidates: list[GraspCandidate]) -> tuple[np.ndarray, np.ndarray]:
        maps = suction_maps(frame, [c.position for c in candidates], self.spec)
        features = np.stack([c.seal.vector() for c in candidates]).astype(np.float32)
        return maps, features

    @torch.no_grad()
    def logits(self, maps: np.ndarray, features: np.ndarray) -> np.ndarray:
        return self.net(torch.from_numpy(maps)[:, None], torch.from_numpy(features)).numpy()

    def probabilities(self, maps: np.ndarray, features: np.ndarray) -> np.ndarray:
        temperature, bias = self.calibration
        return 1.0 / (1.0 + np.exp(-(self.logits(maps, features) / temperature + bias)))

    def score(self, frame: DepthFrame, candidates: list[GraspCandidate]) -> np.ndarray:
        if not candidates:
            return np.zeros(0)
        return self.probabilities(*self.inputs(frame, candidates))

    def save(self, path: str | Path, meta: dict | None = None) -> Path:
        from binpick.core import tensorfile

        document = {"size": self.spec.size, "extent": self.spec.extent, "width": self.width, **self.meta, **(meta or {})}
        return tensorfile.save(path, FORMAT, tensors=self.net.state_dict(), meta=document)

    @classmethod
    def load(cls, path: str | Path) -> SuctionQuality:
        from binpick.core import tensorfile
        from binpick.core.errors import InputFileError

        tensors, meta, _ = tensorfile.load(path, FORMAT, "suction-quality weights")
        size, extent, width = map_settings(meta, path, "suction-quality", 24, 0.06, 12)
        quality = cls(None, SuctionMapSpec(size, extent), width, meta)
        try:
            quality.net.load_state_dict({k: v.float() for k, v in tensors.items()})
        except RuntimeError as error:
            raise InputFileError(f"suction-quality weights {str(path)!r} do not fit the network ({str(error).splitlines()[0][:100]})") from None
        quality.net.eval()
        return quality

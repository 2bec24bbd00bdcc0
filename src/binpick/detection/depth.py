"""Depth as a second input, for pickability (thesis §5.4.4, §6.3).

Which copy of a product a grasp can lift depends on its pose and on its neighbours: whether something
lies on it, whether a finger has room beside it. An RGB crop of 40 pixels shows that poorly, the
camera's depth directly. Appearance still decides *which* product a box holds (the query module
sees only RGB, so shop photos need no depth); geometry is added to the fused features of every level,
before the neck decides objectness. The projections start at zero, so a detector fine-tuned with
depth from RGB-only weights starts as exactly that detector.

Measured on binpick's default bins it did not help: fine-tuned alike, colour alone and colour with
depth both reach val AP50 0.80 (`the `rod_seen_gap` note (docs/notes.md)`). It is off by default.
"""

from __future__ import annotations

import numpy as np
import torch
from PIL import Image
from torch import nn

from binpick.detection.backbone import conv_bn

HEIGHT_UNIT = 0.05  # metres: heights above the bin's median surface, in units of 5 cm
HEIGHT_CLIP = 4.0  # units: ±20 cm covers a tote's contents; beyond it is wall or floor


def depth_input(depth: np.ndarray, size: int) -> np.ndarray:
    """A depth image in metres (H, W; 0 or non-finite: no reading) as the network's input: float32
    (size, size), the height of each pixel above the scene's median depth in HEIGHT_UNITs, clipped.
    Relative heights do not depend on how high the camera hangs; missing readings read as the median."""
    depth = np.asarray(depth, dtype=np.float32)
    valid = np.isfinite(depth) & (depth > 0)
    median = float(np.median(depth[valid])) if valid.any() else 0.0
    heights = np.where(valid, (median - depth) / HEIGHT_UNIT, 0.0).astype(np.float32)
    heights = np.clip(heights, -HEIGHT_CLIP, HEIGHT_CLIP)
    return np.array(Image.fromarray(heights, mode="F").resize((size, size), Image.BILINEAR), dtype=np.float32)


class DepthEncoder(nn.Module):
    """A small strided network on the height map: features at strides 8, 16 and 32 with the
    channels of the detector's levels, from zero-initialised projections."""

    def __init__(self, channels: tuple[int, int, int]) -> None:
        super().__init__()
        self.to_stride8 = nn.Sequential(conv_bn(1, 8, 3, 2), conv_bn(8, 16, 3, 2), conv_bn(16, 32, 3, 2))
        self.to_stride16 = conv_bn(32, 64, 3, 2)
        self.to_stride32 = conv_bn(64, 128, 3, 2)
        self.projections = nn.ModuleList([nn.Conv2d(c_in, c_out, 1) for c_in, c_out in zip((32, 64, 128), channels)])
        for projection in self.projections:
            nn.init.zeros_(projection.weight)
            nn.init.zeros_(projection.bias)

    def forward(self, heights: torch.Tensor) -> list[torch.Tensor]:
        """(B, 1, H, W) heights -> per level (B, C_l, H / s, W / s)."""
        s8 = self.to_stride8(heights)
        s16 = self.to_stride16(s8)
        s32 = self.to_stride32(s16)
        return [projection(x) for projection, x in zip(self.projections, (s8, s16, s32))]

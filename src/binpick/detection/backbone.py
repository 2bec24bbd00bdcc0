"""Fully convolutional feature extractors with feature maps at strides 8, 16 and 32.

``darknet53`` is YOLOv3's backbone as the thesis uses it (Fig 5.9: residual blocks 1-2-8-8-4,
widths 64-1024). ``tiny`` is the same design, narrower and shallower, for training and inference on
a laptop CPU; ``small`` is tiny at 1.5 times the width (the AP / latency trade-off is measured in
``experiments/rod.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn


@dataclass(frozen=True)
class BackboneSpec:
    width: int  # channels of the stem; each stage doubles them
    blocks: tuple[int, int, int, int, int]  # residual blocks per stage (strides 2, 4, 8, 16, 32)

    @property
    def channels(self) -> tuple[int, int, int]:
        """Channels of the stride-8, -16 and -32 feature maps."""
        return self.width * 8, self.width * 16, self.width * 32


BACKBONES = {
    "darknet53": BackboneSpec(32, (1, 2, 8, 8, 4)),
    "tiny": BackboneSpec(8, (1, 1, 2, 2, 1)),
    "small": BackboneSpec(12, (1, 1, 2, 2, 1)),  # tiny at 1.5x the width: ~2.2x the compute
}


def conv_bn(c_in: int, c_out: int, kernel: int = 3, stride: int = 1) -> nn.Sequential:
    """Darknet's unit: convolution, batch norm, leaky ReLU (0.1)."""
    return nn.Sequential(nn.Conv2d(c_in, c_out, kernel, stride, kernel // 2, bias=False),
                         nn.BatchNorm2d(c_out), nn.LeakyReLU(0.1, inplace=True))


class Residual(nn.Module):
    def __init__(self, channels: int) -> None:
        super().__init__()
        self.body = nn.Sequential(conv_bn(channels, channels // 2, 1), conv_bn(channels // 2, channels, 3))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


class Darknet(nn.Module):
    """Stem, then five stages that each halve the resolution (stride-2 conv) and add residual
    blocks; returns the last three stages' outputs."""

    def __init__(self, spec: BackboneSpec) -> None:
        super().__init__()
        self.spec = spec
        self.stem = conv_bn(3, spec.width, 3)
        stages, channels = [], spec.width
        for blocks in spec.blocks:
            layers = [conv_bn(channels, channels * 2, 3, stride=2)]
            channels *= 2
            layers += [Residual(channels) for _ in range(blocks)]
            stages.append(nn.Sequential(*layers))
        self.stages = nn.ModuleList(stages)

    def forward(self, images: torch.Tensor) -> list[torch.Tensor]:
        x = self.stem(images)
        features = []
        for index, stage in enumerate(self.stages):
            x = stage(x)
            if index >= 2:
                features.append(x)
        return features  # strides 8, 16, 32


def build_backbone(name: str) -> Darknet:
    return Darknet(BACKBONES[name])

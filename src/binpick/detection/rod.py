"""The Repeated Object Detection module (thesis §5.3.1, Fig 5.6, Eq 5.11-5.12) and its stand-ins.

Per feature level: the query's features (the known box's crop of the scene features, Eq 5.11, or a
shop photo's features, §6.3) are resized to ``D`` scales; each is cross-correlated with the scene
features; the pixelwise maximum over scales is the heatmap (Eq 5.12), which is concatenated to the
features and convolved. Features are L2-normalised per position and the correlation divided by the
kernel's size, so a heatmap value is the mean cosine similarity, in [-1, 1] — the Gaussian targets of
the heatmap loss then have a fixed scale whatever the backbone.

``SkipModule`` (the "S" of Fig 5.12's RSS/SSR labels) passes the features on without any query;
``TDIDModule`` is the baseline of Ammirato et al. (2018) on the same features.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from binpick.detection.backbone import conv_bn

MAX_KERNEL = 15  # cells: larger crops are shrunk (a query never spans more than this of a map)


def _odd(cells: float) -> int:
    """Kernel sides are odd, 1..MAX_KERNEL, so 'same' padding is symmetric."""
    return int(min(MAX_KERNEL, max(1, 2 * round((cells - 1) / 2) + 1)))


def crop_features(features: torch.Tensor, box: torch.Tensor, stride: int) -> torch.Tensor:
    """Eq 5.11: the cells of one feature map (C, H, W) that the image box (x1, y1, x2, y2) covers,
    at least one cell."""
    _, height, width = features.shape
    x1 = int(torch.clamp(torch.floor(box[0] / stride), 0, width - 1))
    y1 = int(torch.clamp(torch.floor(box[1] / stride), 0, height - 1))
    x2 = int(torch.clamp(torch.ceil(box[2] / stride), x1 + 1, width))
    y2 = int(torch.clamp(torch.ceil(box[3] / stride), y1 + 1, height))
    return features[:, y1:y2, x1:x2]


def scaled_kernels(crop: torch.Tensor, scales: tuple[float, ...]) -> list[torch.Tensor]:
    """The crop resized to each scale (Fig 5.6 D), at least 1 and at most ``MAX_KERNEL`` cells."""
    _, h, w = crop.shape
    kernels = []
    for scale in scales:
        size = (_odd(h * scale), _odd(w * scale))
        kernel = crop if size == (h, w) else F.interpolate(crop[None], size=size, mode="bilinear", align_corners=False)[0]
        kernels.append(kernel)
    return kernels


def correlate(features: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """Mean cosine similarity of ``kernel`` (C, h, w) at every position of ``features`` (C, H, W),
    both already normalised per position: (H, W)."""
    out = F.conv2d(features[None], kernel[None], padding="same")
    return out[0, 0] / (kernel.shape[1] * kernel.shape[2])


class RODModule(nn.Module):
    """Heatmap of the query over the scene at ``scales``; features + heatmap -> convolutions."""

    def __init__(self, channels: int, scales: tuple[float, ...] = (0.5, 1.0, 2.0)) -> None:
        super().__init__()
        self.scales = tuple(scales)
        self.fuse = nn.Sequential(conv_bn(channels + 1, channels, 1), conv_bn(channels, channels, 3))

    def heatmaps(self, features: torch.Tensor, queries: list[torch.Tensor]) -> torch.Tensor:
        """Eq 5.12 for a batch: (B, 1, H, W). ``queries[b]`` is sample b's query features (C, h, w)."""
        mean = features.mean(dim=(2, 3), keepdim=True)
        normalised = F.normalize(features - mean, dim=1)
        maps = []
        for b, query in enumerate(queries):
            query = query - mean[b]
            per_scale = [correlate(normalised[b], F.normalize(k, dim=0)) for k in scaled_kernels(query, self.scales)]
            maps.append(torch.stack(per_scale).amax(0))
        return torch.stack(maps)[:, None]

    def forward(self, features: torch.Tensor, queries: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        heatmap = self.heatmaps(features, queries)
        return self.fuse(torch.cat([features, heatmap], 1)), heatmap


class SkipModule(nn.Module):
    """A plain skip connection: the level's features, no query (the "S" of RSS, SSR, ...)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.fuse = conv_bn(channels, channels, 3)

    def forward(self, features: torch.Tensor, queries: list[torch.Tensor]) -> tuple[torch.Tensor, None]:
        return self.fuse(features), None


class TDIDModule(nn.Module):
    """TDID (Ammirato et al. 2018) on our backbone: the target's features cross-correlated depthwise
    with the scene's, and the scene features minus the globally max-pooled target features, both
    concatenated with the scene features, then convolutions. Queries are target *image* features."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.fuse = nn.Sequential(conv_bn(3 * channels, channels, 1), conv_bn(channels, channels, 3))

    def forward(self, features: torch.Tensor, queries: list[torch.Tensor]) -> tuple[torch.Tensor, None]:
        correlations, differences = [], []
        for b, target in enumerate(queries):
            kernel = target[:, None]  # (C, 1, h, w): one filter per channel
            correlation = F.conv2d(features[b:b + 1], kernel, padding="same", groups=features.shape[1])
            correlations.append(correlation[0] / (target.shape[1] * target.shape[2]))
            differences.append(features[b] - target.amax(dim=(1, 2))[:, None, None])
        return self.fuse(torch.cat([features, torch.stack(correlations), torch.stack(differences)], 1)), None

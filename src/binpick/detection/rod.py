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
    h, w = (int(n) for n in crop.shape[1:])  # int(): constants when traced for export
    kernels = []
    for scale in scales:
        size = (_odd(h * scale), _odd(w * scale))
        kernel = crop if size == (h, w) else F.interpolate(crop[None], size=size, mode="bilinear", align_corners=False)[0]
        kernels.append(kernel)
    return kernels


def _framed(kernels: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Kernels of different sizes in one odd-sized frame (B, C, K_h, K_w), each placed where
    PyTorch's 'same' padding would centre it alone (so even sizes keep their alignment), zeros
    elsewhere; and each kernel's own area (B,)."""
    height = max(int(k.shape[1]) for k in kernels) | 1  # the next odd number (int(): constants when traced)
    width = max(int(k.shape[2]) for k in kernels) | 1
    framed, areas = [], []
    for k in kernels:
        h, w = int(k.shape[1]), int(k.shape[2])
        top, left = (height - 1) // 2 - (h - 1) // 2, (width - 1) // 2 - (w - 1) // 2
        framed.append(F.pad(k, (left, width - w - left, top, height - h - top)))
        areas.append(h * w)
    return torch.stack(framed), torch.tensor(areas, dtype=kernels[0].dtype, device=kernels[0].device)


def _fft_correlate(features: torch.Tensor, weight: torch.Tensor, sum_channels: bool) -> torch.Tensor:
    """Cross-correlation with 'same' zero padding through the FFT: ``features`` (..., C, H, W) with
    ``weight`` (..., C, k_h, k_w), odd sides, leading dimensions broadcast (features (B, 1, C, H, W)
    against D kernels per sample (B, D, C, ...) transform each sample's features once). On a CPU this
    is ~10x faster than a grouped convolution, whose backward pass oneDNN runs slowly for large
    kernels; the result is the same up to rounding (the transform is zero-padded to H + k - 1, so
    nothing wraps around). ``sum_channels``: summed over C."""
    height, width = features.shape[-2:]
    kh, kw = weight.shape[-2:]
    size = (height + kh - 1, width + kw - 1)
    with torch.autocast(features.device.type, enabled=False):  # transforms in float32 whatever the caller's autocast
        spectrum = torch.fft.rfft2(features.float(), s=size) * torch.fft.rfft2(weight.float(), s=size).conj()
        if sum_channels:
            spectrum = spectrum.sum(-3)
        out = torch.fft.irfft2(spectrum, s=size)
    return torch.roll(out, shifts=(kh // 2, kw // 2), dims=(-2, -1))[..., :height, :width]


def correlate_batch(features: torch.Tensor, kernels: list[torch.Tensor]) -> torch.Tensor:
    """Mean cosine similarity of each sample's kernel (C, h, w) at every position of its features
    (B, C, H, W), both already normalised per position, in one call: (B, H, W)."""
    return correlate_scales(features, [[k] for k in kernels])[:, 0]


def correlate_scales(features: torch.Tensor, kernels: list[list[torch.Tensor]]) -> torch.Tensor:
    """:func:`correlate_batch` for D kernels per sample (``kernels[b]``: its D kernels (C, h, w)),
    all in one frame, so each sample's features are transformed once, not once per scale (the
    transforms were two thirds of the ROD modules' time at inference): (B, D, H, W)."""
    batch, scales = len(kernels), len(kernels[0])
    weight, areas = _framed([k for sample in kernels for k in sample])  # (B·D, C, k_h, k_w)
    out = _fft_correlate(features[:, None], weight.view(batch, scales, *weight.shape[1:]), sum_channels=True)
    return out / areas.float().view(batch, scales, 1, 1)


class RODModule(nn.Module):
    """Heatmap of the query over the scene at ``scales``; features + heatmap -> convolutions."""

    def __init__(self, channels: int, scales: tuple[float, ...] = (0.5, 1.0, 2.0)) -> None:
        super().__init__()
        self.scales = tuple(scales)
        self.fuse = nn.Sequential(conv_bn(channels + 1, channels, 1), conv_bn(channels, channels, 3))

    def heatmaps(self, features: torch.Tensor, queries: list[torch.Tensor]) -> torch.Tensor:
        """Eq 5.12 for a batch: (B, 1, H, W). ``queries[b]`` is sample b's query features (C, h, w),
        resized to the D scales; or a tuple of them (a photo at several sizes), each used as it is."""
        mean = features.mean(dim=(2, 3), keepdim=True)
        normalised = F.normalize(features - mean, dim=1)
        kernels = [[F.normalize(k, dim=0) for k in self.kernels(query, m)] for query, m in zip(queries, mean.unbind(0))]
        return correlate_scales(normalised, kernels).amax(1, keepdim=True).to(features.dtype)

    def kernels(self, query: torch.Tensor | tuple[torch.Tensor, ...], mean: torch.Tensor) -> list[torch.Tensor]:
        if isinstance(query, tuple):
            return [k for q in query for k in scaled_kernels(q - mean, (1.0,))]  # capped at MAX_KERNEL cells
        return scaled_kernels(query - mean, self.scales)

    def forward(self, features: torch.Tensor, queries: list) -> tuple[torch.Tensor, torch.Tensor]:
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
        weight, areas = _framed(queries)  # one depthwise filter per channel and sample, in one call
        correlation = (_fft_correlate(features, weight, sum_channels=False) / areas.float()[:, None, None, None]).to(features.dtype)
        differences = features - torch.stack([target.amax(dim=(1, 2)) for target in queries])[:, :, None, None]
        return self.fuse(torch.cat([features, correlation, differences], 1)), None

"""Auto-perception networks (thesis §4.3): an AE or VAE whose latent is partly tied to the semantic state.

The encoder is 6 stride-2 convolutions and one fully connected layer to an n-dimensional latent;
the decoder is one fully connected layer and 6 transposed convolutions (§4.3.1). The first m latent
dimensions are conditioned on the semantic state s̄ with an L1 loss (Eq 4.2), weighted by ω (Eq 4.3).
The VAE (§4.3.2, Fig 4.4) predicts μ for all n dimensions but σ only for the n − m free ones: the
conditioned part is μ^{1:m} itself, and the KL term (weight β) covers only the free part (Eq 4.6).

The semantic state is standardised inside the network (mean/std of the training data are buffers),
so one ω suits positions in metres and in pixels alike; :meth:`AutoPerception.encode` returns the
conditioned part in the semantic state's own units, ready for a policy trained on s̄.

``free_features: keypoints`` (AE only; not the thesis's) reads the n − m free dimensions as the
expected image positions (x, y) of (n − m)/2 heat maps -- a spatial soft-argmax -- instead of a slice
of the fully connected layer: the free part then carries *where* something is, the same way wherever
it is. The heat maps look at what the decoder cannot draw from the conditioned part alone (which
L_VP also asks it to draw as well as it can), and the decoder draws a blob at each keypoint, so the
free features go to what s̄ does not place. With the thesis's flattening layer the free dimensions of
FetchReachObstacle carried nothing of the box (a linear probe found it no better from them than from
s̄); with keypoints they carry part of it (docs/RESULTS.md, Table 4.4).

``goal_keypoints: K`` (not the thesis's either) adds to the conditioned part what a small MLP
reads from the expected positions of K heat maps over the image itself, one per stacked camera view:
the fully connected layer gives every place in the picture its own weights and reads a goal sphere
a few pixels wide only to ~2 cm per axis in FetchReachObstacle, where a student needs ~0.5 cm to
gain from knowing the box (the `april_diagnosis` note (docs/notes.md)); a soft-argmax finds a small
object to a fraction of a pixel wherever it is. Given where s̄'s goal lies in each view (``points``,
projected with the cameras' poses) L_cond also asks each keypoint to sit there -- s̄ itself, in the
image's coordinates: left to find the goal through the MLP alone the maps spread over the whole
arm. At deployment only the image is read.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from binpick.core.config import check_choice, check_range
from binpick.core.errors import ConfigError

LAYERS = 6  # stride-2 convolutions in the encoder, transposed ones in the decoder (thesis §4.3.1)
DRAW_AT = LAYERS - 2  # free keypoints enter the decoder before its last two layers (16 x 16 for 64 px)
BLOB_SIGMA = 0.1  # the drawn blob's width, in the image's [-1, 1] units (0.8 cells at 16 x 16)


@dataclass(frozen=True)
class PerceptionConfig:
    """The network and its loss: kind, latent size n, conditioned size m, ω and β."""

    kind: str = "ae"  # "ae" or "vae"
    latent: int = 6  # n
    conditioned: int = 6  # m: the first m latent dimensions are tied to the semantic state (0 = none)
    omega: float = 1.0  # ω: weight of the conditioning (and, for the VAE, KL) loss
    beta: float = 1e-3  # β: weight of the KL term on the free dimensions (VAE only)
    channels: int = 32  # width of the first convolution; doubles every other layer
    # λ: L_recon weighs 1 + λ on pixels that differ from the training images' median (the goal, a box,
    # the arm): over the whole image an L1 lets the decoder leave out objects of a few dozen pixels,
    # and then no free latent carries them (0: the thesis's plain L1)
    foreground_weight: float = 0.0
    # how the n − m free dimensions are read: "dense" (the thesis's fully connected layer) or
    # "keypoints" (expected (x, y) of (n − m)/2 heat maps in [-1, 1]; AE only)
    free_features: str = "dense"
    # K: heat maps over the image whose expected (x, y), through a small MLP, add to the conditioned
    # part; one per camera view, each trained to sit on s̄'s goal in its view (0: the fully connected
    # layer alone, as in the thesis)
    goal_keypoints: int = 0
    # free keypoints look at the first this-many image channels only (0: all): with stacked views, the
    # first view's (e.g. 3 for RGB), where the other view holds something large that s̄ draws poorly
    free_keypoint_channels: int = 0

    def __post_init__(self) -> None:
        check_choice("perception.kind", self.kind, ["ae", "vae"])
        check_range("perception.latent (n)", self.latent, 1, 1024, integer=True)
        check_range("perception.conditioned (m)", self.conditioned, 0, None, integer=True)
        if self.conditioned > self.latent:
            raise ConfigError(f"perception.conditioned (m={self.conditioned}) must be <= perception.latent "
                              f"(n={self.latent}): the conditioned part is a slice of the latent")
        check_range("perception.omega", self.omega, 0.0, 1e6)
        check_range("perception.beta", self.beta, 0.0, 1e6)
        check_range("perception.channels", self.channels, 1, 512, integer=True)
        check_range("perception.foreground_weight", self.foreground_weight, 0.0, 1e4)
        check_choice("perception.free_features", self.free_features, ["dense", "keypoints"])
        check_range("perception.goal_keypoints", self.goal_keypoints, 0, 64, integer=True)
        check_range("perception.free_keypoint_channels", self.free_keypoint_channels, 0, 64, integer=True)
        if self.free_keypoint_channels and self.free_features != "keypoints":
            raise ConfigError("perception.free_keypoint_channels chooses what free keypoints look at: it needs "
                              "perception.free_features: keypoints")
        if self.goal_keypoints and not self.conditioned:
            raise ConfigError("perception.goal_keypoints needs a conditioned part (perception.conditioned "
                              "m >= 1): the keypoints are read into it")
        if self.free_features == "keypoints":
            if self.kind != "ae":
                raise ConfigError("perception.free_features: keypoints is for kind: ae (a VAE's σ has no "
                                  "meaning for a heat map's expected position)")
            if self.free < 2 or self.free % 2:
                raise ConfigError(f"perception.free_features: keypoints reads (x, y) pairs: n − m must be an even "
                                  f"number >= 2, got {self.free}")

    @property
    def free(self) -> int:
        return self.latent - self.conditioned


def _heat_map_net(channels: int, width: int, maps: int) -> nn.Sequential:
    """Heat maps at half resolution; the dilations see an object a few pixels wide whole."""
    edge = {"padding_mode": "replicate"}  # zero padding would light every map up along the border
    net = nn.Sequential(
        nn.Conv2d(channels, width, 5, stride=2, padding=2, **edge), nn.ReLU(),
        nn.Conv2d(width, width, 3, padding=1, **edge), nn.ReLU(),
        nn.Conv2d(width, width, 3, padding=2, dilation=2, **edge), nn.ReLU(),
        nn.Conv2d(width, maps, 1),
    )
    with torch.no_grad():  # positive weights: at first each map peaks where the input is strongest
        for layer in net:
            if isinstance(layer, nn.Conv2d):
                layer.weight.abs_()
    return net


def _widths(base: int) -> list[int]:
    return [base * 2 ** (i // 2) for i in range(LAYERS)]  # e.g. 32 32 64 64 128 128


class AutoPerception(nn.Module):
    """φ_enc: image -> latent s (n), φ_dec: s -> image; images are uint8 (B, H, W, C) in, float out."""

    def __init__(self, config: PerceptionConfig, image_shape: tuple[int, int, int], state_dim: int) -> None:
        super().__init__()
        height, width, channels = image_shape
        if height != width or height % 2 ** LAYERS:
            raise ConfigError(f"perception needs square images whose side is a multiple of {2 ** LAYERS}, "
                              f"got {height}x{width}")
        if config.conditioned > state_dim:
            raise ConfigError(f"perception.conditioned (m={config.conditioned}) exceeds the semantic state's "
                              f"{state_dim} dimensions")
        self.config, self.image_shape, self.state_dim = config, tuple(image_shape), state_dim
        widths = _widths(config.channels)
        encoder, previous = [], channels
        for width_out in widths:
            encoder += [nn.Conv2d(previous, width_out, 4, stride=2, padding=1), nn.ReLU()]
            previous = width_out
        self.encoder = nn.Sequential(*encoder, nn.Flatten())
        self.side = height // 2 ** LAYERS
        flat = widths[-1] * self.side * self.side
        n, free = config.latent, config.free
        if config.free_features == "keypoints" or config.goal_keypoints:
            side = (height + 1) // 2  # the heat maps' resolution
            self.register_buffer("cell_centres", (torch.arange(side, dtype=torch.float32) + 0.5) / side * 2 - 1)
        if config.goal_keypoints:
            k = config.goal_keypoints
            self.goal_maps = _heat_map_net(channels, config.channels, k)  # sees the image: what s̄ places
            self.goal_sharpness = nn.Parameter(torch.tensor(float(np.log(3.0))))
            self.from_points = nn.Sequential(nn.Linear(2 * k, 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU(),
                                             nn.Linear(64, config.conditioned))  # image places -> s̄ (perspective)
        if config.free_features == "keypoints":  # the fully connected layer gives only the m conditioned ones
            self.to_latent = nn.Linear(flat, config.conditioned)
            if config.free_keypoint_channels > channels:
                raise ConfigError(f"perception.free_keypoint_channels ({config.free_keypoint_channels}) exceeds the "
                                  f"images' {channels} channels")
            self.seen_by_free = config.free_keypoint_channels or channels
            self.heat_maps = _heat_map_net(self.seen_by_free, config.channels, free // 2)  # sees what s̄ leaves out
            self.sharpness = nn.Parameter(torch.tensor(float(np.log(3.0))))  # log of the softmax's inverse temperature
        else:
            self.to_latent = nn.Linear(flat, n + (free if config.kind == "vae" else 0))  # μ (n) and log σ (n − m)
        self.from_latent = nn.Linear(config.conditioned if config.free_features == "keypoints" else n, flat)
        decoder = []
        for layer, (width_in, width_out) in enumerate(zip(widths[::-1], [*widths[::-1][1:], channels])):
            if layer == DRAW_AT and config.free_features == "keypoints":
                width_in += free // 2  # a blob at each keypoint joins the decoder at 1/4 resolution
            decoder += [nn.ConvTranspose2d(width_in, width_out, 4, stride=2, padding=1), nn.ReLU()]
        decoder[-1] = nn.Sigmoid()
        self.decoder = nn.Sequential(*decoder)
        self.register_buffer("state_mean", torch.zeros(config.conditioned))
        self.register_buffer("state_std", torch.ones(config.conditioned))
        if config.foreground_weight:  # the median training image, against which "foreground" is judged
            self.register_buffer("background", torch.zeros(channels, height, width))

    # ------------------------------------------------------------------ data
    def set_state_statistics(self, states: np.ndarray) -> None:
        """Standardise s̄^{1:m} with the training data's statistics (kept with the weights)."""
        m = self.config.conditioned
        if m:
            part = torch.as_tensor(np.asarray(states)[:, :m], dtype=torch.float32)
            self.state_mean.copy_(part.mean(0))
            self.state_std.copy_(part.std(0).clamp_min(1e-3))

    def set_background(self, images: np.ndarray, sample: int = 2000) -> None:
        """The per-pixel median of (up to ``sample`` of) the training images, for ``foreground_weight``."""
        images = np.asarray(images)
        picked = np.random.default_rng(0).choice(len(images), min(sample, len(images)), replace=False)
        self.background.copy_(self._pixels(np.median(images[np.sort(picked)], axis=0).astype(np.uint8))[0])

    def _pixels(self, images: torch.Tensor | np.ndarray) -> torch.Tensor:
        images = torch.as_tensor(np.asarray(images) if not torch.is_tensor(images) else images)
        if images.dim() == 3:
            images = images[None]
        if tuple(images.shape[1:]) != self.image_shape:
            raise ConfigError(f"perception expects images of shape {self.image_shape} (H, W, C), "
                              f"got {tuple(images.shape[1:])}")
        return images.permute(0, 3, 1, 2).float() / 255.0

    # ------------------------------------------------------------------ network
    def forward(self, images, sample: bool = True) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(latent s used by the decoder, μ, log σ of the free part) for a batch of uint8 images."""
        return self._encode(self._pixels(images), sample)[:3]

    def _encode(self, pixels: torch.Tensor, sample: bool = True):
        """:meth:`forward`, then for free keypoints the conditioned part's own drawing and for goal
        keypoints their places (each None when there are none)."""
        output = self.to_latent(self.encoder(pixels))
        points = None
        if self.config.goal_keypoints:
            m, points = self.config.conditioned, self.goal_points(pixels)
            output = torch.cat([output[:, :m] + self.from_points(points), output[:, m:]], dim=1)
        alone = None
        if self.config.free_features == "keypoints":
            alone = self._draw(output, None)
            unexplained = (pixels - alone.detach())[:, :self.seen_by_free]
            output = torch.cat([output, self._keypoints(unexplained)], dim=1)
        n, m = self.config.latent, self.config.conditioned
        mu = output[:, :n]
        if self.config.kind == "ae":
            return mu, mu, output[:, n:], alone, points
        log_sigma = output[:, n:].clamp(-10, 4)
        latent = mu
        if sample and self.training:
            noise = torch.randn_like(log_sigma) * log_sigma.exp()
            latent = torch.cat([mu[:, :m], mu[:, m:] + noise], dim=1)  # σ only on the free part (Fig 4.4)
        return latent, mu, log_sigma, alone, points

    def _keypoints(self, unexplained: torch.Tensor) -> torch.Tensor:
        """(B, n − m): x1, y1, x2, y2, ... the expected position of each heat map (image right / down, [-1, 1]).

        The heat maps see what the decoder cannot draw from the conditioned part alone (the image less
        that drawing, no gradient through it), not the image: shown the image, a keypoint settles on the
        most salient thing, often one s̄ already places, and the free features repeat s̄."""
        return self._soft_argmax(self.heat_maps(unexplained.abs()), self.sharpness)

    def goal_points(self, pixels: torch.Tensor) -> torch.Tensor:
        """(B, 2K): the expected (x, y) of each ``goal_keypoints`` heat map over the image."""
        return self._soft_argmax(self.goal_maps(pixels), self.goal_sharpness)

    def _soft_argmax(self, maps: torch.Tensor, sharpness: torch.Tensor) -> torch.Tensor:
        b, k, h, w = maps.shape
        logits = maps.view(b, k, h * w)
        # standardised over the image, then sharpened: from the first step each keypoint sits on what its
        # map responds to most and moves with it (a near-uniform softmax would pin every one to the centre)
        logits = (logits - logits.mean(-1, keepdim=True)) / (logits.std(-1, keepdim=True) + 1e-6)
        weights = F.softmax(logits * sharpness.exp(), -1).view(b, k, h, w)
        xs = (weights.sum(2) * self.cell_centres).sum(-1)
        ys = (weights.sum(3) * self.cell_centres).sum(-1)
        return torch.stack([xs, ys], -1).view(b, 2 * k)

    def decode(self, latent: torch.Tensor) -> torch.Tensor:
        if self.config.free_features != "keypoints":
            features = F.relu(self.from_latent(latent).view(len(latent), -1, self.side, self.side))
            return self.decoder(features)
        m = self.config.conditioned
        return self._draw(latent[:, :m], latent[:, m:])

    def _draw(self, conditioned: torch.Tensor, points: torch.Tensor | None) -> torch.Tensor:
        """The keypoint decoder: the conditioned part through the fully connected layer, and a blob at
        each free keypoint (none when ``points`` is None): the free part is drawn only where it points."""
        free, latent = self.config.free, conditioned
        features = F.relu(self.from_latent(latent).view(len(latent), -1, self.side, self.side))
        # a Gaussian blob at each free keypoint, drawn where the decoder can paint around it with its
        # convolutions (as landmark autoencoders do): a coordinate read by a fully connected layer
        # would have to be learnt anew for every place the object can be
        split = 2 * DRAW_AT
        hidden = self.decoder[:split](features)
        side = hidden.shape[-1]
        centres = (torch.arange(side, dtype=latent.dtype) + 0.5) / side * 2 - 1
        if points is None:
            blobs = torch.zeros(len(latent), free // 2, side, side)
        else:
            points = points.reshape(len(latent), -1, 2)
            dx = (centres.view(1, 1, side) - points[..., :1]) ** 2  # (B, K, W)
            dy = (centres.view(1, 1, side) - points[..., 1:]) ** 2  # (B, K, H)
            blobs = torch.exp(-(dy[..., :, None] + dx[..., None, :]) / (2 * BLOB_SIGMA ** 2))
        return self.decoder[split:](torch.cat([hidden, blobs], dim=1))

    def loss(self, images, states: torch.Tensor | None, points=None) -> dict[str, torch.Tensor]:
        """L_VP = L_recon + ω (L_cond + β KL_free) (Eq 4.1–4.7); per-element means, so sizes do not matter.
        ``points`` (B, 2K): where s̄'s goal lies in each view, for ``goal_keypoints`` (L_cond gains their
        L1 to the keypoints). Also gives ``mu``, the encoder's output, for losses on the features themselves."""
        target = self._pixels(images)
        latent, mu, log_sigma, alone, found = self._encode(target)
        recon = self._reconstruction_error(self.decode(latent), target)
        m = self.config.conditioned
        cond = torch.zeros(())
        if m and states is not None:
            normalised = (torch.as_tensor(states, dtype=torch.float32)[:, :m] - self.state_mean) / self.state_std
            cond = (mu[:, :m] - normalised).abs().mean()
        if points is not None and self.config.goal_keypoints:
            points = torch.as_tensor(points, dtype=torch.float32)
            if points.shape[1:] != (2 * self.config.goal_keypoints,):
                raise ConfigError(f"perception.goal_keypoints: {self.config.goal_keypoints} keypoints need the goal's "
                                  f"(x, y) in as many views, got {points.shape[1]} coordinates")
            cond = cond + (found - points).abs().mean()
        kl = torch.zeros(())
        if self.config.kind == "vae" and self.config.free:
            free_mu = mu[:, m:]
            kl = 0.5 * (torch.exp(2 * log_sigma) + free_mu ** 2 - 2 * log_sigma - 1).sum(1).mean()
        extra = cond + self.config.beta * kl if self.config.kind == "vae" else cond
        total = recon + self.config.omega * extra
        if self.config.free_features == "keypoints":  # the conditioned part alone must draw what it can,
            # so that what it leaves out -- what the keypoints look at -- is what s̄ does not place
            total = total + self._reconstruction_error(alone, target)
        return {"total": total, "recon": recon, "cond": cond, "kl": kl, "mu": mu}

    def _reconstruction_error(self, drawn: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """L_recon: the mean L1, or with ``foreground_weight`` λ weighted 1 + λ off the median image."""
        error = (drawn - target).abs()
        if not self.config.foreground_weight:
            return error.mean()
        foreground = ((target - self.background).abs().amax(dim=1, keepdim=True) > 0.1).float()
        weight = (1 + self.config.foreground_weight * foreground).expand_as(error)
        return (weight * error).sum() / weight.sum()  # a weighted mean: same scale as the plain L1

    # ------------------------------------------------------------------ deployment
    def features(self, mu: torch.Tensor) -> torch.Tensor:
        """μ as a policy reads it (differentiable :meth:`encode`): the conditioned part in s̄'s units."""
        m = self.config.conditioned
        return torch.cat([mu[:, :m] * self.state_std + self.state_mean, mu[:, m:]], dim=1)

    @torch.no_grad()
    def encode(self, images) -> np.ndarray:
        """φ_enc(I): (B, n) with the conditioned part in the semantic state's units (the VAE gives μ)."""
        _, mu, _ = self(images, sample=False)
        return self.features(mu).numpy()

    @torch.no_grad()
    def reconstruct(self, images) -> np.ndarray:
        """φ_dec(φ_enc(I)) as uint8 images (B, H, W, C), for reconstruction grids."""
        latent, _, _ = self(images, sample=False)  # no dropout or batch norm: sample=False is deterministic
        pixels = self.decode(latent).permute(0, 2, 3, 1).clamp(0, 1) * 255
        return pixels.round().to(torch.uint8).numpy()

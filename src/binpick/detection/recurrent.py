"""The recurrent repeated-object detector the thesis tried first and set aside (§5.2), kept as a
baseline beside ROD: a convolutional encoder, then a decoder of convolutional LSTMs that predicts one
instance mask per step and a stop flag, conditioned here on the query (the crop of one copy).

Eq 5.3: ``U_{i,t} = convLSTM_i([U_2(U_{i-1,t}) | F_i], U_{i,t-1})``, deepest level first; a final
convolution on the last LSTM's output gives the step's mask, and the outputs of every LSTM, pooled
and concatenated, go through one linear layer to the step's objectness ``v_t``. The losses (Eq
5.4-5.9) are in :func:`recurrent_loss`. binpick's data sets hold boxes, not instance masks, so the
masks to predict are the boxes filled (a detection is the box round the mask's largest blob).

The encoder is ROD's backbone (:mod:`binpick.detection.backbone`); the query conditions every level
as in TDID, by the features' product with the query crop's mean feature and their cosine similarity
to it. Three levels (strides 32, 16, 8) where the thesis's encoder had five.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from binpick.detection.backbone import BACKBONES, build_backbone, conv_bn
from binpick.detection.rod import crop_features

STRIDES = (8, 16, 32)
MASK_STRIDE = 4  # masks at a quarter of the image's side
MEAN = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
STD = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)


@dataclass(frozen=True)
class RecurrentSpec:
    backbone: str = "tiny"
    hidden: tuple[int, int, int] = (48, 32, 24)  # convLSTM channels at strides 32, 16, 8
    max_steps: int = 8  # instances one image can yield (the decoder's roll-out at prediction)
    latent: int = 32  # the similarity network's latent space (§5.2.2)

    def check(self) -> None:
        from binpick.core.errors import ConfigError

        if self.backbone not in BACKBONES:
            raise ConfigError(f"model.backbone must be one of {', '.join(BACKBONES)}, got {self.backbone!r}")
        if len(self.hidden) != 3 or any(int(h) != h or h < 4 for h in self.hidden):
            raise ConfigError(f"model.hidden must be three channel counts of at least 4, got {list(self.hidden)}")
        if int(self.max_steps) != self.max_steps or not 1 <= self.max_steps <= 64:
            raise ConfigError(f"model.max_steps must be a whole number in [1, 64], got {self.max_steps!r}")
        if int(self.latent) != self.latent or not 2 <= self.latent <= 512:
            raise ConfigError(f"model.latent must be a whole number in [2, 512], got {self.latent!r}")


class ConvLSTMCell(nn.Module):
    """An LSTM whose gates are convolutions, so its state keeps the image's layout."""

    def __init__(self, c_in: int, c_hidden: int) -> None:
        super().__init__()
        self.hidden = c_hidden
        self.gates = nn.Conv2d(c_in + c_hidden, 4 * c_hidden, 3, padding=1)

    def forward(self, x: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor] | None
                ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        if state is None:
            h = c = x.new_zeros(x.shape[0], self.hidden, *x.shape[-2:])
        else:
            h, c = state
        i, f, o, g = self.gates(torch.cat([x, h], 1)).chunk(4, 1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(c)
        return h, (h, c)


class QueryCondition(nn.Module):
    """Scene features made about the query: the features, their product with the query's mean
    feature, and their cosine similarity to it, mixed by a 1x1 convolution."""

    def __init__(self, channels: int, out: int) -> None:
        super().__init__()
        self.mix = conv_bn(2 * channels + 1, out, 1)

    def forward(self, features: torch.Tensor, query: torch.Tensor) -> torch.Tensor:
        q = query[:, :, None, None]
        cosine = F.cosine_similarity(features, q.expand_as(features), dim=1)[:, None]
        return self.mix(torch.cat([features, features * q, cosine], 1))


class SimilarityNetwork(nn.Module):
    """§5.2.2: the deepest features under a mask, averaged, mapped to a point in a latent space
    where copies of one product lie close and other products at least a margin away (Eq 5.7)."""

    def __init__(self, channels: int, latent: int) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(channels, 128), nn.ReLU(), nn.Linear(128, latent))

    def forward(self, features: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
        """features (C, h, w), masks (K, H, W) in [0, 1] -> (K, latent)."""
        m = F.adaptive_avg_pool2d(masks[:, None], features.shape[-2:])[:, 0]
        pooled = torch.einsum("chw,khw->kc", features, m) / (m.sum((-1, -2))[:, None] + 1e-6)
        return self.net(pooled)


class RecurrentDetector(nn.Module):
    def __init__(self, spec: RecurrentSpec, image_size: int) -> None:
        super().__init__()
        spec.check()
        self.spec, self.image_size = spec, image_size
        self.backbone = build_backbone(spec.backbone)
        c1, c2, c3 = BACKBONES[spec.backbone].channels
        h0, h1, h2 = spec.hidden
        deepest_first = (c3, c2, c1)
        self.conditions = nn.ModuleList([QueryCondition(c, c // 2) for c in deepest_first])
        self.cells = nn.ModuleList([ConvLSTMCell(c3 // 2, h0), ConvLSTMCell(h0 + c2 // 2, h1), ConvLSTMCell(h1 + c1 // 2, h2)])
        self.mask_head = nn.Sequential(nn.Conv2d(h2, h2, 3, padding=1), nn.ReLU(inplace=True), nn.Conv2d(h2, 1, 1))
        self.stop_head = nn.Linear(2 * (h0 + h1 + h2), 1)
        self.similarity = SimilarityNetwork(c3, spec.latent)

    def encode(self, images: torch.Tensor, query_boxes: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
        """The query-conditioned features, deepest level first, and the deepest raw features (F_0)."""
        features = self.backbone((images - MEAN.to(images)) / STD.to(images))
        queries = [torch.stack([crop_features(sample, box, stride).mean((1, 2)) for sample, box in zip(level.unbind(0), query_boxes)])
                   for level, stride in zip(features, STRIDES)]
        conditioned = [condition(f, q) for condition, f, q in zip(self.conditions, features[::-1], queries[::-1])]
        return conditioned, features[2]

    def forward(self, images: torch.Tensor, query_boxes: torch.Tensor, steps: int | None = None) -> dict[str, torch.Tensor]:
        """Mask logits (B, T, H/4, W/4), stop logits (B, T) and F_0 for ``steps`` roll-out steps
        (``max_steps`` if None)."""
        conditioned, deepest = self.encode(images, query_boxes)
        states: list = [None] * len(self.cells)
        masks, stops = [], []
        for _ in range(self.spec.max_steps if steps is None else steps):
            outputs = []
            x = conditioned[0]
            for i, cell in enumerate(self.cells):
                if i > 0:  # Eq 5.3: the upsampled output of the level above beside this level's features
                    x = torch.cat([F.interpolate(outputs[-1], size=conditioned[i].shape[-2:]), conditioned[i]], 1)
                out, states[i] = cell(x, states[i])
                outputs.append(out)
            side = (images.shape[-2] // MASK_STRIDE, images.shape[-1] // MASK_STRIDE)
            masks.append(self.mask_head(F.interpolate(outputs[-1], size=side, mode="bilinear", align_corners=False))[:, 0])
            pooled = torch.cat([torch.cat([o.mean((2, 3)), o.amax((2, 3))], 1) for o in outputs], 1)
            stops.append(self.stop_head(pooled)[:, 0])
        return {"masks": torch.stack(masks, 1), "stops": torch.stack(stops, 1), "deepest": deepest}

    @torch.no_grad()
    def detect(self, images: torch.Tensor, query_boxes: torch.Tensor) -> list[dict[str, torch.Tensor]]:
        """One box per step whose mask is not empty, scored by the step's objectness ``v_t``; no NMS
        (a step that finds a copy found before is the method's own error)."""
        out = self.forward(images, query_boxes)
        masks = torch.sigmoid(out["masks"]).cpu().numpy()
        scores = torch.sigmoid(out["stops"]).cpu()
        scale = images.shape[-1] / masks.shape[-1]
        results = []
        for b in range(images.shape[0]):
            boxes, kept = [], []
            for t in range(masks.shape[1]):
                box = mask_box(masks[b, t] >= 0.5)
                if box is not None:
                    boxes.append([v * scale for v in box])
                    kept.append(float(scores[b, t]))
            results.append({"boxes": torch.tensor(boxes, dtype=torch.float32).reshape(-1, 4).clamp(0, self.image_size),
                            "scores": torch.tensor(kept, dtype=torch.float32)})
        return results


def mask_box(mask: np.ndarray) -> list[float] | None:
    """(x1, y1, x2, y2) in mask cells round the mask's largest connected blob; None if empty."""
    import cv2

    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if count <= 1:
        return None
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, w, h = (int(stats[best, k]) for k in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT))
    return [float(x), float(y), float(x + w), float(y + h)]


def box_masks(boxes: torch.Tensor, height: int, width: int, scale: float) -> torch.Tensor:
    """Boxes (N, 4) xyxy in image pixels as filled masks (N, height, width) on the mask grid."""
    ys = (torch.arange(height, dtype=torch.float32) + 0.5)[None, :, None]
    xs = (torch.arange(width, dtype=torch.float32) + 0.5)[None, None, :]
    b = boxes.float() * scale
    inside_y = (ys >= b[:, 1, None, None]) & (ys <= b[:, 3, None, None])
    inside_x = (xs >= b[:, 0, None, None]) & (xs <= b[:, 2, None, None])
    return (inside_y & inside_x).float()


def soft_iou(predicted: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Eq 5.4 for every pair: predicted (T, H, W), truth (M, H, W) -> (T, M) of 1 - soft IoU."""
    inter = torch.einsum("thw,mhw->tm", predicted, truth)
    union = predicted.sum((1, 2))[:, None] + truth.sum((1, 2))[None, :] - inter
    return 1.0 - inter / union.clamp(min=1e-6)


@dataclass(frozen=True)
class LossWeights:
    stop: float = 1.0  # lambda_s of Eq 5.9
    repetition: float = 0.1  # lambda_r of Eq 5.9
    gamma: float = 0.9  # Eq 5.8's discount
    margin: float = 2.0  # rho of Eq 5.7


def recurrent_loss(model: RecurrentDetector, out: dict[str, torch.Tensor], targets: list[torch.Tensor],
                   others: list[torch.Tensor], weights: LossWeights, use_stop: bool = True,
                   use_repetition: bool = True) -> dict[str, torch.Tensor]:
    """Eq 5.9 (``seg + λ_s stop + λ_r rep``) plus the similarity network's contrastive loss (Eq 5.7).

    - Segmentation (Eq 5.4-5.5): the first ``min(m, T)`` steps are matched to the m copies by the
      Hungarian algorithm on soft IoU, so the order is free but each of those steps must find a
      different copy; a mean over the matched pairs (the thesis sums).
    - Stop (Eq 5.6): ``v_t`` should be 1 for those steps and 0 after; a mean over the steps.
    - Repetition (Eq 5.8): each matched step's distance, in the similarity network's latent space, to
      the nearest earlier step, discounted by γ^n and normalised by Σγ^n; the predicted masks are
      compared (the thesis's first variant, which collapsed to one repeated mask: here the Hungarian
      segmentation loss forbids that). The similarity network's weights are held fixed for it; its
      gradient moves the masks, so the decoder and, through them, the encoder.
    - Contrastive (Eq 5.7): trains only the similarity network, on the ground truth's masks over F_0
      (detached): copies of the query's product pulled together, each pushed at least ``margin``
      from the other products' copies (pairs of two other products are left out: the boxes do not
      say whether they are one product). The thesis pre-trains this network on a fixed encoder; here
      it learns beside the detector, on an encoder that is itself learning.
    """
    from scipy.optimize import linear_sum_assignment

    masks = torch.sigmoid(out["masks"])
    batch, steps, height, width = masks.shape
    scale = 1.0 / MASK_STRIDE
    deepest = out["deepest"].detach()
    frozen = {name: p.detach() for name, p in model.similarity.named_parameters()}
    seg, rep, con = [], [], []
    stop_targets = torch.zeros(batch, steps)
    for b in range(batch):
        truth = box_masks(targets[b].reshape(-1, 4), height, width, scale)
        m = truth.shape[0]
        k = min(m, steps)
        stop_targets[b, :k] = 1.0
        if m == 0:
            continue
        cost = soft_iou(masks[b, :k], truth)
        rows, cols = linear_sum_assignment(cost.detach().numpy())
        seg.append(cost[rows, cols].mean())
        if use_repetition and k > 1:
            points = torch.func.functional_call(model.similarity, frozen, (deepest[b], masks[b, :k]))
            distances = torch.cdist(points, points)
            discounts = weights.gamma ** torch.arange(1, k, dtype=torch.float32)
            nearest = torch.stack([distances[:n, n].min() for n in range(1, k)])
            rep.append((discounts * nearest).sum() / discounts.sum())
        other = box_masks(others[b].reshape(-1, 4), height, width, scale)
        if m > 1 or other.shape[0]:
            points = model.similarity(deepest[b], torch.cat([truth, other]))
            distances = torch.cdist(points, points)
            same = torch.zeros(len(points), len(points), dtype=torch.bool)
            same[:m, :m] = True
            pairs = torch.triu(torch.ones_like(same), 1)
            pairs[m:, m:] = False  # two other products' copies: maybe one product, maybe two
            pair_loss = torch.where(same, distances, (weights.margin - distances).clamp(min=0.0))[pairs]
            if pair_loss.numel():
                con.append(pair_loss.mean())
    zero = masks.sum() * 0.0
    losses = {"seg": torch.stack(seg).mean() if seg else zero,
              "stop": F.binary_cross_entropy_with_logits(out["stops"], stop_targets),
              "rep": torch.stack(rep).mean() if rep else zero,
              "con": torch.stack(con).mean() if con else zero}
    losses["total"] = (losses["seg"] + (weights.stop * losses["stop"] if use_stop else 0.0)
                       + (weights.repetition * losses["rep"] if use_repetition else 0.0) + losses["con"])
    return losses

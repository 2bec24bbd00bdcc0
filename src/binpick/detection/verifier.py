"""Is this detection the ordered product? A learnt check between the shop photo and a detection's
window (colour and heights from depth), before a grasp puts it in the customer's tote.

The detector ranks instances by looks and pickability; under another light, or for a product it
never saw, it also finds confident instances of *other* products. A hand-tuned colour histogram
check (hue-saturation intersection) told them apart in binpick's own light (AUC 0.97) but not under a
warm, hard warehouse light (AUC 0.72, a third of the right product's instances rejected), and white
balancing the frame first traded one for the other (0.81 / 0.85). This check is learnt instead, on
domain-randomised bins (random products, lights, cameras) with shop photos from randomised studios,
the window's colours cast and scaled far beyond any training light; its output is calibrated
(temperature scaling on held-out worlds), so its threshold is a probability.

    verifier = ProductVerifier.load()                          # shipped weights
    p = verifier.probabilities(photo, photo_mask, rgb, depth, boxes_xywh)   # P(same product) per box

One colour tower for photo and window alike (siamese), one for the window's heights; a small head on
``[p, w, p*w, |p-w|, heights]``. GroupNorm,
not BatchNorm: photo batches and window batches have nothing in common statistically.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import torch
from torch import nn

from binpick.core.errors import ConfigError, InputFileError

FORMAT = "binpick.product_verifier"
SIDE = 64  # network input side, pixels
STORED = 72  # windows are cut at this side (box plus MARGIN) so training can jitter them
MARGIN = 0.2  # of the box's side, added around it before cutting
HEIGHT_RANGE = 0.3  # metres: heights above the window's far surface, scaled to [0, 1]
SHIPPED = Path(__file__).parent / "weights" / "product_verifier.safetensors"


# ---------------------------------------------------------------------- inputs (training and inference share these)
def photo_input(photo: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """(SIDE, SIDE, 4) uint8: the shop photo cropped to its product (``mask``: its pixels; default:
    :func:`binpick.detection.photos.photo_mask`) and resized, the product's pixels as alpha."""
    from binpick.detection.photos import MARGIN as FRAME, photo_mask

    photo = np.asarray(photo)
    rgb = np.ascontiguousarray(photo[..., :3], dtype=np.uint8)
    mask = photo_mask(photo) if mask is None else np.asarray(mask, bool)
    if not mask.any():
        mask = np.ones(mask.shape, bool)
    if not mask.all():
        ys, xs = np.nonzero(mask)
        x1, x2 = np.percentile(xs, [0.5, 99.5])
        y1, y2 = np.percentile(ys, [0.5, 99.5])
        dx, dy = FRAME * (x2 - x1) + 1, FRAME * (y2 - y1) + 1
        h, w = mask.shape
        crop = (slice(int(max(0, y1 - dy)), int(min(h, y2 + dy + 1))), slice(int(max(0, x1 - dx)), int(min(w, x2 + dx + 1))))
        rgb, mask = rgb[crop], mask[crop]
    rgba = np.dstack([rgb, np.where(mask, 255, 0).astype(np.uint8)])
    return cv2.resize(rgba, (SIDE, SIDE), interpolation=cv2.INTER_NEAREST)


# ---------------------------------------------------------------------- colour evidence
HIST_BINS, HIST_RANGES = [12, 4], [0, 180, 0, 256]  # hue, saturation (as binpick.picking.colour)
COLOUR_FEATURES = 3 * 48 + 2 + 3  # photo, window and white-balanced window histograms; two intersections; the illuminant
STANDING = 0.04  # heights channel (of HEIGHT_RANGE): pixels this high above the window's far surface are the product's


def illuminant(rgb: np.ndarray, p: int = 6) -> np.ndarray:
    """The frame's light colour, shades of grey (Finlayson & Trezzi 2004): the RGB p-norm, mean 1."""
    values = np.asarray(rgb, np.float32).reshape(-1, 3)[::7] + 1.0  # every 7th pixel: the same estimate, 7x cheaper
    light = (values ** p).mean(0) ** (1.0 / p)
    return (light / light.mean()).astype(np.float32)


def histogram(rgb: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    mask = None if mask is None or not mask.any() else mask.astype(np.uint8)
    hist = cv2.calcHist([hsv], [0, 1], mask, HIST_BINS, HIST_RANGES).ravel()
    return hist / max(float(hist.sum()), 1.0)


def window_mask(window: np.ndarray) -> np.ndarray:
    """The window's product pixels: standing above its far surface (the middle half where depth shows none)."""
    mask = window[..., 3] > round(STANDING * 255)
    if mask.mean() < 0.05:
        mask = np.zeros(window.shape[:2], bool)
        side = window.shape[0]
        mask[side // 4:-side // 4, side // 4:-side // 4] = True
    return mask


def colour_features(photo: np.ndarray, window: np.ndarray, light: np.ndarray) -> np.ndarray:
    """(COLOUR_FEATURES,) float32: hue-saturation histograms of the photo's product pixels, of the
    window's and of the window white-balanced by the frame's ``light``, their intersections with the
    photo's, and the light itself (so the head learns when to trust the balance)."""
    return joined_colour(photo_histogram(photo), *window_histograms(window, light), light)[0]


def photo_histogram(photo: np.ndarray) -> np.ndarray:
    """The hue-saturation histogram of a photo input's product pixels (its alpha)."""
    return histogram(photo[..., :3], photo[..., 3] > 127)


def window_histograms(window: np.ndarray, light: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A window's product pixels' histograms: as read, and white-balanced by the frame's ``light``."""
    mask = window_mask(window)
    balanced_rgb = np.clip(window[..., :3].astype(np.float32) / light, 0, 255).astype(np.uint8)
    return histogram(window[..., :3], mask), histogram(balanced_rgb, mask)


def joined_colour(mine: np.ndarray, raw: np.ndarray, balanced: np.ndarray, light: np.ndarray) -> np.ndarray:
    """(n, COLOUR_FEATURES): :func:`colour_features` from histograms already made (``mine``: the photo's,
    one or (n, 48); ``raw``, ``balanced``: the windows', (48,) or (n, 48))."""
    raw, balanced = np.atleast_2d(raw), np.atleast_2d(balanced)
    mine = np.broadcast_to(np.atleast_2d(mine), raw.shape)
    joined = np.concatenate([mine, raw, balanced, np.minimum(mine, raw).sum(1, keepdims=True),
                             np.minimum(mine, balanced).sum(1, keepdims=True), np.broadcast_to(light, (len(raw), 3))], 1)
    return joined.astype(np.float32)


def window_input(rgb: np.ndarray, depth: np.ndarray, box_xywh, side: int = STORED) -> np.ndarray:
    """(side, side, 4) uint8: the detection's box plus a margin, colour and heights (the window's
    far surface, its 90th depth percentile, taken as what the product stands on; 0 where depth has no
    reading). ``depth`` in metres, registered to ``rgb``."""
    height, width = rgb.shape[:2]
    x, y, w, h = (float(v) for v in box_xywh)
    pad_x, pad_y = MARGIN * w, MARGIN * h
    x0 = int(np.floor(min(max(0.0, x - pad_x), width - 2.0)))  # a box at the image's edge still has pixels
    y0 = int(np.floor(min(max(0.0, y - pad_y), height - 2.0)))
    x1, y1 = int(np.ceil(min(float(width), x + w + pad_x))), int(np.ceil(min(float(height), y + h + pad_y)))
    x1, y1 = max(x1, min(width, x0 + 2)), max(y1, min(height, y0 + 2))
    colour = cv2.resize(np.ascontiguousarray(rgb[y0:y1, x0:x1]), (side, side), interpolation=cv2.INTER_AREA)
    patch = np.asarray(depth[y0:y1, x0:x1], dtype=np.float32)
    valid = np.isfinite(patch) & (patch > 0)
    heights = np.zeros_like(patch)
    if valid.any():
        far = float(np.percentile(patch[valid], 90))
        heights[valid] = np.clip((far - patch[valid]) / HEIGHT_RANGE, 0.0, 1.0)
    heights = cv2.resize(heights, (side, side), interpolation=cv2.INTER_NEAREST)
    return np.dstack([colour, np.round(heights * 255).astype(np.uint8)])


def centre(window: np.ndarray) -> np.ndarray:
    """The SIDE x SIDE middle of a stored window (what inference sees; training jitters it)."""
    offset = (window.shape[0] - SIDE) // 2
    return window[offset:offset + SIDE, offset:offset + SIDE]


def to_tensor(images: np.ndarray) -> torch.Tensor:
    """(N, H, W, C) uint8 -> (N, C, H, W) float in [0, 1]."""
    return torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).float().div(255.0)


# ---------------------------------------------------------------------- the network
def tower(channels: int, width: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    sizes = [channels, width, 2 * width, 4 * width, 4 * width]
    for a, b in zip(sizes, sizes[1:]):
        layers += [nn.Conv2d(a, b, 3, stride=2, padding=1), nn.GroupNorm(8, b), nn.ReLU(inplace=True),
                   nn.Conv2d(b, b, 3, padding=1), nn.GroupNorm(8, b), nn.ReLU(inplace=True)]
    return nn.Sequential(*layers, nn.AdaptiveAvgPool2d(1), nn.Flatten())


class VerifierNet(nn.Module):
    """logit(P(same product)) for (photo, window) pairs; ``temperature`` divides it (calibration).

    One colour tower embeds the photo and the window alike (a siamese pair, so their features can be
    compared element by element); a small tower reads the window's heights."""

    def __init__(self, width: int = 16) -> None:
        super().__init__()
        self.width = width
        self.colour = tower(3, width)
        self.heights = tower(1, 8)
        features = 4 * width
        self.evidence = nn.Sequential(nn.Linear(COLOUR_FEATURES, 64), nn.ReLU(inplace=True))
        self.head = nn.Sequential(nn.Linear(4 * features + 32 + 64, 128), nn.ReLU(inplace=True), nn.Linear(128, 1))
        self.register_buffer("temperature", torch.ones(()))

    def embed_photo(self, photo: torch.Tensor) -> torch.Tensor:
        return self.colour(photo[:, :3])

    def logits(self, photo_features: torch.Tensor, window: torch.Tensor, colour: torch.Tensor) -> torch.Tensor:
        """``colour``: (N, COLOUR_FEATURES) from :func:`colour_features`."""
        return self.joined_logits(photo_features, *self.window_features(window), colour)

    def window_features(self, window: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The windows' colour and height towers (computed once, compared with every photo)."""
        return self.colour(window[:, :3]), self.heights(window[:, 3:])

    def joined_logits(self, photo_features: torch.Tensor, looks: torch.Tensor, heights: torch.Tensor,
                      colour: torch.Tensor) -> torch.Tensor:
        p = photo_features.expand(len(looks), -1) if len(photo_features) == 1 else photo_features
        joined = torch.cat([p, looks, p * looks, (p - looks).abs(), heights, self.evidence(colour)], 1)
        return self.head(joined)[:, 0] / self.temperature

    def forward(self, photo: torch.Tensor, window: torch.Tensor, colour: torch.Tensor) -> torch.Tensor:
        return self.logits(self.embed_photo(photo), window, colour)


class ProductVerifier:
    """``probabilities(photo, photo_mask, rgb, depth, boxes)``: P(same product as the photo) per box."""

    def __init__(self, net: VerifierNet, meta: dict | None = None) -> None:
        self.net, self.meta = net.eval(), dict(meta or {})

    @classmethod
    def load(cls, path: str | Path | None = None) -> ProductVerifier:
        from binpick.core import tensorfile

        path = Path(path) if path is not None else SHIPPED
        if path == SHIPPED and not path.is_file():
            raise ConfigError("the shipped product verifier is missing from the installation (reinstall binpick)")
        tensors, meta, _ = tensorfile.load(path, FORMAT, "product-verifier weights")
        net = VerifierNet(int(meta.get("width", 16)))
        try:
            net.load_state_dict({k: v.float() for k, v in tensors.items()})
        except RuntimeError as error:
            raise InputFileError(f"product-verifier weights {str(path)!r} do not fit the network "
                                 f"({str(error).splitlines()[0][:100]})") from None
        return cls(net, meta)

    def save(self, path: str | Path, meta: dict | None = None) -> Path:
        from binpick.core import tensorfile

        return tensorfile.save(path, FORMAT, tensors=self.net.state_dict(), meta={"width": self.net.width, **self.meta, **(meta or {})})

    def windows(self, rgb: np.ndarray, depth: np.ndarray) -> FrameWindows:
        """The frame's detection windows, each read once however many checks ask for it."""
        return FrameWindows(self.net, rgb, depth)

    @torch.no_grad()
    def pairwise(self, rgb: np.ndarray, depth: np.ndarray, boxes, windows: FrameWindows | None = None) -> np.ndarray:
        """P(same product) between every two boxes of one frame, (n, n), symmetric, 1 on the diagonal:
        each box's window is shown to the check as if it were the shop photo (its colours, its pixels
        standing above the window's floor as the product's mask), both ways round, averaged. Copies of
        one product in a bin agree with each other; a look-alike of another product agrees with few.
        One batch: each window's towers and histograms once (``windows``: those the frame's check
        against the photos already read), the head on every pair."""
        boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
        n = len(boxes)
        if n < 2:
            return np.ones((n, n))
        read = (windows or self.windows(rgb, depth)).read(boxes)
        first, second = (index.ravel() for index in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
        colour = joined_colour(read.raw[first], read.raw[second], read.balanced[second], read.light)  # a window as photo: its own pixels
        logits = self.net.joined_logits(read.looks[first], read.looks[second], read.heights[second], torch.from_numpy(colour))
        same = torch.sigmoid(logits).numpy().astype(float).reshape(n, n)
        same = (same + same.T) / 2
        np.fill_diagonal(same, 1.0)
        return same

    @torch.no_grad()
    def probabilities(self, photos, photo_masks, rgb: np.ndarray, depth: np.ndarray, boxes,
                      windows: FrameWindows | None = None) -> np.ndarray:
        """P(same product) for each box (x, y, w, h) against the best-matching of the ``photos`` (one
        photo, or a list of views of the product; ``photo_masks`` likewise, None entries: found from the
        photo). ``depth``: metres registered to ``rgb``, 0 or NaN for no reading. ``windows``: the
        frame's windows already read (:meth:`windows`), shared with :meth:`pairwise`."""
        boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
        if not len(boxes):
            return np.zeros(0)
        if isinstance(photos, np.ndarray):
            photos, photo_masks = [photos], [photo_masks]
        masks = list(photo_masks) if isinstance(photo_masks, (list, tuple)) else [photo_masks] * len(photos)
        if len(masks) != len(photos):
            raise ConfigError(f"{len(photos)} photos but {len(masks)} product masks: give one per photo")
        photo_arrays = [photo_input(p, m) for p, m in zip(photos, masks)]
        read = (windows or self.windows(rgb, depth)).read(boxes)  # the windows' towers once for every photo
        features = self.net.embed_photo(to_tensor(np.stack(photo_arrays)))
        best = torch.stack([self.net.joined_logits(f[None], read.looks, read.heights, torch.from_numpy(
                                joined_colour(photo_histogram(photo), read.raw, read.balanced, read.light)))
                            for f, photo in zip(features, photo_arrays)]).amax(0)
        return torch.sigmoid(best).numpy().astype(float)


class ReadWindows(NamedTuple):
    """Windows of some boxes as the check reads them: towers (n, features) and histograms (n, 48)."""
    looks: torch.Tensor
    heights: torch.Tensor
    raw: np.ndarray
    balanced: np.ndarray
    light: np.ndarray


class FrameWindows:
    """One frame's detection windows as the product check reads them (pixels and heights, product-pixel
    histograms as read and white-balanced, the colour and height towers), each box's made once: the
    check against the shop photos and the detections' check against each other read the same
    windows, so a plan pays for them once."""

    def __init__(self, net: VerifierNet, rgb: np.ndarray, depth: np.ndarray) -> None:
        self.net, self.rgb, self.depth = net, rgb, depth
        self.light = illuminant(rgb)
        self._read: dict[tuple[float, ...], tuple[torch.Tensor, torch.Tensor, np.ndarray, np.ndarray]] = {}

    @torch.no_grad()
    def read(self, boxes: np.ndarray) -> ReadWindows:
        """The windows of ``boxes`` (n, 4) x, y, w, h: those not read before in one batch."""
        keys = [tuple(float(v) for v in box) for box in np.asarray(boxes, dtype=float).reshape(-1, 4)]
        new = list(dict.fromkeys(key for key in keys if key not in self._read))
        if new:
            arrays = [centre(window_input(self.rgb, self.depth, key)) for key in new]
            looks, heights = self.net.window_features(to_tensor(np.stack(arrays)))
            for i, (key, array) in enumerate(zip(new, arrays)):
                self._read[key] = (looks[i], heights[i], *window_histograms(array, self.light))
        rows = [self._read[key] for key in keys]
        return ReadWindows(torch.stack([r[0] for r in rows]), torch.stack([r[1] for r in rows]),
                           np.stack([r[2] for r in rows]), np.stack([r[3] for r in rows]), self.light)

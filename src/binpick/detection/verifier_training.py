"""Training the product verifier (:mod:`binpick.detection.verifier`) on a binpick data set: a loop you
can read top to bottom.

Pairs come from each scene's ground truth: the ordered product's instances with its shop photos
(the canonical one and the randomised studios' views, ``--photo-views``) are positives; the other
products' instances in the same bin with that photo, and the product's instances with another
world's photo, are negatives; a saturated instance whose hue is turned far round is a negative too
(the same shape in another colour, the detector's usual confusion); optionally (``repainted``) so is
another product's instance repainted in the ordered product's colours (another shape in the same
colours: a white brick beside a white carton), and val pairs of such look-alikes measure how far
shape counts where colour cannot tell (docs/notes.md: as trained, it did not lift them). Every window's colours are cast
and scaled well beyond the training lights (a warehouse's light is not the renderer's) and its box
jittered (detections are not ground truth). Temperature scaling on the val worlds' pairs makes the
output a probability. Checkpoints are written atomically after each epoch; a run resumes.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from torch.nn import functional as F

from binpick.core.config import check_range
from binpick.detection.verifier import (MARGIN, SIDE, STORED, ProductVerifier, VerifierNet, colour_features, illuminant, photo_input,
                                        to_tensor, window_input)
from binpick.core.errors import ConfigError
from binpick.core.runs import SILENT, RunCallback

CHECKPOINT = "verifier_checkpoint.safetensors"


@dataclass(frozen=True)
class VerifierTrainConfig:
    data: str  # a binpick data set (``binpick data generate``), best with --domain random --photo-views N
    out: str = "runs/verifier"
    scenes: int = 8000  # train scenes read (the first ones); val scenes: every val-split scene among the first ``scenes``
    epochs: int = 8
    batch_size: int = 128
    lr: float = 2e-3
    width: int = 16
    min_visible: float = 0.3  # instances less visible than this are left out
    repainted: float = 0.0  # share of negatives repainted in the photo's colours (0: none; it did not help: docs/notes.md)
    threads: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        check_range("scenes", self.scenes, 1, 10_000_000, integer=True)
        check_range("epochs", self.epochs, 1, 1000, integer=True)
        check_range("batch_size", self.batch_size, 2, 4096, integer=True)
        check_range("lr", self.lr, 1e-6, 1.0)
        check_range("width", self.width, 8, 256, integer=True)
        check_range("min_visible", self.min_visible, 0.0, 1.0)
        check_range("repainted", self.repainted, 0.0, 1.0)
        check_range("threads", self.threads, 1, 256, integer=True)
        if self.width % 8:
            raise ConfigError(f"width must be a multiple of 8 (GroupNorm groups), got {self.width}")


@dataclass
class Windows:
    """Instance windows of a data set and the shop photos of the products ordered in it."""

    windows: np.ndarray  # (N, STORED, STORED, 4) uint8
    product: np.ndarray  # (N,) index into ``names``
    ordered: np.ndarray  # (N,) index of the product ordered in the window's scene
    names: list[str]
    photos: dict[int, np.ndarray]  # product index -> (V, SIDE, SIDE, 4) uint8 (alpha: the product): canonical view first
    lights: np.ndarray  # (N, 3) the illuminant of each window's frame (binpick.detection.verifier.illuminant)
    categories: dict[int, str] = field(default_factory=dict)  # product index -> its category (shape family)

    @property
    def positive(self) -> np.ndarray:
        return self.product == self.ordered


def product_photos(data: Path, product: str) -> list[np.ndarray]:
    """The product's photos in a data set: photos/<name>.png, then photos/<name>/*.png."""
    from binpick.detection.data import read_image

    name = product.replace("/", "_")
    paths = [data / "photos" / f"{name}.png"] + sorted((data / "photos" / name).glob("*.png"))
    return [photo_input(read_image(p, keep_alpha=True)) for p in paths if p.is_file()]


def collect(data: str | Path, splits: tuple[str, ...], limit: int | None, min_visible: float,
            callback: RunCallback = SILENT) -> Windows:
    """Windows of every instance (visible enough) in the first ``limit`` scenes of ``splits``."""
    from PIL import Image

    from binpick.core.files import read_json

    data = Path(data)
    if not (data / "dataset.json").is_file():
        raise ConfigError(f"{str(data)!r} is not a binpick data set (no dataset.json); make one with: binpick data generate --out {data}")
    paths = sorted((data / "scenes").glob("*.json"))[:limit]
    if not paths:
        raise ConfigError(f"{str(data)!r} holds no scenes yet")
    names: dict[str, int] = {}
    windows, product, ordered, photos, lights, categories = [], [], [], {}, [], {}
    with callback.task(f"windows of {data.name}", len(paths)) as task:
        for path in paths:
            task.update(advance=1)
            record = read_json(path, "scene file")
            if not isinstance(record, dict) or not {"split", "target", "file_name", "depth_file", "annotations"} <= set(record):
                raise ConfigError(f"scene file {str(path)!r} is damaged; delete it and run generate again to redo that scene")
            if record["split"] not in splits:
                continue
            target = record["target"]
            key = names.setdefault(target, len(names))
            if key not in photos:
                views = product_photos(data, target)
                if not views:
                    continue
                photos[key] = np.stack(views)
            rgb = np.asarray(Image.open(data / record["file_name"]).convert("RGB"))
            depth = np.asarray(Image.open(data / record["depth_file"]), dtype=np.float32) / 1000.0
            light = illuminant(rgb)
            for annotation in record["annotations"]:
                if annotation["visible_fraction"] < min_visible or annotation["bbox"][2] < 4 or annotation["bbox"][3] < 4:
                    continue
                windows.append(window_input(rgb, depth, annotation["bbox"]))
                product.append(names.setdefault(annotation["product"], len(names)))
                categories[product[-1]] = str(annotation.get("category", ""))
                ordered.append(key)
                lights.append(light)
    if not windows:
        raise ConfigError(f"no instance windows in {str(data)!r} for splits {', '.join(splits)}")
    return Windows(np.stack(windows), np.array(product), np.array(ordered), list(names), photos, np.stack(lights), categories)


# ---------------------------------------------------------------------- pairs and augmentation
def hue_turned(window: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The window with its hue turned 60-180 degrees either way: the same shape in another colour."""
    hsv = cv2.cvtColor(np.ascontiguousarray(window[..., :3]), cv2.COLOR_RGB2HSV)
    hsv[..., 0] = (hsv[..., 0].astype(int) + int(rng.integers(30, 91)) * (1 if rng.uniform() < 0.5 else -1)) % 180
    return np.dstack([cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB), window[..., 3]])


def repainted(window: np.ndarray, photo: np.ndarray) -> np.ndarray:
    """The window's product pixels in the photo product's colours (Lab mean and spread of the photo's
    product pixels; the window's own shading and print kept as their pattern): another shape in the
    ordered product's colours, the look-alike a colour check cannot refuse."""
    side = window.shape[0]
    standing = cv2.morphologyEx(np.ascontiguousarray(window[..., 3]), cv2.MORPH_TOPHAT, np.ones((side - 11, side - 11), np.uint8))
    mask = standing > 8  # ~1 cm above the surface round it (a top-hat: tilted floors and walls fall away)
    inside = int(round(side * MARGIN / (1 + 2 * MARGIN)))  # the box itself, without the margin cut round it
    mask[:inside], mask[-inside:], mask[:, :inside], mask[:, -inside:] = False, False, False, False
    own = photo[..., 3] > 127
    if not own.any() or mask.sum() < 16:
        return window
    lab = cv2.cvtColor(np.ascontiguousarray(window[..., :3]), cv2.COLOR_RGB2LAB).astype(np.float32)
    reference = cv2.cvtColor(np.ascontiguousarray(photo[..., :3]), cv2.COLOR_RGB2LAB).astype(np.float32)[own]
    pixels = lab[mask]
    lab[mask] = (pixels - pixels.mean(0)) / (pixels.std(0) + 1.0) * reference.std(0) + reference.mean(0)
    rgb = window[..., :3].copy()
    rgb[mask] = cv2.cvtColor(np.clip(lab, 0, 255).astype(np.uint8), cv2.COLOR_LAB2RGB)[mask]  # the rest as it was
    return np.dstack([rgb, window[..., 3]])


def look_alike_allowed(data: Windows, product: int, photo_of: int) -> bool:
    """Whether a window of ``product`` may be repainted as a look-alike of ``photo_of``: both categories
    known and different (two products of one shape family repainted alike would be the same thing)."""
    mine, theirs = data.categories.get(product, ""), data.categories.get(photo_of, "")
    return bool(mine) and bool(theirs) and mine != theirs


def saturated(window: np.ndarray) -> bool:
    middle = window[STORED // 4:-STORED // 4, STORED // 4:-STORED // 4, :3]
    return float(cv2.cvtColor(np.ascontiguousarray(middle), cv2.COLOR_RGB2HSV)[..., 1].mean()) > 70


def jittered(window: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A SIDE crop of a stored window at a random offset and scale (a detection's box is off by ~10%),
    flipped or turned (the product's yaw in the bin is anything)."""
    side = int(rng.integers(SIDE - 8, STORED + 1))
    x, y = rng.integers(0, STORED - side + 1, 2)
    crop = window[y:y + side, x:x + side]
    crop = cv2.resize(crop, (SIDE, SIDE), interpolation=cv2.INTER_LINEAR) if side != SIDE else crop
    return np.ascontiguousarray(np.rot90(crop, int(rng.integers(4)))[:, ::(1 if rng.uniform() < 0.5 else -1)])


def lit(image: np.ndarray, rng: np.random.Generator, strength: float) -> tuple[np.ndarray, np.ndarray]:
    """Another light on an image's colours: per-channel casts, brightness, gamma and sensor noise.
    Returns the image (alpha kept) and the cast (per channel), which the frame's light took too."""
    colour = image[..., :3].astype(np.float32) / 255.0
    cast = rng.uniform(1 - 0.45 * strength, 1 + 0.45 * strength, 3)
    colour = colour * cast / max(cast.max(), 1.0) * rng.uniform(1 - 0.5 * strength, 1 + 0.4 * strength)
    colour = np.clip(colour, 0, 1) ** rng.uniform(1 - 0.4 * strength, 1 + 0.5 * strength)
    if rng.uniform() < 0.5 * strength:  # a hard light from one side: shading across the window
        ys, xs = np.mgrid[0:colour.shape[0], 0:colour.shape[1]] / max(colour.shape[:2])
        angle = rng.uniform(0, 2 * np.pi)
        ramp = (xs * np.cos(angle) + ys * np.sin(angle))
        ramp = (ramp - ramp.min()) / max(float(np.ptp(ramp)), 1e-6)
        colour = colour * (1 + rng.uniform(-0.5, 0.5) * (ramp - 0.5))[..., None]
    colour = colour * 255 + rng.normal(0, rng.uniform(0, 6 * strength), colour.shape)
    out = np.clip(colour, 0, 255).astype(np.uint8)
    return (np.dstack([out, image[..., 3]]) if image.shape[2] == 4 else out), cast.astype(np.float32)


def holed(window: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Depth as a real sensor gives it: a block of the heights missing, now and then."""
    if rng.uniform() < 0.3:
        window = window.copy()
        h, w = rng.integers(SIDE // 8, SIDE // 2, 2)
        y, x = rng.integers(0, SIDE - h), rng.integers(0, SIDE - w)
        window[y:y + h, x:x + w, 3] = 0
    return window


def batch(data: Windows, indices: np.ndarray, rng: np.random.Generator, train: bool, repaint: float = 0.0):
    """(photos, windows, labels) for windows ``indices``: each window with its scene's ordered product's
    photo, or (half the ordered product's windows) another product's photo; hue-turned hard negatives,
    and (a ``repaint`` share of the negatives) other products repainted in the photo's colours."""
    keys = np.array(sorted(data.photos))
    photos, windows, colours, labels = [], [], [], []
    for i in indices:
        window = data.windows[i]
        own = int(data.ordered[i])
        label = int(data.product[i] == own)
        photo_of = own
        if label and rng.uniform() < 0.5:
            photo_of = int(keys[rng.integers(len(keys))])
            label = int(photo_of == own)
        if train and label and rng.uniform() < 0.2 and saturated(window):
            window, label = hue_turned(window, rng), 0
        views = data.photos[photo_of]
        photo = views[rng.integers(len(views))] if train else views[0]
        if repaint > 0 and not label and look_alike_allowed(data, int(data.product[i]), photo_of) and rng.uniform() < repaint:
            window = repainted(window, photo)
        light = data.lights[i]
        if train:
            window, cast = lit(jittered(window, rng), rng, 1.0)
            window = holed(window, rng)
            light = light * cast / (light * cast).mean()
            photo = lit(np.ascontiguousarray(photo[:, ::(1 if rng.uniform() < 0.5 else -1)]), rng, 0.3)[0]
        else:
            offset = (STORED - SIDE) // 2
            window = window[offset:offset + SIDE, offset:offset + SIDE]
        photos.append(photo)
        windows.append(window)
        colours.append(colour_features(photo, window, light))
        labels.append(label)
    return (to_tensor(np.stack(photos)), to_tensor(np.stack(windows)), torch.from_numpy(np.stack(colours)),
            torch.tensor(labels, dtype=torch.float32))


def fixed_pairs(data: Windows, seed: int, size: int = 4096, repaint: float = 0.0):
    """A fixed evaluation set of pairs (same draws every time it is made); ``repaint``: the share of
    negatives repainted in the photo's colours (1: every negative a look-alike)."""
    rng = np.random.default_rng(seed)
    indices = rng.choice(len(data.windows), size=min(size, len(data.windows)), replace=False)
    return batch(data, indices, rng, train=False, repaint=repaint)


@torch.no_grad()
def logits_of(net: VerifierNet, pairs, chunk: int = 512) -> torch.Tensor:
    photos, windows, colours, _ = pairs
    net.eval()
    return torch.cat([net(photos[i:i + chunk], windows[i:i + chunk], colours[i:i + chunk]) for i in range(0, len(photos), chunk)])


def fit_temperature(logits: torch.Tensor, labels: torch.Tensor) -> float:
    """Temperature scaling (Guo et al. 2017): the T that minimises val log-loss of logits / T."""
    log_t = torch.zeros((), requires_grad=True)
    optimiser = torch.optim.LBFGS([log_t], lr=0.1, max_iter=100)

    def closure():
        optimiser.zero_grad()
        loss = F.binary_cross_entropy_with_logits(logits / log_t.exp(), labels)
        loss.backward()
        return loss

    optimiser.step(closure)
    return float(log_t.detach().exp().clamp(0.05, 20.0))


def scores(probabilities: np.ndarray, labels: np.ndarray, threshold: float = 0.5) -> dict[str, float]:
    """AUC, accuracy, both acceptance rates at ``threshold`` and the calibration error (10 bins)."""
    positive, negative = probabilities[labels == 1], probabilities[labels == 0]
    if not len(positive) or not len(negative):
        return {}
    from binpick.core.metrics import roc_auc

    auc = roc_auc(labels, probabilities)  # the Mann-Whitney statistic, ties counted half, as grasp quality's
    bins = np.minimum((probabilities * 10).astype(int), 9)
    ece = sum(abs(probabilities[bins == b].mean() - labels[bins == b].mean()) * (bins == b).mean() for b in range(10) if (bins == b).any())
    return {"auc": round(float(auc), 4), "accuracy": round(float(((probabilities >= threshold) == labels).mean()), 4),
            "right_accepted": round(float((positive >= threshold).mean()), 4),
            "wrong_accepted": round(float((negative >= threshold).mean()), 4), "ece": round(float(ece), 4),
            "pairs": int(len(labels)), "positives": int(len(positive))}


# ---------------------------------------------------------------------- the loop
def train_verifier(config: VerifierTrainConfig, callback: RunCallback = SILENT) -> dict[str, Any]:
    """Train (or resume), calibrate, save ``<out>/product_verifier.safetensors`` and its metrics."""
    from binpick.core import tensorfile

    torch.set_num_threads(config.threads)
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    train = collect(config.data, ("train",), config.scenes, config.min_visible, callback)
    val = collect(config.data, ("val",), config.scenes, config.min_visible, callback)
    val_pairs = fixed_pairs(val, config.seed + 1)
    look_alikes = fixed_pairs(val, config.seed + 2, repaint=1.0)  # every negative in the ordered product's colours
    net = VerifierNet(config.width)
    optimiser = torch.optim.AdamW(net.parameters(), lr=config.lr, weight_decay=1e-4)
    steps_per_epoch = max(1, len(train.windows) // config.batch_size)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimiser, config.lr, total_steps=config.epochs * steps_per_epoch, pct_start=0.1)
    history: list[dict[str, float]] = []
    start = 0
    checkpoint = out / CHECKPOINT
    if checkpoint.is_file():  # resume: the model, optimiser, schedule and history of the last whole epoch
        _, meta, state = tensorfile.load(checkpoint, FORMAT_CHECKPOINT, "verifier checkpoint")
        if {k: v for k, v in meta.get("config", {}).items() if k != "threads"} != {k: v for k, v in asdict(config).items() if k != "threads"}:
            raise ConfigError(f"{checkpoint} was written by another configuration; give another --out or delete it")
        net.load_state_dict(state["net"])
        optimiser.load_state_dict(state["optimiser"])
        schedule.load_state_dict(state["schedule"])
        history, start = meta["history"], int(meta["epoch"])
    with callback.task("verifier epochs", config.epochs, done=start) as task:
        for epoch in range(start, config.epochs):
            # each epoch's shuffle and augmentation from its own seed: a resumed run goes on exactly as the
            # uninterrupted run (one generator for the whole run would restart at the resumed epoch)
            rng = np.random.default_rng([config.seed, epoch])
            net.train()
            order = rng.permutation(len(train.windows))
            total, started = 0.0, time.perf_counter()
            for step in range(steps_per_epoch):
                photos, windows, colours, labels = batch(train, order[step * config.batch_size:(step + 1) * config.batch_size], rng, True,
                                                         config.repainted)
                loss = F.binary_cross_entropy_with_logits(net(photos, windows, colours), labels)
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
                schedule.step()
                total += loss.item()
            probabilities = torch.sigmoid(logits_of(net, val_pairs)).numpy()
            row = {"epoch": epoch + 1, "loss": round(total / steps_per_epoch, 4), "seconds": round(time.perf_counter() - started, 1),
                   **{f"val_{k}": v for k, v in scores(probabilities, val_pairs[3].numpy()).items()},
                   "val_look_alike_auc": scores(torch.sigmoid(logits_of(net, look_alikes)).numpy(), look_alikes[3].numpy()).get("auc")}
            history.append(row)
            callback.message(json.dumps(row))
            tensorfile.save(checkpoint, FORMAT_CHECKPOINT, meta={"config": asdict(config), "epoch": epoch + 1, "history": history},
                            state={"net": net.state_dict(), "optimiser": optimiser.state_dict(), "schedule": schedule.state_dict()})
            task.update(advance=1)
    net.temperature.fill_(fit_temperature(logits_of(net, val_pairs), val_pairs[3]))
    verifier = ProductVerifier(net)
    metrics = {"val": scores(torch.sigmoid(logits_of(net, val_pairs)).numpy(), val_pairs[3].numpy()),
               "val_look_alike": scores(torch.sigmoid(logits_of(net, look_alikes)).numpy(), look_alikes[3].numpy()),
               "temperature": round(float(net.temperature), 4), "train_windows": int(len(train.windows)),
               "train_products": len(train.photos), "history": history}
    verifier.save(out / "product_verifier.safetensors", {"trained_on": Path(config.data).name, "metrics": metrics["val"]})
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics


FORMAT_CHECKPOINT = "binpick.product_verifier_checkpoint"

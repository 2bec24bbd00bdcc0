"""The product check's training pairs from a binpick data set: each scene's instance windows and the
shop photos of its products, paired (same product or not) and augmented as a warehouse's light and a
detector's boxes would change them.

Positives: the ordered product's instances with its shop photos (the canonical one and the randomised
studios' views). Negatives: the other products' instances in the same bin with that photo, the
product's instances with another world's photo, a saturated instance whose hue is turned far round
(the same shape in another colour) and, optionally, another product's instance repainted in the
ordered product's colours (``repaint``: the look-alikes only shape tells apart)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from binpick.core.errors import ConfigError
from binpick.core.runs import SILENT, RunCallback
from binpick.detection.verifier import (MARGIN, SIDE, STORED, colour_features, illuminant, photo_input, to_tensor,
                                        window_input)


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

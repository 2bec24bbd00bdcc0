"""What a training image and its query go through: resizing, crops, flips and scale, colour and camera
effects (blur, noise, JPEG), with the boxes kept in step."""

from __future__ import annotations

import numpy as np
import torch
from PIL import Image


def to_tensor(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.array(image, dtype=np.uint8)).permute(2, 0, 1).float().div(255.0)


def query_photo(photo: np.ndarray, size: int, framed: bool) -> np.ndarray:
    """A shop photo (RGB, or RGBA whose alpha marks the product) as a ``size`` x ``size`` RGB query:
    framed on its product first for models with ``photo_sizes``."""
    from binpick.detection.photos import framed_on_product

    photo = framed_on_product(photo) if framed else np.ascontiguousarray(np.asarray(photo)[..., :3])
    return np.asarray(Image.fromarray(photo).resize((size, size), Image.BILINEAR))


def crop_resize(image: np.ndarray, box: np.ndarray, size: int) -> np.ndarray:
    """The pixels inside ``box`` (at least 2 px), resized to ``size`` × ``size``."""
    height, width = image.shape[:2]
    x1, y1 = int(np.clip(np.floor(box[0]), 0, width - 2)), int(np.clip(np.floor(box[1]), 0, height - 2))
    x2, y2 = int(np.clip(np.ceil(box[2]), x1 + 2, width)), int(np.clip(np.ceil(box[3]), y1 + 2, height))
    return np.asarray(Image.fromarray(image[y1:y2, x1:x2]).resize((size, size), Image.BILINEAR))


def augment(image: np.ndarray, query_box: np.ndarray, boxes: dict[str, np.ndarray], rng: np.random.Generator,
            heights: np.ndarray | None = None):
    """Box-safe augmentation: flips (which keep the robot's x and y axes, so pickability labels stay
    true), a zoom out by up to 25% onto a grey canvas, and brightness/contrast/saturation jitter.
    A height map (``heights``, or None) is flipped and zoomed with the image (onto the median
    surface, 0) and returned fourth. The random draws do not depend on it."""
    size = image.shape[0]
    image = image.astype(np.float32)
    every = {"query": query_box[None], **boxes}
    if rng.uniform() < 0.5:
        image = image[:, ::-1]
        heights = None if heights is None else heights[:, ::-1]
        every = {k: np.stack([size - v[:, 2], v[:, 1], size - v[:, 0], v[:, 3]], 1) for k, v in every.items()}
    if rng.uniform() < 0.5:
        image = image[::-1]
        heights = None if heights is None else heights[::-1]
        every = {k: np.stack([v[:, 0], size - v[:, 3], v[:, 2], size - v[:, 1]], 1) for k, v in every.items()}
    if rng.uniform() < 0.5:
        zoom = rng.uniform(0.75, 1.0)
        inner = int(round(size * zoom))
        ox, oy = rng.integers(0, size - inner + 1, size=2)
        small = np.asarray(Image.fromarray(image.astype(np.uint8)).resize((inner, inner), Image.BILINEAR), dtype=np.float32)
        canvas = np.full_like(image, 114.0)
        canvas[oy:oy + inner, ox:ox + inner] = small
        image = canvas
        if heights is not None:
            flat = np.zeros_like(heights)
            flat[oy:oy + inner, ox:ox + inner] = np.asarray(
                Image.fromarray(np.ascontiguousarray(heights), mode="F").resize((inner, inner), Image.BILINEAR))
            heights = flat
        every = {k: v * (inner / size) + np.array([ox, oy, ox, oy], dtype=np.float32) for k, v in every.items()}
    grey = image.mean(axis=2, keepdims=True)
    image = grey + (image - grey) * rng.uniform(0.7, 1.3)  # saturation
    image = (image - image.mean()) * rng.uniform(0.8, 1.2) + image.mean() * rng.uniform(0.8, 1.2)  # contrast, brightness
    image = np.clip(image, 0, 255).astype(np.uint8)
    query_box = every.pop("query")[0].astype(np.float32)
    heights = None if heights is None else np.ascontiguousarray(heights, dtype=np.float32)
    return np.ascontiguousarray(image), query_box, {k: v.astype(np.float32) for k, v in every.items()}, heights


def camera_effects(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """What another camera does to an image: exposure and white balance, sensor noise, blur
    (focus, motion) and JPEG artefacts, each now and then (Tremblay et al. 2018)."""
    import io

    from PIL import ImageFilter

    out = image.astype(np.float32)
    if rng.uniform() < 0.5:
        out = out * rng.uniform(0.6, 1.4) * rng.uniform(0.85, 1.15, 3)
    if rng.uniform() < 0.4:
        out = out + rng.normal(0, rng.uniform(1, 8), out.shape)
    result = Image.fromarray(np.clip(out, 0, 255).astype(np.uint8))
    if rng.uniform() < 0.3:
        result = result.filter(ImageFilter.GaussianBlur(rng.uniform(0.3, 1.5)))
    if rng.uniform() < 0.3:
        buffer = io.BytesIO()
        result.save(buffer, format="JPEG", quality=int(rng.integers(30, 90)))
        buffer.seek(0)
        result = Image.open(buffer).convert("RGB")
    return np.asarray(result)

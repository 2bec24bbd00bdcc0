"""Detections for one image and one query (a box in that image, or a product photo)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from binpick.core.depth import read_depth
from binpick.detection.data import crop_resize, query_photo, read_image, to_tensor
from binpick.detection.depth import depth_input
from binpick.detection.model import DetectorNetwork
from binpick.core.errors import ConfigError


@dataclass
class Prediction:
    boxes: np.ndarray  # (N, 4) x, y, w, h in the input image's pixels, best first
    scores: np.ndarray  # (N,)
    heatmaps: list[np.ndarray]  # per ROD level (H_l, W_l), empty for TDID / skip levels
    image: np.ndarray  # the input image (RGB uint8)
    query_box: np.ndarray | None  # x, y, w, h, when the query was a box
    query_image: np.ndarray | None = None  # the shop photo, when the query was one (RGB uint8)
    min_score: float = 0.0  # the threshold it was made with

    def to_json(self, min_score: float = 0.0) -> list[dict]:
        """The detections scoring at least ``min_score`` (after a pickability head's re-scoring)."""
        return [{"bbox": [round(float(v), 1) for v in box], "score": round(float(score), 4)}
                for box, score in zip(self.boxes, self.scores) if score >= min_score]

    def plot(self, min_score: float | None = None) -> np.ndarray:
        """The image with the detections (orange, with scores), the query and a legend (RGB array)."""
        from binpick.viz.detection import overlay

        return overlay(self.image, self.boxes, self.scores, self.query_box, self.query_image,
                       self.min_score if min_score is None else min_score)

    def plot_heatmaps(self) -> np.ndarray:
        """The ROD levels' max heatmaps beside the scene, titled, with a colour bar (RGB array)."""
        from binpick.viz.detection import heatmap_figure

        if not self.heatmaps:
            raise ConfigError("this detector has no ROD heatmaps (TDID or skip-only layout)")
        return heatmap_figure(self.heatmaps, self.image)

    def save(self, path: str | Path, heatmaps: bool = False) -> Path:
        """:meth:`plot` (or :meth:`plot_heatmaps`) as a PNG file, written atomically."""
        from binpick.core.files import atomic_write

        picture = self.plot_heatmaps() if heatmaps else self.plot()
        return atomic_write(Path(path), lambda handle: Image.fromarray(picture).save(handle, format="PNG"))


def parse_box(text: str) -> np.ndarray:
    """``"x,y,w,h"`` -> array; anything else is one clear line."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 4:
        raise ConfigError(f"--query-box must be x,y,w,h in pixels, got {text!r}")
    return np.array(values, dtype=np.float32)


def check_query_box(box: np.ndarray, width: int, height: int) -> None:
    x, y, w, h = box
    if w <= 0 or h <= 0:
        raise ConfigError(f"query box {box.tolist()} has zero area")
    if x < 0 or y < 0 or x + w > width + 0.5 or y + h > height + 0.5:
        raise ConfigError(f"query box {box.tolist()} lies outside the {width}x{height} image")


def predict(model: DetectorNetwork, image: np.ndarray | str | Path, query_box: np.ndarray | None = None,
            query_image: np.ndarray | str | Path | None = None, score_threshold: float = 0.1,
            depth: np.ndarray | str | Path | None = None) -> Prediction:
    """Run the detector on one image. Give ``query_box`` (x, y, w, h) for a crop query, or
    ``query_image`` for a shop photo (models trained with ``query: photo``, or TDID). Detectors that
    read depth (``model.spec.depth``) need the image's ``depth`` (metres, or a 16-bit PNG in mm); a
    pickability head that reads depth re-scores the detections only where it is given (a warning says
    when it is not); others ignore it. ``score_threshold`` applies to the detector's own scores: a
    head re-ranks what the detector found, so returned scores may lie below it."""
    if isinstance(image, (str, Path)):
        image = read_image(Path(image))
    heights = None
    if model.spec.depth and depth is None:
        raise ConfigError("this detector reads depth as well as colour: give the image's depth (--depth)")
    if model.spec.pickability == "rgbd" and depth is None:
        # finding copies needs colour only; judging which the policy picks needs depth: without it, say so
        warnings.warn("no depth given: scores are the detector's own, without its pickability head "
                      "(give the image's depth, --depth, to re-score them)", stacklevel=2)
        model = model.without_pickability()
    if model.spec.reads_depth:
        depth = read_depth(depth) if isinstance(depth, (str, Path)) else np.asarray(depth, dtype=np.float32)
        (dh, dw), (ih, iw) = depth.shape[:2], image.shape[:2]
        if depth.ndim != 2 or abs(dw * ih - iw * dh) > 0.01 * iw * dh:  # resized to the network's input: the aspect must agree
            raise ConfigError(f"depth is {dw}x{dh} but the image is {iw}x{ih}: give depth registered to the colour image, "
                              "at its size or one of the same aspect")
        heights = torch.from_numpy(depth_input(depth, model.image_size))[None, None]
    if (query_box is None) == (query_image is None):
        raise ConfigError("give exactly one of a query box or a query image")
    height, width = image.shape[:2]
    size = model.image_size
    scale = np.array([size / width, size / height] * 2, dtype=np.float32)
    resized = np.asarray(Image.fromarray(image).resize((size, size), Image.BILINEAR))
    box_xyxy = None
    if query_box is not None:
        query_box = np.asarray(query_box, dtype=np.float32)
        check_query_box(query_box, width, height)
        if model.spec.query == "photo":
            raise ConfigError("this detector was trained on shop photos: give --photo")
        box_xyxy = np.array([query_box[0], query_box[1], query_box[0] + query_box[2], query_box[1] + query_box[3]]) * scale
        query_pixels = crop_resize(resized, box_xyxy, model.query_size)
    else:
        if model.spec.method == "rod" and model.spec.query == "crop":
            raise ConfigError("this detector finds copies of a box in the image: give --query-box")
        photo = read_image(Path(query_image), keep_alpha=True) if isinstance(query_image, (str, Path)) else np.asarray(query_image)
        query_pixels = query_photo(photo, model.query_size, framed=model.spec.frames_photos)
        photo = np.ascontiguousarray(photo[..., :3])
    boxes_input = torch.tensor(box_xyxy, dtype=torch.float32)[None] if box_xyxy is not None else None
    if any(m.training for m in model.modules()):  # eval() sets every module's flag: a visible share of a 30 ms call
        model.eval()
    results, heatmaps = model.detect(to_tensor(resized)[None], boxes_input, to_tensor(query_pixels)[None],
                                     score_threshold=score_threshold, depth=heights)
    # every detection scored above the threshold by the detector stays: a pickability head only re-ranks
    # them (its probabilities multiply the scores). Dropping those it pushed under the threshold cost the
    # picker every candidate in 12 of 30 shifted-domain orders, where the head, learnt on default bins, doubts all.
    boxes, scores = results[0]["boxes"].numpy() / scale, results[0]["scores"].numpy()
    xywh = np.c_[boxes[:, :2], boxes[:, 2:] - boxes[:, :2]] if len(boxes) else np.zeros((0, 4), np.float32)
    return Prediction(xywh, scores, [h[0, 0].numpy() for h in heatmaps if h is not None],
                      image, query_box, None if query_image is None else photo, score_threshold)

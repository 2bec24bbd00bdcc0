"""A detector as an ONNX graph for deployment, and an ONNX Runtime network that predicts as the
PyTorch one does.

The graph is the photo-query detector's network (colour, the shop photo at each of its sizes, depth
where it reads depth) up to its decoded boxes and scores, at the detector's fixed input size. What
stays in Python on both paths: the photo's antialiased resizing (ONNX's resize does not antialias
the same way), non-maximum suppression, and a pickability head's re-scoring of the detections (it
runs on windows cut around them, a graph of its own). The correlation of the photo's features with
the scene's is exported as a convolution with the photo's features as its kernel: the FFT that
PyTorch uses on a CPU (binpick.detection.rod) becomes ONNX DFT nodes that ONNX Runtime runs ~20x
slower; both give the same result up to rounding.

``pip install 'binpick[onnx]'`` brings onnx, onnxscript (the exporter) and onnxruntime.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from binpick.core.errors import ConfigError, InputFileError
from binpick.detection import rod
from binpick.detection.model import DetectorNetwork

OPSET = 18
FORMAT = "binpick-detector-onnx-1"
RUNTIMES = ("torch", "onnx")


def require_onnx() -> None:
    missing = [name for name in ("onnx", "onnxscript", "onnxruntime") if _absent(name)]
    if missing:
        raise ConfigError(f"the ONNX path needs {', '.join(missing)}: pip install 'binpick[onnx]'")


def _absent(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is None


def _correlate_by_convolution(features: torch.Tensor, weight: torch.Tensor, sum_channels: bool) -> torch.Tensor:
    """:func:`binpick.detection.rod._fft_correlate` for one sample as a plain convolution: features
    (1, 1, C, H, W), weight (1, D, C, k_h, k_w) odd sides -> (1, D, H, W)."""
    if not sum_channels or features.shape[0] != 1:
        raise ConfigError("ONNX export covers ROD's summed correlation at batch 1")
    kernel = weight[0]
    return F.conv2d(features[:, 0], kernel, padding=(kernel.shape[-2] // 2, kernel.shape[-1] // 2))


@contextmanager
def correlation_by_convolution() -> Iterator[None]:
    original = rod._fft_correlate
    rod._fft_correlate = _correlate_by_convolution
    try:
        yield
    finally:
        rod._fft_correlate = original


class ExportedGraph(nn.Module):
    """What the ONNX file computes: (images, photo_0 .. photo_k[, depth]) -> (boxes xyxy, scores)."""

    def __init__(self, network: DetectorNetwork) -> None:
        super().__init__()
        self.network = network

    def forward(self, images: torch.Tensor, *rest: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        photos, depth = (rest[:-1], rest[-1]) if self.network.spec.depth else (rest, None)
        out = self.network(images, None, list(photos), depth)
        return self.network.decode(out["raw"])


def input_names(network: DetectorNetwork) -> list[str]:
    return ["images", *(f"photo_{i}" for i in range(len(network.spec.photo_sizes))), *(["depth"] if network.spec.depth else [])]


def check_exportable(network: DetectorNetwork) -> None:
    spec = network.spec
    if spec.method != "rod" or spec.query != "photo" or not spec.photo_sizes:
        raise ConfigError("ONNX export covers photo-query ROD detectors (the ones that fulfil orders, e.g. "
                          "rod_photo_learnt_tiny_320); this one is a "
                          f"{spec.method} detector with {spec.query} queries")


def exported_network(network: DetectorNetwork) -> DetectorNetwork:
    """What the graph holds: the detector without its pickability head, batch norms folded."""
    plain = network.without_pickability()
    return plain if plain.inference_only else plain.for_inference()


def weights_digest(network: DetectorNetwork) -> str:
    """A digest of the exported network's tensors: an ONNX file names the weights it was made from."""
    digest = hashlib.sha256()
    for name, tensor in sorted(exported_network(network).state_dict().items()):
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()[:16]


def export_onnx(network: DetectorNetwork, path: str | Path) -> Path:
    """Write ``network`` (its detector, without a pickability head) as ONNX to ``path``, atomically;
    metadata says its input size, photo sides and the digest of the weights it came from."""
    require_onnx()
    check_exportable(network)
    import onnx

    from binpick.core.files import atomic_write

    path = Path(path)
    plain = exported_network(network).eval()
    size = plain.image_size
    example = [torch.zeros(1, 3, size, size), *(torch.zeros(1, 3, s, s) for s in plain.photo_sides(size))]
    if plain.spec.depth:
        example.append(torch.zeros(1, 1, size, size))
    quiet = logging.getLogger("torch.onnx")  # "torchvision is not installed. Skipping ...": nothing of ours
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        with torch.no_grad(), correlation_by_convolution(), warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            warnings.simplefilter("ignore", DeprecationWarning)
            program = torch.onnx.export(ExportedGraph(plain).eval(), tuple(example), dynamo=True, opset_version=OPSET,
                                        input_names=input_names(plain), output_names=["boxes", "scores"], verbose=False)
    finally:
        quiet.setLevel(level)
    model = program.model_proto
    meta = {"format": FORMAT, "image_size": size, "photo_sides": plain.photo_sides(size),
            "spec": json.dumps(plain.spec.__dict__ | {"photo_sizes": list(plain.spec.photo_sizes), "scales": list(plain.spec.scales)}),
            "weights": weights_digest(network)}
    for key, value in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, str(value)
    atomic_write(path, lambda handle: handle.write(model.SerializeToString()))
    onnx.checker.check_model(str(path))
    return path


def cache_name(network: DetectorNetwork) -> str:
    """The cached graph's file name: the weights' digest and what the export makes of them."""
    return f"detector-{weights_digest(network)}-{FORMAT}-opset{OPSET}.onnx"


def cached_export(network: DetectorNetwork) -> Path:
    """The network's ONNX file in binpick's cache ($XDG_CACHE_HOME/binpick/onnx, keyed by the weights'
    digest), exported on first use (seconds)."""
    from binpick.core.files import cache_folder

    cache = cache_folder("onnx")
    path = cache / cache_name(network)
    if not path.is_file():
        from binpick.core.files import ensure_dir

        ensure_dir(cache, "ONNX cache")
        export_onnx(network, path)
    return path


def read_metadata(path: Path) -> dict[str, str]:
    import onnx

    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as error:  # a damaged or foreign file: one line
        raise InputFileError(f"{str(path)!r} is not an ONNX file: {error}") from None
    meta = {p.key: p.value for p in model.metadata_props}
    if meta.get("format") != FORMAT:
        raise InputFileError(f"{str(path)!r} is not a binpick detector exported to ONNX (binpick detect export)")
    return meta


class OnnxNetwork:
    """A :class:`DetectorNetwork` for prediction whose detector runs in ONNX Runtime: ``detect`` takes
    and returns what the PyTorch network's does (no heatmaps), so :func:`predict`, the picker and
    the nodes use it unchanged. The PyTorch network it came from supplies what the graph does not
    hold (its spec, the photo resizing, a pickability head's re-scoring)."""

    def __init__(self, network: DetectorNetwork, onnx_path: str | Path, threads: int | None = None) -> None:
        require_onnx()
        import onnxruntime

        check_exportable(network)
        self.network, self.path = network, Path(onnx_path)
        meta = read_metadata(self.path)
        expected = weights_digest(network)
        if meta.get("weights") != expected:
            raise ConfigError(f"{str(self.path)!r} was exported from other weights (digest {meta.get('weights')}, these "
                              f"{expected}): export them again (binpick detect export)")
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads or max(1, min(4, os.cpu_count() or 1))
        options.inter_op_num_threads = 1
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")  # idle threads sleep: 2 cores are shared
        self.session = onnxruntime.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])

    def __getattr__(self, name: str) -> Any:  # spec, image_size, query_size, score_threshold, ...: the network's
        if name in ("network", "session", "path"):
            raise AttributeError(name)
        return getattr(self.network, name)

    def modules(self):
        return iter(())  # nothing to put in eval mode: the graph is inference only

    def without_pickability(self) -> OnnxNetwork:
        plain = object.__new__(OnnxNetwork)
        plain.network, plain.path, plain.session = self.network.without_pickability(), self.path, self.session
        return plain

    @torch.no_grad()
    def detect(self, images: torch.Tensor, query_boxes: torch.Tensor | None = None, query_images: torch.Tensor | None = None,
               score_threshold: float = 0.01, iou_threshold: float = 0.45, max_detections: int = 100,
               depth: torch.Tensor | None = None) -> tuple[list[dict[str, torch.Tensor]], list]:
        if query_images is None or images.shape[0] != 1:
            raise ConfigError("the ONNX detector takes one image and its shop photo")
        net = self.network
        feeds = {"images": images.float().numpy()}
        for i, photo in enumerate(net.sized_photos(query_images.float(), net.image_size)):
            feeds[f"photo_{i}"] = photo.numpy()
        if net.spec.depth:
            if depth is None:
                raise ConfigError("this detector reads depth as well as colour: give the scene's depth image")
            feeds["depth"] = depth.float().numpy()
        boxes, scores = self.session.run(["boxes", "scores"], feeds)
        results = net.select(torch.from_numpy(np.asarray(boxes)), torch.from_numpy(np.asarray(scores)), score_threshold,
                             iou_threshold, max_detections)
        if net.pickability is not None:
            results = net.rescore(images, depth, results, query_boxes, query_images)
        return results, []

"""The picking detector exported to ONNX finds the same boxes as in PyTorch (IoU >= 0.99, scores within
1e-3), runs where the PyTorch one runs (Picker, binpick plan), and refuses what it cannot be."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest
from conftest import binpick_here

from binpick.core.errors import BinpickError, ConfigError
from binpick.detection import Detector
from binpick.detection.detector import PICKING
from binpick.samples import SAMPLE_FRAME

pytest.importorskip("onnxruntime")


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The picking detector exported once, by the command a user runs."""
    folder = tmp_path_factory.mktemp("export")
    ran = binpick_here(["detect", "export", PICKING, "--out", str(folder)])
    assert ran.returncode == 0, ran.stderr
    return folder / f"{PICKING}.onnx"


@pytest.fixture(scope="module")
def detectors(exported):
    return Detector.load(PICKING), Detector.load(PICKING).using("onnx", exported)


def iou(a, b) -> float:
    w = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    return w * h / (a[2] * a[3] + b[2] * b[3] - w * h)


def test_onnx_finds_the_same_boxes_as_pytorch_on_frames_it_was_not_exported_with(detectors):
    from binpick.core.files import read_image
    from binpick.core.depth import read_depth

    rgb, photo = read_image(SAMPLE_FRAME / "rgb.png"), read_image(SAMPLE_FRAME / "photo.png", keep_alpha=True)
    depth = read_depth(SAMPLE_FRAME / "depth.png")
    torch_detector, onnx_detector = detectors
    compared = 0
    for frame, frame_depth in ((rgb, depth), (rgb[:, ::-1].copy(), depth[:, ::-1].copy()), (np.roll(rgb, 40, 0), np.roll(depth, 20, 0))):
        a = torch_detector.predict(frame, query_image=photo, depth=frame_depth, min_score=0.05)
        b = onnx_detector.predict(frame, query_image=photo, depth=frame_depth, min_score=0.05)
        assert len(a.boxes) == len(b.boxes) >= 1
        for box_a, box_b, score_a, score_b in zip(a.boxes, b.boxes, a.scores, b.scores):
            assert iou(box_a, box_b) >= 0.99 and abs(float(score_a) - float(score_b)) <= 1e-3
            compared += 1
    assert compared >= 5
    assert onnx_detector.runtime == "onnx" and type(onnx_detector.inference_network).__name__ == "OnnxNetwork"


def test_the_export_is_a_checked_onnx_file_that_names_its_weights(detectors, exported):
    import onnx

    from binpick.detection.onnx_runtime import read_metadata, weights_digest

    torch_detector, _ = detectors
    path = exported
    onnx.checker.check_model(str(path))
    meta = read_metadata(path)
    assert meta["weights"] == weights_digest(torch_detector.network) and meta["image_size"] == "320"
    inputs = [i.name for i in onnx.load(str(path)).graph.input]
    assert inputs == ["images", "photo_0", "photo_1", "photo_2", "photo_3"]


def test_what_cannot_be_exported_or_loaded_is_one_line(detectors, exported, tmp_path):
    from binpick.detection.onnx_runtime import OnnxNetwork, read_metadata

    with pytest.raises(ConfigError, match="photo-query ROD detectors"):
        Detector.load("rod_tiny_320").export("onnx", tmp_path / "crop.onnx")
    with pytest.raises(ConfigError, match="format must be one of 'onnx'"):
        detectors[0].export("openvino", tmp_path / "x")
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    with pytest.raises(BinpickError, match="not an ONNX file"):
        read_metadata(tmp_path / "junk.onnx")
    import copy

    import torch

    other = copy.deepcopy(Detector.load("rod_photo_learnt_tiny_320").inference_network)  # the same network, one weight moved
    with torch.no_grad():
        first = next(other.parameters())
        first.add_(0.01 * (torch.arange(first.numel()).reshape(first.shape) == 0))
    with pytest.raises(ConfigError, match="exported from other weights"):
        OnnxNetwork(other, exported)


def test_binpick_plan_with_onnx_plans_the_grasps_pytorch_plans(tmp_path, exported, detectors):
    from binpick.detection.onnx_runtime import cache_name

    cache = tmp_path / "cache"  # the command finds its export in the cache, named by the weights' digest
    (cache / "binpick" / "onnx").mkdir(parents=True)
    shutil.copy(exported, cache / "binpick" / "onnx" / cache_name(detectors[0].network))
    env = {**os.environ, "XDG_CACHE_HOME": str(cache)}
    for runtime in ("torch", "onnx"):
        ran = binpick_here(["plan", "--sample", "--out", str(tmp_path / runtime), "--runtime", runtime], env=env)
        assert ran.returncode == 0, ran.stderr
    a, b = (json.loads((tmp_path / r / "plan.json").read_text()) for r in ("torch", "onnx"))
    assert np.allclose([p["box"] for p in a["plans"]], [p["box"] for p in b["plans"]], atol=0.5)
    assert a["grasps"] == b["grasps"] >= 1
    assert [p.name for p in (cache / "binpick" / "onnx").iterdir()] == [cache_name(detectors[0].network)]

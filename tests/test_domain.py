"""Domain randomisation: validated domains, randomised bins whose recorded camera is the one
that rendered them, a shifted domain outside the training ranges, Ray scene workers, and the training
pieces that make pre-training affordable (batched correlation, batched loss, joint training)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from binpick.core.errors import ConfigError
from binpick.sim.domain import DomainConfig, draw_camera, load_domain
from binpick.warehouse.dataset import generate
from binpick.warehouse.generation import GenerateConfig


def _random(tmp_path, name: str, **changes) -> GenerateConfig:
    settings = dict(out=str(tmp_path / name), scenes=4, policies=[], workers=1, image_size=96, copies=(2, 3),
                    distractors=(0, 1), domain="random", scenes_per_world=2, val_fraction=0.5, seed=3)
    return GenerateConfig(**{**settings, **changes})


def test_domains_load_validate_and_the_shifted_one_lies_outside_training():
    assert load_domain("default") == DomainConfig() and not DomainConfig().randomise
    train, shifted = load_domain("random"), load_domain("shifted")
    for name in ("camera_height", "camera_tilt", "camera_fovy", "tote_half_x", "tote_half_y", "wall_height",
                 "light_intensity", "ambient"):
        low, high = getattr(train, name)
        s_low, s_high = getattr(shifted, name)
        assert s_high < low or s_low > high, name  # disjoint ranges
    assert shifted.textures != train.textures
    with pytest.raises(ConfigError, match="neither a known domain"):
        load_domain("nowhere")
    with pytest.raises(ConfigError, match="camera_tilt"):
        DomainConfig(camera_tilt=(10.0, 90.0))
    with pytest.raises(ConfigError, match="low <= high"):
        DomainConfig(camera_height=(1.0, 0.5))


def test_a_camera_draw_looks_at_the_tote_from_the_asked_height_and_tilt():
    domain = DomainConfig(randomise=True, camera_height=(0.8, 0.8), camera_tilt=(30.0, 30.0), camera_yaw=(20.0, 20.0))
    draw = draw_camera(domain, np.random.default_rng(0), 128, 0.03)
    transform = np.array(draw.extrinsics())
    assert transform[2, 3] == pytest.approx(0.8)
    forward = transform[:3, 2]  # OpenCV z: the viewing direction
    assert np.degrees(np.arccos(-forward[2])) == pytest.approx(30.0, abs=1e-3)
    fx, fy, cx, cy = draw.intrinsics()
    look = np.linalg.inv(transform) @ np.array([0.0, 0.0, 0.03, 1.0])  # the aim point projects to the centre
    u, v = fx * look[0] / look[2] + cx, fy * look[1] / look[2] + cy
    assert (u, v) == pytest.approx((cx, cy), abs=0.5)


@pytest.mark.slow
def test_randomised_bins_record_the_camera_that_rendered_them_and_resume(tmp_path):
    stats = generate(_random(tmp_path, "dr"))
    assert stats["scenes"] == 4 and stats["splits"] == {"train": 2, "val": 2}
    coco = json.loads((tmp_path / "dr" / "annotations.json").read_text())
    names = {c["name"] for c in coco["categories"]}
    assert {"random/000000_0", "random/000001_0"} <= names  # each world's own products
    assert (tmp_path / "dr" / "photos" / "random_000000_0.png").is_file()
    errors = []
    for image in coco["images"]:
        camera = image["camera"]
        K, transform = np.array(camera["K"]), np.array(camera["camera_to_world"])
        for a in (a for a in coco["annotations"] if a["image_id"] == image["id"] and a["is_target"]):
            record = json.loads((tmp_path / "dr" / "scenes" / f"{image['id'] - 1:06d}.json").read_text())
            position = next(r["position"] for r in record["annotations"] if r["bbox"] == a["bbox"])
            point = np.linalg.inv(transform) @ np.array([*position, 1.0])
            u, v = (K @ point[:3])[:2] / point[2]
            x, y, w, h = a["bbox"]
            errors.append(max(abs(u - (x + w / 2)) / w, abs(v - (y + h / 2)) / h))
    assert np.median(errors) < 0.25  # the product's origin projects into the middle of its own box
    cameras = {json.dumps(i["camera"]["camera_to_world"]) for i in coco["images"]}
    assert len(cameras) == 4  # a new camera per scene
    with pytest.raises(ConfigError, match="made with other settings"):
        generate(_random(tmp_path, "dr", domain="shifted"))


@pytest.mark.slow
def test_ray_scene_workers_make_the_same_data_set_as_local_processes(tmp_path):
    os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    generate(_random(tmp_path, "local"))
    from binpick.core.jobs import run_job
    from binpick.warehouse.dataset import DataGeneration

    run_job(DataGeneration.new(_random(tmp_path, "ray", workers=1)), address="local")  # as `binpick train data.yaml --address local`
    local = json.loads((tmp_path / "local" / "annotations.json").read_text())
    ray = json.loads((tmp_path / "ray" / "annotations.json").read_text())
    assert [a["bbox"] for a in ray["annotations"]] == [a["bbox"] for a in local["annotations"]]
    assert (tmp_path / "ray" / "images" / "000003.png").read_bytes() == (tmp_path / "local" / "images" / "000003.png").read_bytes()


def test_bad_domain_and_cluster_address_are_one_line(tmp_path):
    with pytest.raises(ConfigError, match="neither a known domain"):
        _random(tmp_path, "x", domain="mars")
    with pytest.raises(ConfigError, match="--address must be HOST:PORT"):
        _random(tmp_path, "x", address="nowhere")
    bad = tmp_path / "bad.yaml"
    bad.write_text("randomise: true\ncamera_fovy: [10, 200]\n")
    with pytest.raises(ConfigError, match="camera_fovy"):
        load_domain(str(bad))


def test_batched_fft_correlation_equals_one_convolution_per_sample():
    from binpick.detection.rod import correlate_batch, correlate_scales

    torch.manual_seed(0)
    features = torch.randn(3, 8, 13, 17)
    kernels = [torch.randn(8, 3, 5), torch.randn(8, 2, 2), torch.randn(8, 7, 1)]  # even sizes too
    got = correlate_batch(features, kernels)
    for b, kernel in enumerate(kernels):
        direct = F.conv2d(features[b:b + 1], kernel[None], padding="same")[0, 0] / (kernel.shape[1] * kernel.shape[2])
        assert torch.allclose(got[b], direct, atol=1e-5)
    # several kernels per sample, of other sizes, share each sample's transform: still one convolution each
    per_sample = [[kernel, torch.randn(8, 9, 3)] for kernel in kernels]
    got = correlate_scales(features, per_sample)
    assert got.shape == (3, 2, 13, 17)
    for b, sample in enumerate(per_sample):
        for d, kernel in enumerate(sample):
            direct = F.conv2d(features[b:b + 1], kernel[None], padding="same")[0, 0] / (kernel.shape[1] * kernel.shape[2])
            assert torch.allclose(got[b, d], direct, atol=1e-5)


def test_batched_loss_assigns_what_the_per_image_rule_assigns():
    from binpick.detection.losses import assign, assign_batch
    from binpick.detection.model import DetectorNetwork, ModelSpec

    torch.manual_seed(1)
    model = DetectorNetwork(ModelSpec(), 128)
    out = model(torch.rand(3, 3, 128, 128), torch.tensor([[10.0, 10.0, 40.0, 40.0]] * 3))
    boxes, _ = model.decode(out["raw"])
    targets = [torch.tensor([[5.0, 5.0, 30.0, 40.0], [5.0, 5.0, 30.0, 40.0], [60, 70, 90, 110.0]]),
               torch.zeros(0, 4), torch.tensor([[100.0, 2.0, 126.0, 20.0]])]
    image, target, level, anchor, row, col = assign_batch(out["raw"], boxes, targets)
    offsets = np.cumsum([0] + [len(t) for t in targets])
    batched = sorted((int(i), int(t) - offsets[int(i)], int(lv), int(a), int(r), int(c))
                     for i, t, lv, a, r, c in zip(image, target, level, anchor, row, col))
    single = sorted((b, *pair) for b in range(3) for pair in assign(model, out["raw"], boxes[b], targets[b]))
    assert batched == single and len(single) == 4  # the duplicate target takes the next-best anchor


def test_joint_training_feeds_every_detector_the_same_batches_and_keeps_the_best(tmp_path):
    from synthetic_coco import make_coco

    from binpick.detection.config import DetectConfig
    from binpick.core.config import load_config
    from binpick.detection.joint import JointTraining
    from binpick.detection.train import DetectorTrainer

    path = make_coco(tmp_path / "toy", images=8, size=64, seed=2)
    config = tmp_path / "rod.yaml"
    config.write_text(f"""name: a
data: {{train: {path}, val: {path}, targets: all, image_size: 64, train_sizes: [64, 96], photometric: true}}
train: {{epochs: 2, batch_size: 4, warmup_steps: 2, eval_every: 1, workers: 0, threads: 1, keep_best: true}}
""")
    seen: dict[str, list] = {"a": [], "b": []}
    trainers = [DetectorTrainer.new(load_config(DetectConfig, config, {"name": name, **extra}), tmp_path / "runs")
                for name, extra in (("a", {}), ("b", {"loss.heatmap": 0.0}))]
    for trainer in trainers:
        original = trainer.train_step

        def recording(batch, sums, trainer=trainer, original=original):
            seen[trainer.config.name].append(batch["image"].sum().item())
            return original(batch, sums)
        trainer.train_step = recording
    metrics = JointTraining(trainers).run()
    assert seen["a"] == seen["b"] and len(seen["a"]) == 4  # 2 epochs of 2 batches, the same for both
    assert metrics["a"]["steps"] == metrics["b"]["steps"] == 4
    for trainer in trainers:
        assert (trainer.run_dir / "best.safetensors").is_file() and (trainer.run_dir / "model.safetensors").is_file()
    other = load_config(DetectConfig, config, {"name": "c", "data.image_size": 96})
    with pytest.raises(ConfigError, match="same data section"):
        JointTraining([trainers[0], DetectorTrainer.new(other, tmp_path / "runs")])

"""Grasps from depth alone: the camera model, candidates with their widths and clearance,
the watershed that tells touching products apart, the policies, and the grasp-quality model's files."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from binpick.core.errors import ConfigError, InputFileError
from binpick.grasping import DepthFrame, GraspPlanner, JawGripper, PinholeCamera, grasp_candidates
from binpick.core.depth import read_depth
from binpick.grasping.instance import instance_surface, watershed_labels
from binpick.grasping.quality import GraspQuality, height_map
from binpick.grasping.training import roc_auc

SIZE, HEIGHT = 200, 0.8  # a camera 0.8 m above a floor at z = 0, looking straight down
K = np.array([[400.0, 0.0, 99.5], [0.0, 400.0, 99.5], [0.0, 0.0, 1.0]])
DOWN = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, HEIGHT], [0, 0, 0, 1.0]])  # OpenCV axes, z down


def camera() -> PinholeCamera:
    return PinholeCamera(K, SIZE, SIZE, DOWN)


def scene_depth(boxes) -> np.ndarray:
    """Depth of a floor with axis-aligned blocks: (x0, x1, y0, y1, height) in world metres."""
    pixels = camera().points(np.full((SIZE, SIZE), HEIGHT))
    heights = np.zeros((SIZE, SIZE))
    for x0, x1, y0, y1, h in boxes:
        inside = (pixels[..., 0] >= x0) & (pixels[..., 0] <= x1) & (pixels[..., 1] >= y0) & (pixels[..., 1] <= y1)
        heights = np.where(inside, np.maximum(heights, h), heights)
    return (HEIGHT - heights).astype(np.float32)


def frame_of(depth, cam: PinholeCamera | None = None) -> DepthFrame:
    return DepthFrame.from_depth(depth, cam or camera())


def box_of(cam: PinholeCamera, x0, x1, y0, y1, h) -> tuple[float, float, float, float]:
    corners = np.array([[x, y, h] for x in (x0, x1) for y in (y0, y1)])
    uv, _ = cam.project(corners)
    return (float(uv[:, 0].min()), float(uv[:, 1].min()), float(np.ptp(uv[:, 0])), float(np.ptp(uv[:, 1])))


def test_points_and_projection_invert_each_other_and_bad_intrinsics_are_one_line():
    cam = camera()
    points = cam.points(np.full((SIZE, SIZE), 0.5))
    uv, depth = cam.project(points[10, 150])
    assert np.allclose(uv, [150, 10]) and np.isclose(depth, 0.5)
    assert np.allclose(points[..., 2], HEIGHT - 0.5)
    assert points[0, 199, 0] > 0 and points[0, 199, 1] > 0  # image right = +x, image up = +y
    assert PinholeCamera.from_record(cam.to_record()).K.tolist() == K.tolist()
    with pytest.raises(ConfigError, match=r"\[\[fx, s, cx\]"):
        PinholeCamera(np.zeros((3, 3)), 10, 10)
    with pytest.raises(ConfigError, match="no 'K' field"):
        PinholeCamera.from_record({"width": 10, "height": 10})


def test_an_elongated_block_is_grasped_across_its_narrow_side():
    cam = camera()
    block = (-0.02, 0.02, -0.06, 0.06, 0.05)  # 4 cm wide along x, 12 cm long along y
    surface, candidates = grasp_candidates(frame_of(scene_depth([block])), box_of(cam, *block))
    assert surface is not None and abs(surface.top - 0.05) < 0.003 and abs(surface.support) < 0.003
    assert surface.elongation > 2 and abs(np.cos(surface.minor_yaw)) > 0.99  # close along x
    across = min(candidates, key=lambda c: abs(np.sin(c.yaw)))  # yaw 0: jaws along x
    along = min(candidates, key=lambda c: abs(np.cos(c.yaw)))
    assert across.rejected is None and abs(across.width - 0.04) < 0.006 and np.allclose(across.position[:2], 0, atol=0.004)
    assert along.rejected.startswith("too wide") and along.width > 0.11
    assert 0.0059 <= across.position[2] <= 0.05 - 0.02  # tips below the top, clear of the floor
    choice = GraspPlanner("analytic").choose(frame_of(scene_depth([block])), box_of(cam, *block))
    assert abs(np.sin(choice.chosen.yaw)) < 0.2 and choice.rejections().get("too wide across the jaws", 0) >= 3
    fixed = GraspPlanner("fixed").choose(frame_of(scene_depth([block])), box_of(cam, *block))
    assert abs(fixed.chosen.yaw - np.pi / 2) < 1e-6 and fixed.chosen.rejected  # today's grasp: tried regardless


def test_a_tall_neighbour_blocks_the_finger_that_would_land_on_it():
    cam = camera()
    block, wall = (-0.02, 0.02, -0.06, 0.06, 0.04), (0.045, 0.09, -0.1, 0.1, 0.12)  # a wall 2.5 cm to its +x side
    surface, candidates = grasp_candidates(frame_of(scene_depth([block, wall])), box_of(cam, *block))
    across = min(candidates, key=lambda c: abs(np.sin(c.yaw)))
    assert across.rejected.startswith("finger blocked") and across.clearance < -0.05
    choice = GraspPlanner("analytic").choose(frame_of(scene_depth([block, wall])), box_of(cam, *block))
    assert choice.chosen is None and "finger blocked" in choice.reason


def test_the_watershed_tells_two_touching_lying_cylinders_apart():
    cam = camera()
    pixels = cam.points(np.full((SIZE, SIZE), HEIGHT))
    x, y = pixels[..., 0], pixels[..., 1]
    radius = 0.03
    heights = np.zeros((SIZE, SIZE))
    for cx in (-radius, radius):  # two cylinders along y, touching at x = 0
        inside = (np.abs(x - cx) < radius) & (np.abs(y) < 0.08)
        heights = np.where(inside, np.maximum(heights, radius + np.sqrt(np.clip(radius ** 2 - (x - cx) ** 2, 0, None))), heights)
    labels = watershed_labels(heights, 0.01, heights.max())
    left, right = labels[100, 100 - 24], labels[100, 100 + 24]  # the two ridges
    assert left > 0 and right > 0 and left != right
    points = frame_of(HEIGHT - heights)
    surface = instance_surface(points, box_of(cam, -2 * radius, 0, -0.08, 0.08, 2 * radius))
    assert surface is not None and abs(surface.centre[0] + radius) < 0.006 and np.ptp(surface.xy[:, 0]) < 2 * radius + 0.006
    _, candidates = grasp_candidates(points, box_of(cam, -2 * radius, 0, -0.08, 0.08, 2 * radius))
    across = min(candidates, key=lambda c: abs(np.sin(c.yaw)))
    assert abs(across.width - 2 * radius) < 0.008  # one cylinder's width, not both


def test_depth_files_in_millimetres_or_metres_and_wrong_units_are_one_line(tmp_path):
    metres = np.full((4, 5), 0.8, dtype=np.float32)
    Image.fromarray((metres * 1000).astype(np.uint16)).save(tmp_path / "d.png")
    np.save(tmp_path / "d.npy", metres)
    assert np.allclose(read_depth(tmp_path / "d.png"), 0.8) and np.allclose(read_depth(tmp_path / "d.npy"), 0.8)
    np.save(tmp_path / "zeros.npy", np.zeros((4, 5)))
    np.save(tmp_path / "mm.npy", metres * 1000)
    Image.fromarray(np.zeros((4, 5, 3), np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(InputFileError, match="no valid reading"):
        read_depth(tmp_path / "zeros.npy")
    with pytest.raises(InputFileError, match="800 m at its median"):
        read_depth(tmp_path / "mm.npy")
    with pytest.raises(InputFileError, match="single-channel 16-bit PNG"):
        read_depth(tmp_path / "rgb.png")


def test_the_quality_model_scores_candidates_and_round_trips_through_safetensors(tmp_path):
    cam = camera()
    block = (-0.02, 0.02, -0.06, 0.06, 0.05)
    points = frame_of(scene_depth([block]))
    _, candidates = grasp_candidates(points, box_of(cam, *block))
    grid = height_map(points, candidates[1].position, 0.0, candidates[1].top, candidates[1].support)
    assert grid.shape == (32, 32) and grid[16, 16] > 0.3 and grid[16, 0] < 0  # the block's top above the tips, floor below
    model = GraspQuality()
    scores = model.score(points, candidates)
    assert scores.shape == (len(candidates),) and np.all((scores > 0) & (scores < 1))
    model.save(tmp_path / "q.safetensors")
    again = GraspQuality.load(tmp_path / "q.safetensors")
    assert np.allclose(again.score(points, candidates), scores, atol=1e-6)
    planner = GraspPlanner("learnt", again)
    assert planner.choose(points, box_of(cam, *block)).chosen.quality == pytest.approx(max(
        s for s, c in zip(scores, candidates) if c.rejected is None), abs=1e-6)
    (tmp_path / "bad.safetensors").write_bytes(b"not a file")
    with pytest.raises(InputFileError, match="not a safetensors file"):
        GraspQuality.load(tmp_path / "bad.safetensors")
    with pytest.raises(ConfigError, match="needs a grasp-quality model"):
        GraspPlanner("learnt")
    with pytest.raises(ConfigError, match="unknown grasp policy 'sideways'"):
        GraspPlanner("sideways")


def test_roc_auc_counts_ranked_pairs_and_ties_half():
    assert roc_auc([0, 0, 1, 1], [0.1, 0.2, 0.3, 0.4]) == 1.0
    assert roc_auc([0, 0, 1, 1], [0.4, 0.3, 0.2, 0.1]) == 0.0
    assert roc_auc([0, 1, 0, 1], [0.5, 0.5, 0.1, 0.9]) == pytest.approx(0.875)  # one tie of four pairs
    assert roc_auc([1, 1], [0.2, 0.3]) is None


def test_the_planner_imports_no_simulator():
    code = "import sys, binpick.grasping, binpick.grasping.quality; assert 'mujoco' not in sys.modules, 'mujoco imported'"
    ran = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert ran.returncode == 0, ran.stderr


def test_the_default_gripper_matches_the_simulated_one():
    from binpick.sim import gripper

    assert JawGripper().opening == gripper.OPENING


def test_grasp_trials_and_planned_pickability_are_recorded_and_the_quality_model_trains_and_resumes_on_them(tmp_path):
    from binpick.grasping.training import QualityTrainConfig, QualityTrainer, load_trials
    from binpick.warehouse.dataset import DataGeneration
    from binpick.warehouse.generation import GenerateConfig

    data = tmp_path / "trials"
    DataGeneration.new(GenerateConfig(out=str(data), scenes=4, policies=["analytic"], grasp_trials=2, workers=1, image_size=128,
                                      copies=(2, 3), distractors=(0, 1), targets=["can", "procedural_box"], scenes_per_world=1,
                                      val_fraction=0.5)).run()
    records = [__import__("json").loads(p.read_text()) for p in sorted((data / "scenes").glob("*.json"))]
    trials = [t for r in records for t in r["grasp_trials"]]
    assert trials and all(isinstance(t["success"], bool) and len(t["position"]) == 3 and 0 <= t["yaw"] < np.pi for t in trials)
    assert f"| grasp trials (candidates from depth, executed with a carry) | {len(trials)}," in (data / "CARD.md").read_text()
    assert {r["split"] for r in records} == {"train", "val"}
    targets = [a for r in records for a in r["annotations"] if a["is_target"]]
    assert targets and all(isinstance(a["pickable"]["analytic"], bool) for a in targets)  # labelled by the planner's policy
    train = load_trials(data, "train")
    assert len(train) > 0 and train.maps.shape[1:] == (32, 32) and set(np.unique(train.labels)) <= {0.0, 1.0}
    config = QualityTrainConfig(data=str(data), epochs=1, batch_size=2, threads=1)
    first = QualityTrainer.new(config, tmp_path / "runs")
    first.run()
    assert (first.run_dir / "checkpoints" / "latest").is_file() and first.epoch == 1
    import yaml

    (first.run_dir / "config.yaml").write_text(yaml.safe_dump({**yaml.safe_load((first.run_dir / "config.yaml").read_text()), "epochs": 2}))
    again = QualityTrainer.resume(first.run_dir)
    assert again.epoch == 1  # continues from the checkpoint, not from zero
    metrics = again.run()
    assert metrics["epochs"] == 2 and len(metrics["history"]) == 2
    GraspQuality.load(first.run_dir / "model.safetensors")


def test_an_instance_in_a_corner_gets_a_push_away_from_both_walls_and_one_in_the_open_none():
    from binpick.grasping.push import PUSH_DISTANCE, plan_push

    cam = camera()
    block = (0.02, 0.06, 0.02, 0.06, 0.04)  # 4 cm square, 4 cm high, in the corner of two 12 cm walls
    walls = [(0.065, 0.1, -0.1, 0.1, 0.12), (-0.1, 0.1, 0.065, 0.1, 0.12)]  # beyond +x and beyond +y, 5 mm off it
    frame = frame_of(scene_depth([block, *walls]))
    choice = GraspPlanner("analytic").choose(frame, box_of(cam, *block))
    assert choice.chosen is None and "finger blocked" in choice.reason  # no room for either finger
    push = plan_push(frame, choice.surface)
    assert push is not None
    direction = (push.end - push.start)[:2]
    assert np.isclose(np.linalg.norm(direction), PUSH_DISTANCE) and direction[0] < -0.02 and direction[1] < -0.02  # out of the corner
    assert 0.04 - 0.012 < push.start[2] < 0.04  # the closed tips press on its top
    assert push.start[0] > 0.04 and push.start[1] > 0.04  # on the walls' side of its middle: it slides away from them
    assert np.isclose(push.yaw, np.arctan2(direction[1], direction[0]))
    alone = frame_of(scene_depth([block]))
    assert plan_push(alone, GraspPlanner("analytic").choose(alone, box_of(cam, *block)).surface) is None  # nothing blocks it

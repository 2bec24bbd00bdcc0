"""Suction grasps planned from depth, and the ambidextrous choice between the cup and the jaws."""

from __future__ import annotations

import numpy as np
import pytest

from binpick.core.errors import ConfigError
from binpick.grasping import GraspPlanner
from binpick.grasping.instance import instance_surface
from binpick.grasping.suction import analytic_probability, describe_suction, moment_ratio, suction_candidates
from binpick.grippers import SuctionCup
from binpick.picking import Picker
from test_grasping import HEIGHT, SIZE, box_of, camera, frame_of, scene_depth


def ball_depth(radius: float, centre=(0.0, 0.0)) -> np.ndarray:
    """A ball resting on the floor, seen from above."""
    pixels = camera().points(np.full((SIZE, SIZE), HEIGHT))
    r2 = (pixels[..., 0] - centre[0]) ** 2 + (pixels[..., 1] - centre[1]) ** 2
    heights = np.where(r2 < radius ** 2, radius + np.sqrt(np.clip(radius ** 2 - r2, 0, None)), 0.0)
    return (HEIGHT - heights).astype(np.float32)


def test_a_wide_box_face_gets_a_suction_grasp_near_its_middle():
    block = (-0.08, 0.08, -0.06, 0.06, 0.05)  # 16 x 12 cm: wider than the jaws open either way
    frame = frame_of(scene_depth([block]))
    surface = instance_surface(frame, box_of(camera(), *block))
    candidates = suction_candidates(frame, surface)
    best = max(candidates, key=lambda c: analytic_probability(c.seal))
    assert best.tool == "suction" and np.allclose(best.position[:2], 0.0, atol=0.012) and abs(best.position[2] - 0.05) < 0.003
    assert best.seal.coverage == 1.0 and best.seal.planarity < 0.001 and best.seal.tilt < 2.0
    assert analytic_probability(best.seal) > 0.9
    edge = describe_suction(frame, surface, np.array([[0.08, 0.0]]))[0]  # a cup over the face's edge leaks
    assert edge.seal.coverage < 0.8 and edge.rejected is not None and analytic_probability(edge.seal) < 0.01


def test_a_small_ball_gets_no_likely_suction_grasp():
    frame = frame_of(ball_depth(0.03))
    surface = instance_surface(frame, box_of(camera(), -0.03, 0.03, -0.03, 0.03, 0.06))
    candidates = suction_candidates(frame, surface)
    assert candidates and max(analytic_probability(c.seal) for c in candidates) < 0.2


def test_the_weights_moment_grows_with_the_lever():
    cup = SuctionCup()
    assert moment_ratio(0.4, 0.0, cup) == 0.0
    assert moment_ratio(0.5, 0.10, cup) > 1.0 > moment_ratio(0.5, 0.03, cup)  # 0.5 kg held 10 cm off its centre peels
    assert moment_ratio(4.0, 0.0, cup) == float("inf")  # heavier than the vacuum holds


@pytest.mark.parametrize("hand, tools", [("jaws", {"jaws"}), ("suction", {"suction"}), ("both", {"jaws", "suction"})])
def test_a_hand_only_gets_grasps_for_its_tools(hand, tools):
    blocks = [(-0.08, 0.08, -0.06, 0.06, 0.05), (0.10, 0.13, -0.02, 0.02, 0.04)]  # a wide box and a narrow one
    frame = frame_of(scene_depth(blocks))
    planner = GraspPlanner("analytic", hand=hand)
    chosen = set()
    for block in blocks:
        choice = planner.choose(frame, box_of(camera(), *block))
        assert {c.tool for c in choice.candidates} <= tools
        if choice.chosen is not None:
            chosen.add(choice.chosen.tool)
    assert chosen <= tools and chosen


def test_a_bin_of_boxes_wider_than_the_jaws_is_picked_by_suction_and_a_jaws_cell_gets_none():
    blocks = [(-0.16, -0.01, -0.06, 0.06, 0.05), (0.01, 0.16, -0.06, 0.06, 0.06)]  # two 15 x 12 cm boxes side by side
    depth = scene_depth(blocks)
    boxes = np.array([box_of(camera(), *b) for b in blocks])
    both = Picker(None, GraspPlanner("analytic", hand="both"), verifier=None).plan(
        np.zeros((SIZE, SIZE, 3), np.uint8), depth, camera(), boxes=(boxes, np.ones(2)))
    assert both.grasps and all(plan.tool == "suction" and plan.width is None and plan.opening is None for plan in both.grasps)
    assert all(plan.quality > 0.5 for plan in both.grasps)
    jaws = Picker(None, GraspPlanner("analytic", hand="jaws"), verifier=None).plan(
        np.zeros((SIZE, SIZE, 3), np.uint8), depth, camera(), boxes=(boxes, np.ones(2)))
    assert not jaws.grasps and all("too wide across the jaws" in plan.rejected for plan in jaws)
    assert all(p["tool"] is None for p in jaws.to_json()["plans"])


def test_a_bad_gripper_name_is_one_line():
    with pytest.raises(ConfigError, match="gripper"):
        GraspPlanner("analytic", hand="vacuum")
    with pytest.raises(ConfigError, match="fixed grasp policy"):
        GraspPlanner("fixed", hand="suction")


def test_a_thin_u_shaped_object_is_grasped_on_itself_not_on_the_background_inside_it():
    strips = [(-0.05, -0.035, -0.05, 0.05, 0.015), (0.035, 0.05, -0.05, 0.05, 0.015),  # two arms 1.5 cm wide
              (-0.05, 0.05, -0.065, -0.05, 0.015)]  # and the strip joining them: a U whose centre is floor
    frame = frame_of(scene_depth(strips))
    box = box_of(camera(), -0.05, 0.05, -0.065, 0.05, 0.015)
    surface = instance_surface(frame, box)
    assert surface is not None
    from binpick.grasping.instance import on_instance

    assert not on_instance(frame, surface, surface.centre[None])[0]  # its centre is background
    for hand in ("jaws", "both"):
        choice = GraspPlanner("analytic", hand=hand).choose(frame, box)
        assert choice.chosen is not None and on_instance(frame, surface, choice.chosen.position[None, :2])[0], hand
        assert choice.rejections().get("centre off the instance", 0) > 0 or hand == "both"


def test_suction_trials_are_recorded_and_a_calibrated_suction_model_trains_on_them(tmp_path):
    from binpick.grasping.suction_quality import SuctionQuality
    from binpick.grasping.training import QualityTrainConfig, QualityTrainer, load_trials
    from binpick.warehouse.dataset import DataGeneration
    from binpick.warehouse.generation import GenerateConfig

    data = tmp_path / "trials"
    DataGeneration.new(GenerateConfig(out=str(data), scenes=2, policies=[], grasp_trials=3, workers=1, image_size=128, gripper="suction",
                                      copies=(2, 3), distractors=(0, 1), targets=["procedural_box", "can"], scenes_per_world=1,
                                      val_fraction=0.5)).run()
    records = [__import__("json").loads(p.read_text()) for p in sorted((data / "scenes").glob("*.json"))]
    trials = [t for r in records for t in r["grasp_trials"]]
    assert trials and all(t["tool"] == "suction" and t["width"] == 0.0 for t in trials)
    assert all((t["why"] is None) == t["success"] or t["success"] is False for t in trials)  # a failure says why (or the load let go)
    train = load_trials(data, "train", tool="suction")
    assert len(train) and train.maps.shape[1:] == (24, 24) and train.features.shape[1] == 9 and np.isfinite(train.features).all()
    assert not len(load_trials(data, "train", tool="jaws"))  # a suction-only hand made no jaw trials
    run = QualityTrainer.new(QualityTrainConfig(data=str(data), tool="suction", balance=False, epochs=1, batch_size=2, width=4,
                                                threads=1), tmp_path / "runs")
    metrics = run.run()
    model = SuctionQuality.load(run.run_dir / "model.safetensors")
    assert set(metrics["calibration"]) >= {"temperature", "bias", "ece_before", "ece_after"} and model.calibration[0] > 0
    with pytest.raises(ConfigError, match="tool"):
        QualityTrainConfig(data=str(data), tool="magnet")


def test_platt_scaling_recovers_a_known_miscalibration():
    from binpick.core.metrics import calibration_error, fit_platt, reliability

    rng = np.random.default_rng(0)
    logits = rng.normal(0.0, 3.0, 4000)
    labels = (rng.random(4000) < 1 / (1 + np.exp(-(0.5 * logits - 1.0)))).astype(float)  # the truth: half the logit, minus 1
    temperature, bias = fit_platt(logits, labels)
    assert abs(temperature - 2.0) < 0.2 and abs(bias + 1.0) < 0.15
    raw, fixed = 1 / (1 + np.exp(-logits)), 1 / (1 + np.exp(-(logits / temperature + bias)))
    assert calibration_error(labels, fixed) < 0.03 < calibration_error(labels, raw)
    assert sum(row["count"] for row in reliability(labels, fixed)) == 4000


def test_a_grasp_that_failed_makes_its_tool_count_for_less_there():
    block = (-0.04, 0.04, -0.03, 0.03, 0.05)  # 8 x 6 cm: the jaws fit it and the cup seals on its top
    frame = frame_of(scene_depth([block]))
    box = box_of(camera(), *block)
    planner = GraspPlanner("analytic", hand="both")
    first = planner.choose(frame, box).chosen
    again = planner.choose(frame, box, failed=[(first.position, first.tool)]).chosen
    assert again is not None and (again.tool != first.tool or np.linalg.norm(again.position[:2] - first.position[:2]) >= 0.03)

"""Your cell in one file: read and checked once; the planner never emits a grasp wider than its jaws
open, the simulator builds the same hand, and a stroke no candidate fits is one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import cli_zygote

from binpick.cell import Cell, load_cell
from binpick.core.errors import InputFileError

ROOT = Path(__file__).resolve().parents[1]
FRANKA = ROOT / "configs" / "cells" / "franka_hand.yaml"


def test_the_shipped_cells_load_and_mistakes_are_one_line(tmp_path):
    franka = load_cell(FRANKA)
    assert franka.tools == "jaws" and franka.jaws.opening == 0.08 and franka.widest == pytest.approx(0.074)
    assert load_cell(ROOT / "configs" / "cells" / "robotiq_2f85.yaml").tools == "both"
    for text, words in (("gripper: {tools: claws}", "gripper.tools 'claws'"),
                        ("gripper: {jaws: {stroke: 80}}", "gripper.jaws.stroke must be a number from 0.01 to 0.3"),
                        ("gripper: {jaws: {strok: 0.08}}", "unknown field(s) strok"),
                        ("gripper: {tools: jaws}\narm: {model: kuka}", "arm.model 'kuka'")):
        bad = tmp_path / "cell.yaml"
        bad.write_text(text)
        with pytest.raises(InputFileError, match=words.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")) as raised:
            Cell.load(bad)
        assert "\n" not in str(raised.value)


def test_an_8_cm_cell_plans_nothing_wider_and_the_simulator_builds_its_hand():
    from binpick.grasping import DepthFrame, GraspPlanner, PinholeCamera
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.mjcf import CameraSpec
    from binpick.sim.products import Product

    franka = load_cell(FRANKA)
    planner = GraspPlanner("analytic", hand=franka.tools, gripper=franka.jaws)
    box = Product("test/box", "test", shape="box", size=(0.045, 0.035, 0.02), mass=0.2)  # 9 x 7 cm: fits 11 cm jaws only across
    world = BinWorld(box, [], max_copies=1, camera=CameraSpec(size=200), gripper=franka.tools, jaws=franka.jaws)
    try:
        fingers = [world.model.actuator(name).id for name in ("finger_a", "finger_b")]
        assert np.allclose(world.model.actuator_ctrlrange[fingers, 1], 0.04)  # each finger travels half the 8 cm stroke
        from binpick.grippers import TIPS_BELOW

        finger = world.model.geom("finger_a")
        assert np.isclose(finger.size[2] * 2, franka.jaws.finger_length)
        assert np.isclose(finger.pos[2] - finger.size[2], -TIPS_BELOW)  # its tips at the tool point the planner plans for
        scene = world.scene(1, 0, seed=2)
        frame = DepthFrame.from_depth(scene.depth, PinholeCamera.from_record(scene.camera))
        choice = planner.choose(frame, scene.instances[0].bbox)
        assert choice.chosen is not None and choice.chosen.width <= franka.widest
        assert all(c.rejected or c.width <= franka.widest for c in choice.candidates if c.tool == "jaws")
        wide = GraspPlanner("analytic", hand="jaws", gripper=load_cell(FRANKA).jaws.__class__(opening=0.03, margin=0.005))
        assert wide.choose(frame, scene.instances[0].bbox).chosen is None
    finally:
        world.close()


def test_a_stroke_below_every_candidate_is_one_line_not_a_plan(tmp_path):
    narrow = tmp_path / "narrow.yaml"
    narrow.write_text("gripper: {tools: jaws, jaws: {stroke: 0.012, margin: 0.002}}\narm: {model: none}\n")  # 12 mm, not 12 cm
    run = cli_zygote.run(["plan", "--sample", "--cell", str(narrow), "--grasp", "analytic", "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, timeout=240)
    assert run.returncode == 2, run.stdout[-1500:] + run.stderr[-1500:]
    errors = [line for line in run.stderr.strip().splitlines() if not line.startswith("warning:")]  # (the sample's depth is half size)
    assert len(errors) == 1 and "wider than the jaws take (1.0 cm" in errors[0]
    ok = cli_zygote.run(["plan", "--sample", "--cell", str(FRANKA), "--grasp", "analytic", "--out", str(tmp_path / "ok")],
                        capture_output=True, text=True, timeout=240)
    assert ok.returncode == 0, ok.stdout[-1500:] + ok.stderr[-1500:]
    plans = json.loads((tmp_path / "ok" / "plan.json").read_text())
    assert plans["gripper"] == "jaws"
    assert all(p["width"] is None or p["width"] <= 0.074 for p in plans["plans"] if p["position"] is not None)


@pytest.mark.parametrize("arm", ["panda", "ur5e"])
def test_the_arm_carries_the_cell_files_hand_at_its_tool_point(tmp_path, arm):
    import mujoco

    from binpick.arm import MotionPlanner
    from binpick.cell import MIN_ARM_TCP
    from binpick.core.errors import ConfigError
    from binpick.grippers import TIPS_BELOW
    from binpick.sim.robot_arm import PALM_TOP, RobotArm, arm_model

    assert MIN_ARM_TCP == pytest.approx(TIPS_BELOW + PALM_TOP)  # the cell file's check is the simulated hand's size
    path = tmp_path / "cell.yaml"
    path.write_text("gripper: {tools: both, jaws: {stroke: 0.085, finger_length: 0.04}, suction: {radius: 0.02}, tcp: 0.17}\n"
                    f"arm: {{model: {arm}}}\n")
    cell = load_cell(path)
    planner = MotionPlanner.for_cell(cell)  # the file's arm
    model, data = planner.kinematics.model, planner.kinematics.data
    assert planner.kinematics.arm.name == arm and planner.gripper == "both"
    fingers = [model.actuator(name).id for name in ("finger_a", "finger_b")]
    assert np.allclose(model.actuator_ctrlrange[fingers, 1], 0.0425)  # half the 8.5 cm stroke each
    assert model.geom("cup").size[0] == pytest.approx(0.02)
    data.qpos[planner.kinematics.arm.qpos] = planner.home
    mujoco.mj_kinematics(model, data)
    flange = model.body("right_hand").id
    axis = data.xmat[flange].reshape(3, 3)[:, 2]  # out of the flange
    for name in ("finger_a", "finger_b"):
        finger = model.geom(name).id
        tip = data.geom_xpos[finger] - data.geom_xmat[finger].reshape(3, 3)[:, 2] * model.geom_size[finger][2]  # its lowest face
        assert float((tip - data.xpos[flange]) @ axis) == pytest.approx(0.17, abs=1e-6)  # flange to fingertip: the file's tcp
    robot = RobotArm(arm_model(arm), gripper=cell.tools, jaws=cell.jaws, cup=cell.cup, tcp=cell.tcp)
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.mjcf import CameraSpec
    from binpick.sim.products import Product

    box = Product("test/box", "test", shape="box", size=(0.03, 0.03, 0.02), mass=0.1)
    world = BinWorld(box, [], max_copies=1, camera=CameraSpec(size=64), robot=robot)
    try:
        assert world.arm.hand.vacuum.cup.radius == pytest.approx(0.02)  # the simulated seal judged over the file's lip
    finally:
        world.close()
    with pytest.raises(ConfigError, match="gripper.tcp 0.05 m") as raised:
        MotionPlanner.for_cell(Cell(tools="jaws", tcp=0.05, arm=arm))
    assert "\n" not in str(raised.value)


def test_a_ur5e_cell_is_simulated_with_its_arm_and_another_arm_asked_for_is_one_line():
    from binpick.arm import MotionPlanner
    from binpick.core.errors import ConfigError

    cell = load_cell(ROOT / "configs" / "cells" / "ur5e_2f85.yaml")
    assert cell.arm == "ur5e" and cell.jaws.opening == 0.085
    planner = MotionPlanner.for_cell(cell, arm="ur5e")
    assert planner.kinematics.arm.name == "ur5e" and planner.kinematics.arm.tcp == 0.175
    assert len(planner.home) == 6
    with pytest.raises(ConfigError, match="has a ur5e arm; robot panda asks for another") as raised:
        MotionPlanner.for_cell(cell, arm="panda")
    assert "\n" not in str(raised.value)


def test_grasp_trials_are_made_and_judged_with_the_cell_files_hand(tmp_path):
    from binpick.core.errors import ConfigError
    from binpick.warehouse.dataset import DataGeneration, world_sim
    from binpick.warehouse.generation import GenerateConfig

    config = GenerateConfig(out=str(tmp_path / "trials"), scenes=1, policies=[], grasp_trials=3, workers=1, image_size=96,
                            copies=(2, 2), distractors=(0, 0), targets=["procedural_box"], scenes_per_world=1, val_fraction=0.0,
                            cell=str(FRANKA))
    assert config.gripper == "jaws" and config.hand[0].opening == 0.08
    sim, _, _ = world_sim(config, 0)
    try:
        fingers = [sim.model.actuator(name).id for name in ("finger_a", "finger_b")]
        assert np.allclose(sim.model.actuator_ctrlrange[fingers, 1], 0.04)  # the simulated hand opens the file's 8 cm
    finally:
        sim.close()
    DataGeneration.new(config).run()
    trials = [t for path in (tmp_path / "trials" / "scenes").glob("*.json") for t in json.loads(path.read_text())["grasp_trials"]]
    assert trials
    franka = load_cell(FRANKA)
    assert all(t["width"] is None or t["width"] <= franka.widest + 1e-9 for t in trials if t["rejected"] is None)
    assert all(not t["success"] for t in trials if t["rejected"] and t["rejected"].startswith("too wide"))
    with pytest.raises(ConfigError, match="gripper 'suction' and cell") as raised:
        GenerateConfig(out=str(tmp_path / "x"), gripper="suction", policies=[], cell=str(FRANKA))
    assert "\n" not in str(raised.value)


def test_the_arms_base_comes_from_the_cell_file_and_one_out_of_reach_is_one_line(tmp_path):
    import mujoco

    from binpick.arm import MotionPlanner
    from binpick.core.errors import ConfigError

    path = tmp_path / "cell.yaml"
    path.write_text("gripper: {tools: jaws}\narm: {model: ur5e, base: [-0.6, 0.05, 0.0]}\n")
    cell = load_cell(path)
    assert cell.base == (-0.6, 0.05, 0.0)
    planner = MotionPlanner.for_cell(cell)
    kinematics = planner.kinematics
    mujoco.mj_kinematics(kinematics.model, kinematics.data)
    assert np.allclose(kinematics.data.xpos[kinematics.model.body("base").id], [-0.6, 0.05, 0.0])
    far = tmp_path / "far.yaml"
    far.write_text("gripper: {tools: jaws}\narm: {model: panda, base: [2.5, 0.0, 0.0]}\n")
    with pytest.raises(ConfigError, match=r"base at \[2.5, 0.0, 0.0\] m does not reach") as raised:
        MotionPlanner.for_cell(load_cell(far))
    assert "\n" not in str(raised.value)
    for text in ("arm: {model: panda, base: [1, 2]}", "arm: {model: panda, base: [0, 0, 9]}", "arm: {model: panda, base: here}"):
        path.write_text(f"gripper: {{tools: jaws}}\n{text}\n")
        with pytest.raises(InputFileError, match="arm.base must be"):
            Cell.load(path)

"""The pick pipeline (thesis ch. 6): grasp points from depth, a pick carried into the order tote,
and an order run end to end with its pictures."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import cli_zygote
from conftest import binpick_here

from binpick.detection.model import DetectorNetwork, ModelSpec
from binpick.detection.weights_file import save_detector
from binpick.sim import default_library
from binpick.sim.bin_scene import BinWorld
from binpick.grasping import DepthFrame, GraspPlanner, PinholeCamera
from binpick.sim.mjcf import FLOOR_TOP, CameraSpec
from binpick.sim.order_tote import (ORDER_FLOOR_TOP, ORDER_HALF, ORDER_TOTE, RELEASE_HEIGHT, in_order_tote, order_tote_xml,
                                     release_height)
from binpick.warehouse.grasping import Reason, execute_pick, grasp_point, pixel_to_world
from binpick.warehouse.orders import summarise
from binpick.warehouse.pipeline import PickPipeline



def test_pixel_to_world_inverts_the_overhead_camera():
    camera = CameraSpec(size=416)
    fx, _, cx, cy = camera.intrinsics()
    assert np.allclose(pixel_to_world(cx, cy, 0.8, camera), [0, 0, camera.height - 0.8])
    right_up = pixel_to_world(cx + fx * 0.1, cy - fx * 0.1, 0.5, camera)  # image right = +x, image up = +y
    assert np.allclose(right_up, [0.05, 0.05, camera.height - 0.5])


def test_a_detected_can_is_grasped_at_its_top_and_placed_in_the_order_tote():
    library = default_library(procedural=0, shapes=0)
    camera = CameraSpec(size=160)
    world = BinWorld(library["robosuite/can"], [], max_copies=2, camera=camera, extra_worldbody=order_tote_xml(), gripper=True)
    try:
        scene = world.scene(2, 0, seed=1)
        world.set_guards(False)
        results = []
        frame = DepthFrame.from_depth(scene.depth, PinholeCamera.from_record(scene.camera))
        for instance in scene.instances:
            world.restore(scene.state)
            point = grasp_point(instance.bbox, scene.depth, camera)  # the fixed policy's point: the can's top
            centre, top = world.instance_centre_and_top(instance.slot)
            assert np.allclose(point[:2], centre[:2], atol=0.012) and abs(point[2] - top) < 0.012
            chosen = GraspPlanner("analytic").choose(frame, instance.bbox).chosen  # from depth alone
            assert chosen is not None and np.allclose(chosen.position[:2], centre[:2], atol=0.015)
            assert FLOOR_TOP < chosen.position[2] < top - 0.015 and chosen.width < 0.09
            results.append((instance.slot, execute_pick(world, chosen.position, chosen.yaw)))
    finally:
        world.close()
    placed = [(slot, outcome) for slot, outcome in results if outcome.placed]
    assert placed and all(outcome.lifted_slot == slot and outcome.reason is Reason.PLACED for slot, outcome in placed)


def test_an_order_runs_end_to_end_and_the_cli_reports_it(tmp_path):
    detector = DetectorNetwork(ModelSpec(query="photo"), 128).eval()  # untrained: whatever it finds is tried
    pipeline = PickPipeline(detector, default_library(procedural=3, shapes=0), score_threshold=0.0, max_attempts=1,
                            camera=CameraSpec(size=128), verifier=None)  # no product check: an untrained net's boxes are tried
    result = pipeline.run_order("robosuite/can", 0, seed=0, out=tmp_path)
    assert isinstance(result.reason, Reason) and result.reason is not Reason.NOT_THE_PRODUCT  # detections were tried
    grasps = [a for a in result.attempts if a.outcome is not Reason.NO_GRASP]  # infeasible ones cost no attempt
    assert result.attempts and len(grasps) <= 1 and (tmp_path / result.gif).is_file() and (tmp_path / result.overlay).is_file()
    assert all(a.rejected or a.outcome is not Reason.NO_GRASP for a in result.attempts)  # a skipped detection says why
    summary = summarise([result], 10.0)
    assert summary["orders"] == 1 and 0.0 <= summary["pick_success"] <= 1.0
    save_detector(detector, tmp_path / "photo.safetensors")
    ran = binpick_here(["pick", "--product", "can", "--orders", "1", "--weights", str(tmp_path / "photo.safetensors"),
                                "--out", str(tmp_path / "cli")])
    assert ran.returncode == 0, ran.stderr
    written = json.loads((tmp_path / "cli" / "results.json").read_text())  # --out is the folder itself
    assert (tmp_path / "cli" / "report.html").read_text().count("<tr>") == 2  # header + the order
    assert written["summary"]["orders"] == 1 and written["orders"][0]["product"] == "robosuite/can"
    bad = binpick_here(["pick", "--product", "sofa", "--weights", str(tmp_path / "photo.safetensors")])
    assert bad.returncode == 2 and "unknown product or category 'sofa'" in bad.stderr


def test_the_oracle_locates_the_ordered_product_from_the_simulator(tmp_path):
    detector = DetectorNetwork(ModelSpec(query="photo"), 128).eval()
    pipeline = PickPipeline(detector, default_library(procedural=3, shapes=0), max_attempts=1, camera=CameraSpec(size=128),
                            oracle=True)
    result = pipeline.run_order("robosuite/can", 0, seed=3)
    assert result.detections >= 1 and result.attempts[0].outcome in {Reason.PLACED, Reason.MISSED, Reason.SLIPPED, Reason.DROPPED}
    assert result.attempts[0].lifted_product in (None, "robosuite/can")  # it aimed at a can, not at whatever the net said


def test_the_demo_fulfils_an_order_with_the_shipped_detector(tmp_path):
    run_dir = tmp_path / "demo"
    ran = cli_zygote.run(["demo", "--orders", "1", "--out", str(run_dir)], capture_output=True, text=True)  # the user's process
    assert ran.returncode == 0, ran.stderr
    written = json.loads((run_dir / "results.json").read_text())
    (order,) = written["orders"]
    assert order["product"] == "robosuite/milk" and order["seen"] is True  # the shipped weights know what they were trained on
    assert (run_dir / order["gif"]).is_file() and "report.html" in ran.stdout + ran.stderr
    from PIL import Image

    from binpick.warehouse.report import COLUMNS

    report = (run_dir / "report.html").read_text()
    assert all(f"<th>{column}</th>" in report for column in COLUMNS)  # the terminal table's columns
    for key in ("overlay", "depth", "gif"):  # full size a click away, scaled to the page's width
        assert f'<a href="{order[key]}"><img src="{order[key]}"' in report and (run_dir / order[key]).is_file()
    assert "max-width" not in report.split("<body>")[1] and "width:100%" in report
    assert {"depth", "detect", "grasp", "simulated picks"} <= set(order["timing_ms"]) and "time per stage: depth" in report
    assert "detector score" in report and ("predicted success" in report or not order["attempts"])
    gif = Image.open(run_dir / order["gif"])
    assert gif.size[1] > gif.size[0]  # the caption band under each frame


def test_the_colour_check_tells_the_ordered_product_from_another_colour():
    from binpick.sim.photos import shop_photo
    from binpick.grasping import PinholeCamera
    from binpick.detection.photos import photo_mask
    from binpick.picking.colour import colour_histogram, colour_similarity

    library = default_library(procedural=0, shapes=0)
    camera = CameraSpec(size=160)
    world = BinWorld(library["robosuite/can"], [library["robosuite/lemon"]], max_copies=2, camera=camera)
    try:
        scene = world.scene(2, 1, seed=2)
    finally:
        world.close()
    can_photo, can_mask = shop_photo(library["robosuite/can"], size=128, with_mask=True)
    assert 0.01 < can_mask.mean() < 0.5
    histogram = colour_histogram(can_photo, can_mask)
    by_product: dict[str, list[float]] = {}
    points = DepthFrame.from_depth(scene.depth, PinholeCamera.from_record(scene.camera)).heights  # above the support plane
    for instance in scene.instances:
        by_product.setdefault(instance.product_id, []).append(colour_similarity(histogram, scene.rgb, points, instance.bbox))
    assert min(by_product["robosuite/can"]) > 0.3 > max(by_product["robosuite/lemon"])
    user_photo = np.full((40, 40, 3), 235, np.uint8)
    user_photo[10:20, 5:30] = (200, 30, 30)  # a red product on a light grey background
    assert photo_mask(user_photo).sum() == 250 and photo_mask(user_photo)[15, 10]
    assert photo_mask(np.full((40, 40, 3), (200, 30, 30), np.uint8)).all()  # a crop of the product itself: all of it
    assert photo_mask(np.full((40, 40, 3), 250, np.uint8)).all()  # white on white: all of it, never an empty mask


def test_an_order_that_lifts_another_product_says_so_in_results_the_table_and_the_report():
    from binpick.core.depth import as_camera_depth
    from binpick.warehouse.orders import OrderResult, results_json
    from binpick.warehouse.report import order_outcome, order_section

    detector = DetectorNetwork(ModelSpec(query="photo"), 128).eval()
    pipeline = PickPipeline(detector, default_library(procedural=0, shapes=0), max_attempts=3, camera=CameraSpec(size=160),
                            verifier=None, copies=(1, 1), distractors=(2, 2), look_again=False)
    result, lifted = None, None
    for seed in range(8):  # a grasp aimed at another product's instance (as a confused detector would aim it), then the can
        world, rng = pipeline.build_world("robosuite/can", seed)
        try:
            scene = pipeline.settle(world, rng, seed)
            frame = pipeline.picker.grasp.frame(as_camera_depth(scene.depth), PinholeCamera.from_record(scene.camera))
            (can,) = [i for i in scene.instances if i.product_id == "robosuite/can"]
            right = pipeline.picker.plan_detection(frame, can.bbox, 0.5, None)
            for other in (i for i in scene.instances if i.product_id != "robosuite/can" and i.visible_fraction > 0.8):
                wrong = pipeline.picker.plan_detection(frame, other.bbox, 0.9, None)
                if not wrong.feasible:
                    continue
                world.restore(scene.state)
                result = OrderResult(0, "robosuite/can", seed, False, Reason.NO_DETECTION)
                pipeline.execute(world, scene, [wrong, right], result)
                lifted = result.attempts[0].lifted_product
                if result.attempts[0].outcome is Reason.WRONG_PRODUCT:  # it went into the customer's tote
                    break
        finally:
            world.close()
        if result is not None and result.attempts[0].outcome is Reason.WRONG_PRODUCT:
            break
    assert result is not None and result.attempts[0].outcome is Reason.WRONG_PRODUCT and lifted != "robosuite/can"
    assert len(result.attempts) == 1  # the order stops there: the can is not grasped after it, never counted as placed
    (order,) = results_json([result])
    assert not order["success"] and order["reason"] == "wrong product"
    assert order["attempts"][0]["outcome"] == "wrong product" and order["attempts"][0]["lifted_product"] == lifted
    short = lifted.split("/")[-1]
    assert order_outcome(order) == f"wrong product: {short} lifted"  # the terminal table's cell, and the report's
    page = order_section({**order, "seconds": 1.0, "detections": 1})
    assert f"color:#cf222e'>wrong product: {short} lifted</b>" in page and f"{lifted} lifted, not the ordered product" in page


def test_a_product_is_judged_in_the_order_tote_by_its_centre_of_mass_not_its_body_origin():
    library = default_library(procedural=0, shapes=0)
    world = BinWorld(library["pybullet/teddy"], [], max_copies=1, camera=CameraSpec(size=64), extra_worldbody=order_tote_xml())
    try:
        body, data = world.body_ids[0], world.data
        mujoco.mj_forward(world.model, data)
        offset = data.xipos[body] - data.xpos[body]  # the teddy's mesh sits a hand's width off its origin
        assert np.hypot(*offset[:2]) > ORDER_HALF / 3
        adr = world.model.jnt_qposadr[world.model.body_jntadr[body]]
        for centre, inside in (((ORDER_TOTE[0], ORDER_TOTE[1]), True), ((ORDER_TOTE[0] + 0.25, ORDER_TOTE[1]), False)):
            data.qpos[adr:adr + 3] = [centre[0] - offset[0], centre[1] - offset[1], 0.05]  # its centre of mass over `centre`
            mujoco.mj_forward(world.model, data)
            assert in_order_tote(data, body) is inside
        axis = int(np.argmax(np.abs(offset[:2])))  # its mass just beyond the wall its mesh leans towards, ...
        centre = np.array([*ORDER_TOTE, 0.05 + offset[2]])
        centre[axis] += np.sign(offset[axis]) * (ORDER_HALF + 0.01)
        data.qpos[adr:adr + 3] = centre - offset  # ... its origin inside the tote
        mujoco.mj_forward(world.model, data)
        assert abs(data.xpos[body][0] - ORDER_TOTE[0]) < ORDER_HALF and abs(data.xpos[body][1] - ORDER_TOTE[1]) < ORDER_HALF
        assert not in_order_tote(data, body)
    finally:
        world.close()


def test_products_are_let_go_low_over_the_order_tote_however_deep_they_were_grasped():
    releases = [release_height(grasp_z, FLOOR_TOP) for grasp_z in (0.05, 0.08, 0.12, 0.30)]
    assert releases == sorted(releases) and max(releases) == RELEASE_HEIGHT  # never higher than it was before
    for grasp_z, release in zip((0.05, 0.08, 0.12), releases):
        hanging = grasp_z - FLOOR_TOP  # the most a product grasped off the bin floor hangs below the tool
        assert ORDER_FLOOR_TOP < release - hanging <= ORDER_FLOOR_TOP + 0.05  # clear of the tote's floor, a short fall


def test_a_lying_can_in_a_corner_that_no_grasp_fits_is_pushed_out_and_then_a_grasp_fits():
    from binpick.grasping.push import plan_push
    from binpick.sim.mjcf import BIN_HALF
    from binpick.sim.products import Product
    from binpick.warehouse.grasping import execute_push

    can = Product("test/can", "test", shape="cylinder", size=(0.022, 0.03), mass=0.15)  # radius, half-length
    world = BinWorld(can, [], max_copies=1, camera=CameraSpec(size=200), extra_worldbody=order_tote_xml(), gripper=True)
    try:
        scene = world.scene(1, 0, seed=0)
        world.set_guards(False)
        corner = np.array([BIN_HALF[0] - 0.031, BIN_HALF[1] - 0.023])  # lying along x, touching both walls
        world._place(0, [*corner, FLOOR_TOP + 0.023], [np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0])
        for _ in range(300):
            mujoco.mj_step(world.model, world.data)
        planner = GraspPlanner("analytic")

        def look(seed: int):
            seen = world.look_again(scene, seed)
            frame = DepthFrame.from_depth(seen.depth, PinholeCamera.from_record(seen.camera))
            return frame, planner.choose(frame, seen.instances[0].bbox)

        frame, choice = look(1)
        assert choice.chosen is None and "finger blocked" in choice.reason
        push = plan_push(frame, choice.surface)
        assert push is not None and push.end[0] < push.start[0] and push.end[1] < push.start[1]  # out of the corner
        moved = execute_push(world, push.start, push.end, push.yaw)
        centre = world.data.xipos[world.body_ids[0]]
        assert moved > 0.02 and np.all(corner - centre[:2] > 0.005) and np.linalg.norm(corner - centre[:2]) > 0.02 and centre[2] > FLOOR_TOP
        _, choice = look(2)
        assert choice.chosen is not None and choice.chosen.tool == "jaws"
    finally:
        world.close()


def test_a_picking_look_waits_for_a_rolling_ball_to_come_to_rest():
    from binpick.sim.bin_scene import STILL_SPEED
    from binpick.sim.products import Product

    ball = Product("test/ball", "test", shape="sphere", size=(0.025,), mass=0.1)
    world = BinWorld(ball, [], max_copies=1, camera=CameraSpec(size=64))
    try:
        scene = world.scene(1, 0, seed=0, still=True)
        dof = world.dof_adr[0]
        assert np.abs(world.data.qvel[dof:dof + 3]).max() < STILL_SPEED  # the first look: at rest
        world.data.qvel[dof:dof + 6] = [0.05, 0.0, 0.0, 0.0, 2.0, 0.0]  # knocked by a failed grasp: rolling along x
        before = world.data.xipos[world.body_ids[0]].copy()
        world.look_again(scene, 1)
        assert np.abs(world.data.qvel[dof:dof + 3]).max() < STILL_SPEED
        assert np.linalg.norm(world.data.xipos[world.body_ids[0]] - before) > 0.01  # it rolled on before the frame was taken
    finally:
        world.close()


def test_grasps_worth_trying_go_before_hopeless_ones_and_a_push_only_when_none_is_left():
    from types import SimpleNamespace

    from binpick.picking.plans import GraspPlan
    from binpick.picking.picker import Picker
    from binpick.warehouse.orders import OrderResult

    picker = SimpleNamespace(grasp=SimpleNamespace(policy=GraspPlanner("analytic").policy))
    picker.hopeless = lambda plan: Picker.hopeless(picker, plan)
    pipeline = SimpleNamespace(picker=picker, motion=None, grasp=SimpleNamespace(tools=("jaws", "suction")))
    push = {"start": [0.1, 0.1, 0.05], "end": [0.06, 0.06, 0.05], "yaw": 0.0}
    cup_on_a_ball = GraspPlan([0, 0, 9, 9], 0.9, 0.95, position=[0.1, 0.1, 0.05], quality=0.01, tool="suction", push=push)
    blocked = GraspPlan([0, 0, 9, 9], 0.8, 0.95, push=push)
    copy = GraspPlan([20, 0, 9, 9], 0.7, 0.9, position=[0.0, 0.0, 0.04], quality=0.97, tool="suction")
    ordered = PickPipeline.good_first(pipeline, [cup_on_a_ball, blocked, copy])
    assert ordered == [blocked, copy, cup_on_a_ball]  # the hopeless grasp last; one without a grasp costs nothing
    result = OrderResult(0, "p", 0, False, Reason.NO_DETECTION)
    assert not PickPipeline.pushes_first(pipeline, cup_on_a_ball, [copy], result)  # a good grasp is left: no push
    assert PickPipeline.pushes_first(pipeline, cup_on_a_ball, [blocked], result)
    cup_only = SimpleNamespace(picker=picker, motion=None, grasp=SimpleNamespace(tools=("suction",)))
    assert not PickPipeline.pushes_first(cup_only, cup_on_a_ball, [blocked], result)  # the push is the jaws': a cup-only hand has none
    result.pushes.append({**push, "moved": 0.03})
    assert not PickPipeline.pushes_first(pipeline, cup_on_a_ball, [], result)  # one push per order

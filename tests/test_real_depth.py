"""Depth as real sensors give it: the sensor model (shadows, noise, tilt), and a planner that expects
it (holes unknown, not obstacles; heights above a fitted support plane; the pointed instance planned)."""

from __future__ import annotations

import numpy as np
import pytest

from binpick.core.errors import ConfigError, InputFileError
from binpick.grasping import DepthFrame, GraspPlanner, PinholeCamera
from binpick.grasping.candidates import JawGripper, finger_heights
from binpick.sim.sensor import SensorConfig, axial_sigma, load_sensor, projector_shadow, sense

SIZE, HEIGHT, F = 240, 0.8, 400.0
K = np.array([[F, 0.0, (SIZE - 1) / 2], [0.0, F, (SIZE - 1) / 2], [0.0, 0.0, 1.0]])
DOWN = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, HEIGHT], [0, 0, 0, 1.0]])  # OpenCV axes, looking down


def blocks_depth(blocks) -> np.ndarray:
    """A camera straight down over a floor at z = 0 with axis-aligned blocks (x0, x1, y0, y1, height)."""
    pixels = PinholeCamera(K, SIZE, SIZE, DOWN).points(np.full((SIZE, SIZE), HEIGHT))
    heights = np.zeros((SIZE, SIZE))
    for x0, x1, y0, y1, h in blocks:
        inside = (pixels[..., 0] >= x0) & (pixels[..., 0] <= x1) & (pixels[..., 1] >= y0) & (pixels[..., 1] <= y1)
        heights = np.where(inside, np.maximum(heights, h), heights)
    return (HEIGHT - heights).astype(np.float32)


def box_of(camera: PinholeCamera, x0, x1, y0, y1, h) -> tuple[float, float, float, float]:
    corners = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (0.0, h)])
    uv, _ = camera.project(corners)
    return float(uv[:, 0].min()), float(uv[:, 1].min()), float(np.ptp(uv[:, 0])), float(np.ptp(uv[:, 1]))


def test_the_projector_shadows_the_far_side_of_a_tall_edge_noise_grows_with_distance_and_borders_and_registration_are_a_sensors():
    depth = blocks_depth([(-0.02, 0.02, -0.2, 0.2, 0.15)])  # a 15 cm wall along y through the middle
    right = projector_shadow(depth, F, 0.075, side=1)
    left = projector_shadow(depth, F, 0.075, side=-1)
    columns = lambda mask: np.flatnonzero(mask[SIZE // 2])  # noqa: E731
    wall = np.flatnonzero(depth[SIZE // 2] < HEIGHT - 0.1)
    assert columns(right).max() < wall.min() and columns(left).min() > wall.max()  # on the side away from the projector
    expected = F * 0.075 * (1 / (HEIGHT - 0.15) - 1 / HEIGHT)  # the disparity step across the edge, in pixels
    assert abs(len(columns(right)) - expected) <= 2 and not right[:, :wall.min() - 30].any()
    assert axial_sigma(np.array(0.4))[()] == pytest.approx(0.0012) and axial_sigma(np.array(1.4))[()] == pytest.approx(0.0031)
    rng = np.random.default_rng(0)
    quiet = dict(realistic=True, lateral_noise=(0, 0), flying_pixels=(0, 0), dropout=(0, 0), border=(0, 0), misregistration=(0, 0),
                 noise_scale=(1, 1), subpixel=(64, 64), hard_instances=(0, 0))
    spreads = []
    for distance in (0.6, 1.4):  # the sensor's noise grows with distance as Nguyen et al. measured it
        noisy, drawn = sense(np.full((SIZE, SIZE, 3), 128, np.uint8), np.full((SIZE, SIZE), distance, np.float32), K,
                             SensorConfig(**quiet), rng)
        spreads.append(float(noisy[noisy > 0].std()))
        assert abs(spreads[-1] - float(axial_sigma(np.array(distance)))) < 0.0004 and drawn["missing"] < 0.01
    assert spreads[1] > 1.5 * spreads[0]
    # the edge the projector cannot reach loses twice the band of the others; depth moves against colour
    flat = np.full((SIZE, SIZE), 0.8, np.float32)
    edged, _ = sense(np.full((SIZE, SIZE, 3), 128, np.uint8), flat, K, SensorConfig(**quiet | {"border": (5, 5), "projector_side": "right"}), rng)
    lost = (edged[SIZE // 2] == 0)
    assert lost[:10].all() and not lost[10] and lost[-5:].all() and not lost[-6]
    shifted, drawn = sense(np.full((SIZE, SIZE, 3), 128, np.uint8), flat + np.linspace(0, 0.1, SIZE, dtype=np.float32)[None, :], K,
                           SensorConfig(**quiet | {"misregistration": (2, 2), "noise_scale": (0, 0)}), rng)
    dx, dy = drawn["misregistration"]
    assert abs(dx) == 2 and abs(dy) == 2 and shifted[SIZE // 2, SIZE // 2] == pytest.approx(
        0.8 + 0.1 * (SIZE // 2 - dx) / (SIZE - 1), abs=0.003)
    same, _ = sense(np.zeros((4, 4, 3), np.uint8), np.ones((4, 4), np.float32), K, load_sensor("perfect"), rng)
    assert np.array_equal(same, np.ones((4, 4)))  # perfect depth stays as rendered
    with pytest.raises(ConfigError, match="sensor 'lidar' is neither"):
        load_sensor("lidar")
    with pytest.raises(ConfigError, match="baseline"):
        SensorConfig(baseline=(0.1, 0.05))


def test_with_30_percent_of_depth_missing_in_shadows_the_fingers_avoid_the_taller_neighbour():
    camera = PinholeCamera(K, SIZE, SIZE, DOWN)
    block = (-0.02, 0.02, -0.03, 0.03, 0.04)  # the instance: 4 x 6 cm, 4 cm tall
    neighbour = (0.045, 0.09, -0.12, 0.12, 0.16)  # 2.5 cm to its +x side, 16 cm tall
    others = [(x, x + 0.03, -0.25, 0.25, 0.2) for x in (0.13, 0.19, -0.2, -0.14, -0.08)]  # tall clutter casting shadows
    truth = blocks_depth([block, neighbour, *others])
    shadow = projector_shadow(truth, F, 0.15, side=1)
    assert shadow.mean() >= 0.3  # 30% of the frame unread, all of it beside tall edges
    depth = np.where(shadow, 0.0, truth).astype(np.float32)
    frame = DepthFrame.from_depth(depth, camera)
    assert frame.missing >= 0.3 and np.isfinite(frame.points).all()  # every hole filled
    choice = GraspPlanner("analytic").choose(frame, box_of(camera, *block))
    chosen = choice.chosen
    assert chosen is not None, choice.reason
    assert np.allclose(chosen.position[:2], 0.0, atol=0.012) and 0.0 < chosen.position[2] < 0.04 - 0.01
    # judged on the true scene: neither finger lands on the neighbour (nor on anything above the tips' tolerance)
    true_frame = DepthFrame.from_depth(truth, camera)
    under, seen = finger_heights(true_frame, chosen.position[None, :2], np.array([chosen.yaw]), JawGripper(), chosen.top)
    assert seen.all() and under.max() < chosen.position[2] + 0.03 and under.max() < 0.1
    # the old reading of a hole, an obstacle or the view's end, would have left nothing to grasp: not so here
    assert "finger outside the camera's view" not in choice.rejections()


def test_a_tilted_camera_over_a_tilted_tote_plans_grasps_at_the_surface_height():
    from binpick.sim import default_library
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.mjcf import CameraSpec

    library = default_library(procedural=0, shapes=0)
    sensor = SensorConfig(name="tilted", realistic=True, camera_tilt=(15.0, 15.0), tote_tilt=(3.0, 3.0))
    world = BinWorld(library["robosuite/can"], [library["robosuite/lemon"]], max_copies=2, camera=CameraSpec(size=200),
                     seed=3, sensor=sensor)
    try:
        scene = world.scene(2, 1, seed=3)
        _, perfect, segmentation = world.render()  # the same scene as the renderer sees it, every pixel exact
    finally:
        world.close()
    truth = PinholeCamera.from_record(scene.camera).points(perfect)
    truths = {i.slot: (truth[segmentation == i.slot][:, :2].mean(axis=0), float(truth[segmentation == i.slot][:, 2].max()))
              for i in scene.instances}
    pose = np.array(scene.camera["camera_to_world"])
    assert np.degrees(np.arccos(-pose[2, 2])) == pytest.approx(15.0, abs=0.5)  # the calibration records the tilt
    assert 0.05 < scene.sensor["missing"] < 0.5 and np.hypot(*scene.sensor["tote_tilt_degrees"]) == pytest.approx(3.0, abs=0.01)
    frame = DepthFrame.from_depth(scene.depth, PinholeCamera.from_record(scene.camera))
    a, b, _ = frame.plane
    assert np.degrees(np.arctan(np.hypot(a, b))) == pytest.approx(3.0, abs=0.7)  # the tote floor, found off level
    planner = GraspPlanner("analytic")
    planned = 0
    for instance in scene.instances:
        if instance.visible_fraction < 0.6:
            continue
        centre, top = truths[instance.slot]
        choice = planner.choose(frame, instance.bbox)
        assert choice.surface is not None and abs(choice.surface.top - top) < 0.008  # the top read from tilted depth
        if choice.chosen is not None:
            planned += 1
            floor = float(frame.support_z(choice.chosen.position[:2]))
            assert floor < choice.chosen.position[2] < top - 0.01  # under its top, above the tote floor there
            assert np.linalg.norm(choice.chosen.position[:2] - centre[:2]) < 0.03
    assert planned >= 1


def test_a_query_box_on_the_one_copy_plans_on_it_and_on_the_empty_floor_is_one_line():
    from binpick.picking import Picker
    from binpick.sim import default_library
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.mjcf import CameraSpec

    library = default_library(procedural=0, shapes=0)
    world = BinWorld(library["robosuite/can"], [library["robosuite/lemon"], library["robosuite/milk"]], max_copies=3,
                     camera=CameraSpec(size=256), seed=4, sensor=load_sensor("realistic"))
    try:
        scene = world.scene(3, 2, seed=4)
        can = max((i for i in scene.instances if i.product_id == "robosuite/can"), key=lambda i: i.visible_fraction)
        centre, top = world.instance_centre_and_top(can.slot)
    finally:
        world.close()
    camera = PinholeCamera.from_record(scene.camera)
    picker = Picker.load(grasp="analytic")
    plans = picker.plan(scene.rgb, scene.depth, camera, query_box=can.bbox, max_grasps=3)
    first = plans[0]
    assert first.box == [round(float(v), 2) for v in can.bbox] and first.feasible  # the pointed instance, first
    assert np.linalg.norm(np.array(first.position[:2]) - centre[:2]) < 0.03 and first.position[2] < top
    others = picker.plan(scene.rgb, scene.depth, camera, query_box=can.bbox, copies_only=True, max_grasps=3)
    assert len(plans) > 1 and [p.box for p in plans[1:]] == [p.box for p in others][:len(plans) - 1]  # then its copies, as before
    x0, y0, w0, h0 = can.bbox
    for plan in others:  # the thesis's evaluation: the other copies only, never the pointed one
        x, y, w, h = plan.box
        overlap = max(0.0, min(x + w, x0 + w0) - max(x, x0)) * max(0.0, min(y + h, y0 + h0) - max(y, y0))
        assert overlap / (w * h + w0 * h0 - overlap) < 0.5
    heights = DepthFrame.from_depth(scene.depth, camera).heights
    flat = [(x, y) for y in range(24, 210, 6) for x in range(24, 210, 6)  # a patch of floor with nothing on it
            if np.ptp(heights[y - 12:y + 36, x - 12:x + 36]) < 0.012 and (scene.segmentation[y - 12:y + 36, x - 12:x + 36] < 0).all()]
    assert flat, "no patch of empty floor in this bin"
    x, y = flat[0]
    with pytest.raises(InputFileError, match=rf"^the query box {x},{y},24,24 lies on no object: depth shows only the surface"):
        picker.plan(scene.rgb, scene.depth, camera, query_box=(x, y, 24, 24))
    with pytest.raises(InputFileError, match="no valid reading"):
        picker.plan(scene.rgb, np.zeros_like(scene.depth), camera, query_box=can.bbox)
    with pytest.raises(ConfigError, match="lies outside the 256x256 image"):
        picker.plan(scene.rgb, scene.depth, camera, query_box=(250, 10, 20, 20))
    with pytest.raises(ConfigError, match="4 finite numbers"):
        picker.plan(scene.rgb, scene.depth, camera, query_box=(1, 2, 3))


def test_depth_at_a_lower_resolution_of_the_same_aspect_is_resampled_and_the_sample_frame_plans():
    from binpick.picking import Picker
    from binpick.picking.frames import read_frame, read_photo
    from binpick.samples import SAMPLE_FRAME

    from binpick.picking.inputs import register_depth

    coarse = np.arange(12, dtype=np.float32).reshape(3, 4)  # each reading covers its 2x2 block at the colour's size
    assert np.array_equal(register_depth(coarse, (6, 8)), np.repeat(np.repeat(coarse, 2, axis=0), 2, axis=1))
    rgb, depth, info = read_frame(SAMPLE_FRAME / "rgb.png", SAMPLE_FRAME / "depth.png", SAMPLE_FRAME / "camera.yaml")
    assert rgb.shape[:2] == (480, 640) and depth.shape == (240, 320) and (depth == 0).mean() > 0.05  # as a sensor gives it
    assert abs(info.camera.camera_to_world[2, 2]) < 0.999  # a tilted camera
    plans = Picker.load().plan(rgb, depth, info, photo=read_photo(SAMPLE_FRAME / "photo.png"))
    assert plans.detections >= 1 and plans.grasps and np.isfinite(plans.grasps[0].position).all()
    with pytest.raises(InputFileError, match="depth is 320x200 but colour is 640x480"):
        Picker.load(grasp="analytic").plan(rgb, np.ones((200, 320), np.float32), info, query_box=(1, 1, 5, 5))


def test_data_generate_with_the_realistic_sensor_records_it_and_resumes_only_with_it(tmp_path):
    import json

    from binpick.core.depth import read_depth
    from binpick.warehouse.dataset import DataGeneration
    from binpick.warehouse.generation import GenerateConfig

    settings = dict(out=str(tmp_path / "bins"), scenes=2, policies=[], workers=1, image_size=96, copies=(2, 2), distractors=(1, 1),
                    targets=["can"], scenes_per_world=1, val_fraction=0.5)
    DataGeneration.new(GenerateConfig(**settings, sensor="realistic")).run()
    record = json.loads((tmp_path / "bins" / "scenes" / "000000.json").read_text())
    assert record["sensor"]["name"] == "realistic" and 0.02 < record["sensor"]["missing"] < 0.6
    depth = read_depth(tmp_path / "bins" / record["depth_file"])
    assert 0.02 < float((depth == 0).mean()) < 0.6  # the holes travel in the file as 0 (no reading)
    manifest = json.loads((tmp_path / "bins" / "dataset.json").read_text())
    assert manifest["config"]["sensor"] == "realistic" and manifest["config"]["sensor_values"]["baseline"] == [0.05, 0.08]
    with pytest.raises(ConfigError, match="made with other settings"):
        DataGeneration.new(GenerateConfig(**settings | {"scenes": 3}))  # perfect depth would be another data set
    perfect = GenerateConfig(**settings | {"out": str(tmp_path / "perfect")})
    assert "sensor" not in perfect.comparable()  # data sets made before sensors existed resume as they were


def test_the_pipeline_picks_the_pointed_instance_and_nothing_else():
    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.sim import default_library
    from binpick.sim.mjcf import CameraSpec
    from binpick.warehouse.grasping import Reason
    from binpick.warehouse.orders import OrderResult
    from binpick.warehouse.pipeline import PickPipeline

    library = default_library(procedural=0, shapes=0)
    pipeline = PickPipeline(Detector.load(PICKING).network, library, copies=(1, 1), distractors=(2, 2),
                            camera=CameraSpec(size=256), sensor=load_sensor("realistic"))
    world, rng = pipeline.build_world("robosuite/can", 7)
    try:
        scene = pipeline.settle(world, rng, 7)
        (can,) = [i for i in scene.instances if i.product_id == "robosuite/can"]
        again = world.look_again(scene, 1)  # a new frame of the same bin: same camera, the sensor's faults drawn anew
        assert again.camera == scene.camera and not np.array_equal(again.depth, scene.depth)
        result = OrderResult(0, "robosuite/can", 7, False, Reason.NO_DETECTION)
        pipeline.pick_pointed(world, scene, can.bbox, result)
    finally:
        world.close()
    lifted = [a.lifted_product for a in result.attempts if a.lifted_product is not None]
    assert result.success and set(lifted) == {"robosuite/can"}, result


def test_a_pointed_instance_that_moved_is_found_again_near_its_old_box():
    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.core.depth import as_camera_depth
    from binpick.grasping import PinholeCamera
    from binpick.picking import Picker
    from binpick.sim import default_library
    from binpick.sim.mjcf import CameraSpec
    from binpick.warehouse.pipeline import PickPipeline

    library = default_library(procedural=0, shapes=0)
    pipeline = PickPipeline(Detector.load(PICKING).network, library, copies=(1, 1), distractors=(2, 2),
                            camera=CameraSpec(size=256), sensor=load_sensor("realistic"))
    world, rng = pipeline.build_world("robosuite/can", 7)
    try:
        scene = pipeline.settle(world, rng, 7)
        (can,) = [i for i in scene.instances if i.product_id == "robosuite/can"]
        adr = world.qpos_adr[can.slot]
        world.data.qpos[adr:adr + 2] += [0.03, -0.02]  # a failed grasp pushed it 3.6 cm aside
        import mujoco

        mujoco.mj_forward(world.model, world.data)
        moved = world.look_again(scene, 1)
        (now,) = [i for i in moved.instances if i.product_id == "robosuite/can"]
        picker = Picker.load(gripper="both")
        camera = PinholeCamera.from_record(scene.camera)
        found = picker.find_again(scene.rgb, as_camera_depth(scene.depth), can.bbox, moved.rgb, as_camera_depth(moved.depth), camera)
        assert found is not None
        x0, y0, x1, y1 = now.bbox[0], now.bbox[1], now.bbox[0] + now.bbox[2], now.bbox[1] + now.bbox[3]
        fx0, fy0, fx1, fy1 = found[0], found[1], found[0] + found[2], found[1] + found[3]
        overlap = max(0, min(x1, fx1) - max(x0, fx0)) * max(0, min(y1, fy1) - max(y0, fy0))
        union = now.bbox[2] * now.bbox[3] + found[2] * found[3] - overlap
        assert overlap / union > 0.5, (found, now.bbox)
        # the instance gone (carried off): nothing is found in its place
        world.data.qpos[adr:adr + 3] = [3.0, 0.0, 0.5]
        mujoco.mj_forward(world.model, world.data)
        gone = world.look_again(scene, 2)
        assert picker.find_again(scene.rgb, as_camera_depth(scene.depth), can.bbox, gone.rgb, as_camera_depth(gone.depth), camera) is None
    finally:
        world.close()


def _squares_frame(squares, size: int = 200):
    """A grey floor 1 m under a camera looking straight down, with coloured squares 4 cm tall."""
    from binpick.grasping import DepthFrame, PinholeCamera

    camera = PinholeCamera(np.array([[300.0, 0, size / 2], [0, 300.0, size / 2], [0, 0, 1]]), size, size,
                           np.array([[1.0, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 1.0], [0, 0, 0, 1]]))
    rgb = np.full((size, size, 3), 128, np.uint8)
    depth = np.ones((size, size), np.float32)
    for (x, y, w, h), colour, *pattern in squares:
        rgb[y:y + h, x:x + w] = colour
        if pattern:  # a printed label: a darker band across the top third and a dot in the middle
            rgb[y + h // 6:y + h // 3, x + w // 5:x + 4 * w // 5] = np.asarray(colour) // 3
            rgb[y + h // 2:y + h // 2 + 4, x + w // 2:x + w // 2 + 4] = 250
        depth[y:y + h, x:x + w] = 0.96
    return rgb, DepthFrame.from_depth(depth, camera)


def test_a_pointed_instance_pushed_far_is_found_by_its_colours_and_two_look_alikes_are_never_guessed():
    from binpick.picking.colour import colour_histogram
    from binpick.picking.find_again import found_by_colour, instance_pixels, matched_in_place, middle_of

    green, dark_green, red = (20, 170, 30), (15, 120, 25), (200, 30, 30)
    box = np.array([40.0, 40.0, 30.0, 30.0])
    before_rgb, before = _squares_frame([((40, 40, 30, 30), green, "label"), ((130, 40, 30, 30), red)])
    pixels = instance_pixels(before, box)
    assert 0.6 * 900 < pixels.sum() <= 900 + 4 * 31  # the square's own pixels, not the floor round it
    histogram, area = colour_histogram(before_rgb, pixels), int(pixels.sum())
    template = middle_of(before_rgb, box)

    def find(*squares):
        rgb, frame = _squares_frame(list(squares))
        return found_by_colour(histogram, rgb, frame, box, area, template)

    # pushed 2.4 box diagonals away, beside a red product: found where it is now
    found = find(((130, 120, 30, 30), green, "label"), ((130, 40, 30, 30), red))
    assert found is not None and abs(found[0] - 130) <= 3 and abs(found[1] - 120) <= 3, found
    # a second green square of its size and label: colour, size and picture cannot tell them apart
    assert find(((130, 120, 30, 30), green, "label"), ((40, 150, 30, 30), green, "label"), ((130, 40, 30, 30), red)) is None
    # one of them clearly larger: the one of its size is it
    found = find(((130, 120, 30, 30), green, "label"), ((20, 130, 42, 42), green, "label"), ((130, 40, 30, 30), red))
    assert found is not None and abs(found[0] - 130) <= 3, found
    # gone: nothing green standing anywhere; a green product of another look or one far off is not it
    assert find(((130, 40, 30, 30), red)) is None
    assert find(((120, 120, 34, 34), green), ((130, 40, 30, 30), red)) is None  # no label: its picture does not match
    assert find(((165, 165, 30, 30), green, "label")) is None  # past three box diagonals from where it was
    # a flat-coloured instance has no picture to match: never placed by the correlation's arbitrary peak
    flat_rgb, flat = _squares_frame([((40, 40, 30, 30), green), ((4, 4, 30, 30), dark_green)])
    flat_histogram = colour_histogram(flat_rgb, instance_pixels(flat, box))
    assert matched_in_place(flat_rgb, box, flat_rgb, flat, flat_histogram) is None
    assert found_by_colour(flat_histogram, flat_rgb, flat, box, area, middle_of(flat_rgb, box)) is None

"""Pick planning from a real camera's frames: the calibration files, grasp poses in the
base frame, the planner with no simulator in it, and `binpick plan` on an exported scene."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from binpick.core.errors import InputFileError
from binpick.grasping import GraspPlanner, PinholeCamera
from binpick.picking import CameraInfo, Picker, read_camera_info, write_camera_info
from binpick.picking.camera_info import matrix_to_quaternion, quaternion_to_matrix
from binpick.picking.plans import grasp_orientation

K = np.array([[400.0, 0.0, 99.5], [0.0, 400.0, 99.5], [0.0, 0.0, 1.0]])
DOWN = np.array([[1.0, 0, 0, 0.1], [0, -1.0, 0, 0.0], [0, 0, -1.0, 0.8], [0, 0, 0, 1.0]])  # 0.8 m up, looking down


def test_camera_info_yaml_round_trips_and_quaternions_match_rotations(tmp_path):
    info = CameraInfo(PinholeCamera(K, 200, 150, DOWN), np.array([0.1, -0.05, 0.0, 0.0, 0.0]), "plumb_bob", "base_link")
    read = read_camera_info(write_camera_info(info, tmp_path / "camera.yaml"))
    assert np.allclose(read.camera.K, K) and (read.camera.width, read.camera.height) == (200, 150)
    assert np.allclose(read.camera.camera_to_world, DOWN, atol=1e-6) and read.base_frame == "base_link" and read.distorted
    rng = np.random.default_rng(0)
    for q in rng.normal(size=(20, 4)):
        q = q / np.linalg.norm(q) * np.sign(q[3])
        assert np.allclose(matrix_to_quaternion(quaternion_to_matrix(q)), q, atol=1e-9)
    (tmp_path / "bad.yaml").write_text("image_width: 200\nimage_height: 150\ncamera_matrix: {data: [1, 2, 3]}\n")
    with pytest.raises(InputFileError, match="camera_matrix must have 9 numbers"):
        read_camera_info(tmp_path / "bad.yaml")


def test_rectifying_a_distorted_frame_undoes_the_distortion():
    import cv2

    info = CameraInfo(PinholeCamera(K, 200, 200), np.array([-0.3, 0.1, 0.0, 0.0, 0.0]))
    ideal = np.zeros((200, 200, 3), np.uint8)
    ideal[:, 20:24] = 255  # a straight vertical line near the edge, where distortion bends it most
    # the distorted image: each distorted pixel samples the ideal image where it undistorts to
    grid = np.stack(np.meshgrid(np.arange(200.0), np.arange(200.0)), axis=-1).reshape(-1, 1, 2).astype(np.float32)
    undistorted = cv2.undistortPoints(grid, K, info.D, P=K).reshape(200, 200, 2)
    distorted = cv2.remap(ideal, undistorted[..., 0], undistorted[..., 1], cv2.INTER_LINEAR)
    assert abs(np.argmax(distorted[0, :, 0]) - np.argmax(distorted[100, :, 0])) > 3  # bent
    rgb, depth = info.rectify(distorted, np.ones((200, 200), np.float32))
    columns = [np.argmax(rgb[row, :, 0] > 100) for row in (10, 100, 190)]
    assert max(columns) - min(columns) <= 1 and abs(columns[1] - 20) <= 1  # straight again, where it belongs
    assert set(np.unique(depth)) <= {0.0, 1.0}  # depth is never blended between surfaces


def test_the_gripper_pose_points_down_and_closes_along_the_yaw():
    for yaw in (0.0, 0.7, -1.2):
        R = quaternion_to_matrix(grasp_orientation(yaw))
        assert np.allclose(R[:, 2], [0, 0, -1]) and np.allclose(R[:, 0], [np.cos(yaw), np.sin(yaw), 0])
        assert np.isclose(np.linalg.det(R), 1.0)


def test_given_boxes_the_picker_plans_a_grasp_in_the_base_frame():
    camera = PinholeCamera(K, 200, 200, DOWN)
    points = camera.points(np.full((200, 200), 0.8))
    inside = (np.abs(points[..., 0] - 0.12) < 0.02) & (np.abs(points[..., 1] - 0.01) < 0.05)  # a 4 x 10 x 5 cm block
    depth = np.where(inside, 0.75, 0.8).astype(np.float32)
    rows, cols = np.nonzero(inside)
    box = (cols.min(), rows.min(), cols.max() - cols.min() + 1, rows.max() - rows.min() + 1)
    picker = Picker(None, GraspPlanner("analytic"), verifier=None)
    plans = picker.plan(np.zeros((200, 200, 3), np.uint8), depth, camera, boxes=(np.array([box]), np.array([0.9])))
    (plan,) = plans.grasps
    assert np.allclose(plan.position[:2], [0.12, 0.01], atol=0.006) and 0.0 < plan.position[2] < 0.05
    assert abs(np.cos(plan.yaw)) > 0.95  # across the block's 4 cm side (along x), not its 10 cm one
    assert plan.width == pytest.approx(0.04, abs=0.008) and plans.frame == "base_link"
    assert json.loads(json.dumps(plans.to_json()))["plans"][0]["orientation"] == plan.orientation
    # the catalogue's dimensions: a 4 x 10 x 5 cm product fits what depth shows, a 3 x 4 x 2 cm one does not
    detections = (np.array([box]), np.array([0.9]))
    assert picker.plan(np.zeros((200, 200, 3), np.uint8), depth, camera, boxes=detections, size=(0.05, 0.1, 0.04)).grasps
    (small,) = picker.plan(np.zeros((200, 200, 3), np.uint8), depth, camera, boxes=detections, size=(0.03, 0.04, 0.02))
    assert not small.feasible and small.rejected == {"larger than the ordered product": 1}


def test_the_planner_imports_no_simulator():
    code = "import sys, binpick.picking, binpick.picking.frames; assert 'mujoco' not in sys.modules, 'mujoco imported'"
    ran = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert ran.returncode == 0, ran.stderr


def test_binpick_plan_on_an_exported_scene_matches_the_in_memory_plan(tmp_path, monkeypatch, capsys):
    """A simulated bin exported as a camera's files: the CLI plans from the files what the picker plans
    from the arrays (depth rounded to millimetres moves a grasp by at most a few millimetres)."""
    from binpick.cli import main
    from binpick.picking.frames import read_frame
    from binpick.sim import default_library
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.mjcf import CameraSpec
    from binpick.sim.photos import shop_photo
    from binpick.warehouse.export import export_frame

    library = default_library(procedural=0, shapes=0)
    world = BinWorld(library["robosuite/can"], [library["robosuite/lemon"]], max_copies=2, camera=CameraSpec(size=160))
    try:
        scene = world.scene(2, 1, seed=2)
    finally:
        world.close()
    can = max((i for i in scene.instances if i.product_id == "robosuite/can"), key=lambda i: i.visible_fraction)
    out = export_frame(tmp_path / "frame", scene.rgb, scene.depth, scene.camera, shop_photo(library["robosuite/can"], size=96),
                       {"product": "robosuite/can"})
    box = ",".join(str(int(round(v))) for v in can.bbox)
    monkeypatch.setattr(sys, "argv", ["binpick", "plan", "--rgb", str(out / "rgb.png"), "--depth", str(out / "depth.png"),
                                      "--camera", str(out / "camera.yaml"), "--query-box", box, "--grasp", "analytic",
                                      "--out", str(tmp_path)])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 0
    written = json.loads((tmp_path / "plan.json").read_text())
    assert written["frame"] == "world" and (tmp_path / "overlay.png").is_file()
    said = capsys.readouterr().out  # the terminal counts as the overlay's caption does: planned of all detections
    assert f"from {len(written['plans'])} planned of {written['detections']} detections" in " ".join(said.split())
    rgb, depth, info = read_frame(out / "rgb.png", out / "depth.png", out / "camera.yaml")
    assert np.array_equal(rgb, scene.rgb) and np.abs(depth - scene.depth).max() <= 0.0005
    picker = Picker.load(grasp="analytic")
    query = np.array([float(v) for v in box.split(",")])
    from_files = picker.plan(rgb, depth, info, query_box=query)
    from_memory = picker.plan(scene.rgb, scene.depth, PinholeCamera.from_record(scene.camera), query_box=query)
    assert [p["box"] for p in written["plans"]] == [p.box for p in from_files]
    assert len(from_memory) == len(from_files) and from_files.grasps
    for a, b in zip(from_files.grasps, from_memory.grasps):
        assert np.allclose(a.position, b.position, atol=0.004) and a.box == b.box


def test_ros_images_convert_both_ways_and_frames_are_matched_by_stamp():
    from binpick.picking.node import FrameSynchroniser, depth_of, image_array, image_fields, photo_of

    rgb = np.random.default_rng(0).integers(0, 255, (5, 7, 3), dtype=np.uint8)
    fields = image_fields(rgb, "rgb8")
    assert np.array_equal(image_array("rgb8", 5, 7, fields["step"], fields["data"]), rgb)
    padded = b"".join(rgb[r].tobytes() + b"\0\0\0" for r in range(5))  # rows padded to a 24-byte step
    assert np.array_equal(image_array("rgb8", 5, 7, 24, padded), rgb)
    bgra = np.dstack([rgb[..., ::-1], np.full((5, 7), 255, np.uint8)])
    assert np.array_equal(photo_of("bgra8", bgra)[..., :3], rgb)
    millimetres = np.full((2, 2), 812, np.uint16)
    assert np.allclose(depth_of("16UC1", image_array("16UC1", 2, 2, 4, millimetres.tobytes())), 0.812)
    with pytest.raises(InputFileError, match="too few"):
        image_array("rgb8", 5, 7, 21, b"\0" * 20)
    with pytest.raises(InputFileError, match="not supported"):
        image_array("yuv422", 5, 7, 14, b"\0" * 70)
    frames = FrameSynchroniser(slop=0.02)
    info = CameraInfo(PinholeCamera(np.array([[6.0, 0.0, 3.0], [0.0, 6.0, 2.0], [0.0, 0.0, 1.0]]), 7, 5))
    frames.add_colour(1.00, rgb)
    frames.add_depth(1.10, np.ones((5, 7)))  # 100 ms apart: not the same frame
    frames.add_info(1.00, info)
    assert frames.latest() is None
    frames.add_depth(1.01, np.full((5, 7), 2.0))
    latest = frames.latest()
    assert latest.stamp == 1.00 and latest.depth[0, 0] == 2.0

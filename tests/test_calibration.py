"""Hand-eye calibration: the AX = XB solver, the board's detection in simulated pictures, and
`binpick calibrate` writing a camera pose a planner then uses."""

from __future__ import annotations


import numpy as np
import pytest
from conftest import binpick_here

from binpick.core.errors import InputFileError
from binpick.picking.hand_eye import calibrate, inverse, pose_error



def random_pose(rng, turn: float = 0.6, shift: float = 0.2) -> np.ndarray:
    import cv2

    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rng.normal(size=3) * turn)[0]
    pose[:3, 3] = rng.normal(size=3) * shift
    return pose


@pytest.mark.parametrize("mount", ["eye-to-hand", "eye-in-hand"])
def test_the_solver_recovers_the_transform_from_exact_poses_and_drops_a_misread_board(mount):
    rng = np.random.default_rng(0)
    X, fixed = random_pose(rng, 1.0, 0.5), random_pose(rng, 0.5, 0.1)
    flanges = [random_pose(rng) for _ in range(12)]
    # eye-to-hand: flange . board_on_flange = X . board_in_camera; eye-in-hand: flange . X . board_in_camera = board_in_base
    boards = [inverse(X) @ (f if mount == "eye-to-hand" else inverse(f)) @ fixed for f in flanges]
    solved = calibrate(flanges, boards, mount)
    mm, degrees = pose_error(solved.transform, X)
    assert mm < 1e-6 and degrees < 1e-6 and solved.residual_mm < 1e-6 and not solved.dropped
    boards[5] = boards[5] @ random_pose(rng, 0.3, 0.08)  # a board read wrongly in one picture
    solved = calibrate(flanges, boards, mount)
    assert solved.dropped == [5] and max(pose_error(solved.transform, X)) < 1e-6


def test_too_few_poses_or_poses_about_one_axis_are_one_line():
    import cv2

    rng = np.random.default_rng(1)
    X, fixed = random_pose(rng), random_pose(rng)
    flanges = [random_pose(rng) for _ in range(2)]
    with pytest.raises(InputFileError, match="at least 3 poses"):
        calibrate(flanges, [inverse(X) @ f @ fixed for f in flanges])
    about_z = []
    for k in range(8):
        pose = np.eye(4)
        pose[:3, :3] = cv2.Rodrigues(np.array([0.0, 0.0, 0.3 * k]))[0]
        pose[:3, 3] = rng.normal(size=3) * 0.1
        about_z.append(pose)
    with pytest.raises(InputFileError, match="turn about one axis"):
        calibrate(about_z, [inverse(X) @ f @ fixed for f in about_z])


@pytest.mark.parametrize("mount", ["eye-to-hand", "eye-in-hand"])
def test_a_simulated_camera_is_found_within_2_mm_and_0_2_degrees_from_15_board_pictures(mount):
    from binpick.warehouse.calibration import simulated_session

    result = simulated_session(mount, seed=3, poses=15)
    assert result.poses_seen >= 12
    assert result.error_mm < 2.0 and result.error_degrees < 0.2
    assert result.solved.reprojection_px < 0.5  # rendered corners, no noise added


def test_binpick_calibrate_writes_a_camera_pose_the_planner_reads(tmp_path):
    from binpick.picking.camera_info import read_camera_info
    from binpick.warehouse.calibration import write_session

    folder = tmp_path / "session"
    truth = write_session(folder, "eye-to-hand", seed=5, poses=15)
    camera = folder / "camera.yaml"
    with pytest.raises(InputFileError, match="no camera_to_base"):
        read_camera_info(camera)  # not calibrated yet: it cannot plan
    run = binpick_here(["calibrate", str(folder), "--camera", str(camera)])
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    assert "camera_to_base" in run.stdout and "residual" in run.stdout
    info = read_camera_info(camera)
    mm, degrees = pose_error(info.camera.camera_to_world, truth)
    assert mm < 2.0 and degrees < 0.2
    (folder / "poses.yaml").write_text((folder / "poses.yaml").read_text().replace("eye-to-hand", "eye-on-a-stick"))
    bad = binpick_here(["calibrate", str(folder), "--camera", str(camera)])
    assert bad.returncode == 2 and "mount 'eye-on-a-stick'" in bad.stderr and "Traceback" not in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1


def test_an_eye_in_hand_camera_plans_only_with_the_flange_pose_of_its_frame(tmp_path):
    from binpick.picking.calibration_session import calibrate_folder
    from binpick.picking.camera_info import read_camera_info
    from binpick.warehouse.calibration import write_session

    folder = tmp_path / "wrist"
    truth = write_session(folder, "eye-in-hand", seed=2, poses=15)
    camera = folder / "camera.yaml"
    camera.write_text(camera.read_text() + "camera_to_base: {translation: [0, 0, 1], rotation: {x: 1, y: 0, z: 0, w: 0}}\n")
    solved, record = calibrate_folder(folder, camera)  # (an earlier fixed-camera pose in the file goes: it is stale)
    mm, degrees = pose_error(solved.transform, truth)
    assert record["mount"] == "eye-in-hand" and mm < 2.0 and degrees < 0.2
    with pytest.raises(InputFileError, match="eye-in-hand camera .camera_to_flange.: give the flange's pose"):
        read_camera_info(folder / "camera.yaml")
    flange = random_pose(np.random.default_rng(4), 0.3, 0.3)
    info = read_camera_info(folder / "camera.yaml", flange)
    assert np.allclose(info.camera.camera_to_world, flange @ solved.transform, atol=1e-5)
    run = binpick_here(["plan", "--sample", "--flange-pose", "0,0,1,0,0,0,1", "--out", str(tmp_path / "out")])
    assert run.returncode == 2 and "--flange-pose is for a camera on the wrist" in run.stderr

"""A camera pose its own depth contradicts is one line, never a plan: a tilted camera over a level
floor passes with its quaternion read right and fails read w-first; a camera looking up (no pose:
the camera taken for the base) and a floor below the robot base's (unless the workspace declares it)
are refused too."""

from __future__ import annotations

import numpy as np
import pytest

from binpick.core.errors import InputFileError
from binpick.grasping import DepthFrame, PinholeCamera
from binpick.picking.camera_info import quaternion_to_matrix
from binpick.picking.pose_check import check_camera_pose
from binpick.picking.workspace import Workspace

K = np.array([[120.0, 0.0, 64.0], [0.0, 120.0, 48.0], [0.0, 0.0, 1.0]])


def pose(quaternion, translation) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = quaternion_to_matrix(quaternion), translation
    return matrix


def floor_seen_by(true_pose: np.ndarray, floor_z: float = 0.03) -> np.ndarray:
    """Depth (m along the optical axis) of a level floor at ``floor_z`` seen by a camera at ``true_pose``."""
    v, u = np.mgrid[0:96, 0:128]
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((96, 128))], axis=-1) @ true_pose[:3, :3].T
    return ((floor_z - true_pose[2, 3]) / rays[..., 2]).astype(np.float32)


def frame(depth: np.ndarray, believed_pose: np.ndarray) -> DepthFrame:
    return DepthFrame.from_depth(depth, PinholeCamera(K, 128, 96, believed_pose))


TILTED = [float(np.sin(np.radians(100.0))), 0.0, 0.0, float(np.cos(np.radians(100.0)))]  # x, y, z, w: 20 degrees off straight down
AT = [0.1, -0.05, 0.85]


def test_a_tilted_camera_passes_read_right_and_is_refused_read_w_first():
    depth = floor_seen_by(pose(TILTED, AT))
    check_camera_pose(frame(depth, pose(TILTED, AT)))  # the right pose: nothing to say
    w_first = [TILTED[3], *TILTED[:3]]
    with pytest.raises(InputFileError, match="degrees from level.*x, y, z, w") as raised:
        check_camera_pose(frame(depth, pose(w_first, AT)))
    assert "\n" not in str(raised.value)


def test_a_camera_looking_up_or_a_floor_below_the_base_is_refused():
    down = [1.0, 0.0, 0.0, 0.0]  # x, y, z, w: straight down
    depth = floor_seen_by(pose(down, AT))
    with pytest.raises(InputFileError, match="optical axis up"):  # no camera_to_base: the camera taken for the base
        check_camera_pose(frame(depth, np.eye(4)))
    with pytest.raises(InputFileError, match="below the robot base's floor"):  # the translation's z given negative
        check_camera_pose(frame(depth, pose(down, [0.1, -0.05, -0.85])))
    low = floor_seen_by(pose(down, [0.1, -0.05, 0.2]), floor_z=-0.6)  # a tote 60 cm below the arm's base
    believed = pose(down, [0.1, -0.05, 0.2])
    with pytest.raises(InputFileError, match="below the robot base's floor"):
        check_camera_pose(frame(low, believed))
    check_camera_pose(frame(low, believed), Workspace((-0.5, -0.5, -0.6), (0.5, 0.5, 0.0)))  # ... declared: fine
    with pytest.raises(InputFileError, match="outside the workspace's heights"):
        check_camera_pose(frame(depth, pose(down, AT)), Workspace((-0.5, -0.5, 0.3), (0.5, 0.5, 0.8)))


def test_a_w_first_quaternion_is_refused_wherever_it_tilts_the_floor_past_the_limit():
    """Cameras tilted 10-40 degrees from straight down, turned 0-135 degrees about the vertical: read
    w-first, every pose whose misread puts the floor more than 14 degrees off level (or the camera
    looking up) is refused, steeper than the planner's own plane fit takes included; read right, none is."""
    refused = 0
    for tilt in (10.0, 20.0, 30.0, 40.0):
        for turn in (0.0, 45.0, 90.0, 135.0):
            t, u = np.radians(tilt), np.radians(turn)
            down = np.diag([1.0, -1.0, -1.0])  # straight down
            about_x = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
            about_z = np.array([[np.cos(u), -np.sin(u), 0], [np.sin(u), np.cos(u), 0], [0, 0, 1]])
            from binpick.picking.camera_info import matrix_to_quaternion

            rotation = about_z @ about_x @ down
            quaternion = matrix_to_quaternion(rotation)  # x, y, z, w
            true_pose = np.eye(4)
            true_pose[:3, :3], true_pose[:3, 3] = rotation, AT
            depth = floor_seen_by(true_pose)
            check_camera_pose(frame(depth, true_pose))  # read right: nothing to say
            wrong = pose([quaternion[3], *quaternion[:3]], AT)
            normal = wrong[:3, :3] @ rotation.T @ np.array([0.0, 0.0, 1.0])  # the floor's normal as the misread places it
            apparent = np.degrees(np.arccos(min(1.0, abs(normal[2]))))
            try:
                check_camera_pose(frame(depth, wrong))
            except InputFileError:
                refused += 1
                continue
            assert apparent <= 14.0 and wrong[2, 2] < 0, (tilt, turn, apparent)  # only a misread that leaves it near level passes
    assert refused >= 14, refused  # 15 of the 16 (the 10-degree camera facing the base: its floor comes out 10 degrees off)

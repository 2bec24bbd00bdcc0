"""A hand-eye calibration session in the simulator, for checking ``binpick calibrate``'s solver
against a camera pose it was not told: the board rendered at many flange poses (the board facing the
camera, tilted and turned at random), its corners detected, optionally with pixel noise on the
corners and noise on the flange poses the robot reports, then solved.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from binpick.picking.charuco import Board, board_corners, board_pose
from binpick.picking.hand_eye import HandEye, calibrate, inverse, pose_error

BOARD_CENTRE = np.array([0.45, 0.0, 0.30])  # where the board is shown (eye-to-hand), or lies (eye-in-hand, on the table)


def _rotation(vector: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(vector, dtype=float))[0]


def _looking(at: np.ndarray, origin: np.ndarray, spin: float) -> np.ndarray:
    """A frame at ``origin`` whose z points at ``at`` (OpenCV's camera and board convention), turned ``spin`` about it."""
    z = (at - origin) / np.linalg.norm(at - origin)
    x = np.cross([0.0, 0.0, 1.0], z) if abs(z[2]) < 0.95 else np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z], axis=1) @ _rotation([0.0, 0.0, spin])
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = R, origin
    return pose


def _tilted(pose: np.ndarray, rng: np.random.Generator, degrees: float, shift: float) -> np.ndarray:
    tilted = pose.copy()
    axis = rng.normal(size=3)
    tilted[:3, :3] = _rotation(axis / np.linalg.norm(axis) * np.radians(rng.uniform(5, degrees))) @ pose[:3, :3]
    tilted[:3, 3] = pose[:3, 3] + rng.uniform(-shift, shift, 3)
    return tilted


def _noisy(pose: np.ndarray, rng: np.random.Generator, mm: float, degrees: float) -> np.ndarray:
    noisy = pose.copy()
    noisy[:3, :3] = _rotation(rng.normal(size=3) * np.radians(degrees)) @ pose[:3, :3]
    noisy[:3, 3] = pose[:3, 3] + rng.normal(size=3) * mm / 1000
    return noisy


@dataclass
class SessionResult:
    mount: str
    seed: int
    poses_rendered: int
    poses_seen: int
    error_mm: float  # the recovered camera pose against the true one
    error_degrees: float
    solved: HandEye


def render_session(mount: str = "eye-to-hand", seed: int = 0, poses: int = 20, flange_mm: float = 0.0,
                   flange_degrees: float = 0.0, board: Board = Board()) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray, np.ndarray]:
    """(pictures, flange poses as the robot would report them (with its noise), the true transform
    (camera_to_base or camera_to_flange), the camera's K) for ``poses`` flange poses over the working volume."""
    from binpick.sim.calibration_rig import CalibrationRig

    rng = np.random.default_rng(seed)
    w, h = board.size
    centre_on_board = np.array([w / 2, h / 2, 0.0])
    if mount == "eye-to-hand":
        camera = _looking(BOARD_CENTRE, BOARD_CENTRE + [0.35, rng.uniform(-0.2, 0.2), 0.55], rng.uniform(-np.pi, np.pi))
        board_on_flange = np.eye(4)
        board_on_flange[:3, 3] = [-w / 2, -h / 2, 0.02]  # the board's centre 2 cm out along the flange's z
        truth, fixed = camera, board_on_flange
    else:
        camera_on_flange = np.eye(4)
        camera_on_flange[:3, :3] = _rotation([0.0, 0.0, np.pi / 2])
        camera_on_flange[:3, 3] = [0.06, 0.0, 0.04]
        board_in_base = _looking(BOARD_CENTRE + [0, 0, -1.0], BOARD_CENTRE, 0.0)  # flat, face up: its z down
        board_in_base[:3, 3] -= board_in_base[:3, :3] @ centre_on_board  # ... centred on BOARD_CENTRE
        truth, fixed = camera_on_flange, board_in_base
    rig = CalibrationRig(board.picture(), board.size, mount, truth, fixed)
    pictures, flanges = [], []
    try:
        for _ in range(poses):
            if mount == "eye-to-hand":  # the board faces the camera, tilted and turned, over the working volume
                facing = _looking(BOARD_CENTRE + (BOARD_CENTRE - camera[:3, 3]), BOARD_CENTRE, rng.uniform(-np.pi, np.pi))
                board_pose_base = _tilted(facing, rng, 40.0, 0.15)
                board_pose_base[:3, 3] -= board_pose_base[:3, :3] @ centre_on_board
                flange = board_pose_base @ inverse(board_on_flange)
            else:  # the camera looks at the board from 35-65 cm, from up to about 40 degrees off vertical
                direction = _rotation(rng.normal(size=3) * np.radians(25)) @ np.array([0.0, 0.0, 1.0])
                aim = BOARD_CENTRE + np.append(rng.uniform(-0.06, 0.06, 2), 0.0)
                eye = _looking(aim, aim + direction * rng.uniform(0.35, 0.65), rng.uniform(-np.pi, np.pi))
                flange = eye @ inverse(camera_on_flange)
            pictures.append(rig.picture(flange))
            flanges.append(_noisy(flange, rng, flange_mm, flange_degrees))
    finally:
        rig.close()
    return pictures, flanges, truth, rig.K


def simulated_session(mount: str = "eye-to-hand", seed: int = 0, poses: int = 20, pixel_noise: float = 0.0,
                      flange_mm: float = 0.0, flange_degrees: float = 0.0, board: Board = Board()) -> SessionResult:
    """Render the board at ``poses`` flange poses, detect it (``pixel_noise`` px added to its corners),
    solve, and compare with the truth."""
    pictures, flanges, truth, K = render_session(mount, seed, poses, flange_mm, flange_degrees, board)
    rng = np.random.default_rng([seed, 1])
    seen, views, observations = [], [], []
    for picture, flange in zip(pictures, flanges):
        found = board_corners(picture, board)
        if found is None:
            continue
        objects, pixels = found
        pixels = pixels + rng.normal(size=pixels.shape) * pixel_noise
        views.append(board_pose(objects, pixels, K).board_to_camera)
        observations.append((objects, pixels))
        seen.append(flange)
    solved = calibrate(seen, views, mount, observations, K)
    error_mm, error_degrees = pose_error(solved.transform, truth)
    return SessionResult(mount, seed, poses, len(views), error_mm, error_degrees, solved)


def write_session(folder: Path, mount: str = "eye-to-hand", seed: int = 0, poses: int = 20, board: Board = Board()) -> np.ndarray:
    """A calibration folder as a user's robot would make it (pictures, poses.yaml) and a camera.yaml
    with the rig's intrinsics and no pose yet; returns the true transform."""
    import yaml
    from PIL import Image

    from binpick.picking.camera_info import matrix_to_quaternion

    pictures, flanges, truth, K = render_session(mount, seed, poses, board=board)
    folder.mkdir(parents=True, exist_ok=True)
    entries = []
    for index, (picture, flange) in enumerate(zip(pictures, flanges)):
        name = f"pose_{index:02d}.png"
        Image.fromarray(picture).save(folder / name)
        entries.append({"image": name, "flange_to_base": {"translation": [round(float(v), 6) for v in flange[:3, 3]],
                                                          "rotation": dict(zip("xyzw", (round(float(v), 9) for v in matrix_to_quaternion(flange[:3, :3]))))}})
    session = {"mount": mount, "board": {"squares": list(board.squares), "square": board.square, "marker": board.marker,
                                         "dictionary": board.dictionary}, "poses": entries}
    (folder / "poses.yaml").write_text(yaml.safe_dump(session, sort_keys=False, default_flow_style=None))
    height, width = pictures[0].shape[:2]
    camera = {"image_width": width, "image_height": height, "camera_name": "simulated",
              "camera_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in K.ravel()]},
              "distortion_model": "plumb_bob", "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0.0] * 5}}
    (folder / "camera.yaml").write_text(yaml.safe_dump(camera, sort_keys=False, default_flow_style=None))
    return truth

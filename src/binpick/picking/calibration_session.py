"""``binpick calibrate``: a folder of board pictures and the flange pose the robot reported at each
-> the camera's pose, written into ``camera.yaml``.

The folder holds the pictures and ``poses.yaml``::

    mount: eye-to-hand            # the camera stands still and the board rides on the flange; or eye-in-hand
    board: {squares: [7, 5], square: 0.04, marker: 0.03, dictionary: 5x5_100}   # as printed, measured
    poses:                        # the flange in the robot's base frame when each picture was taken
      - image: pose_00.png
        flange_to_base: {translation: [0.45, 0.0, 0.30], rotation: {x: 1.0, y: 0.0, z: 0.0, w: 0.0}}

eye-to-hand writes ``camera_to_base``; eye-in-hand writes ``camera_to_flange`` (a frame's
``camera_to_base`` is then the flange's pose when it was taken times it). With ``intrinsics`` the
camera's K and distortion are solved from the same pictures first (a camera without factory ones).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from binpick.core.errors import InputFileError
from binpick.picking.camera_info import matrix_to_quaternion, read_intrinsics, read_pose
from binpick.picking.charuco import Board, board_corners, board_pose, intrinsics_from_board
from binpick.picking.hand_eye import FLANGE_SIGMA, MOUNTS, HandEye, calibrate


def read_session(folder: Path) -> tuple[str, Board, list[tuple[Path, np.ndarray]]]:
    """(mount, board, [(picture, flange_to_base 4x4), ...]) from ``folder/poses.yaml``; one line per mistake."""
    from binpick.core.files import read_yaml

    path = folder / "poses.yaml"
    if not path.is_file():
        raise InputFileError(f"{str(folder)!r} has no poses.yaml (the flange pose at each picture; see `binpick calibrate --help`)")
    data = read_yaml(path, "poses file")
    where = f"poses file {str(path)!r}"
    if not isinstance(data, dict):
        raise InputFileError(f"{where} must be a mapping with mount, board and poses")
    unknown = set(data) - {"mount", "board", "poses"}
    if unknown:
        raise InputFileError(f"{where}: unknown field(s) {', '.join(sorted(map(str, unknown)))} (mount, board, poses)")
    mount = str(data.get("mount", "eye-to-hand"))
    if mount not in MOUNTS:
        raise InputFileError(f"{where}: mount {mount!r}: choose from {', '.join(MOUNTS)}")
    board_data = data.get("board") or {}
    if not isinstance(board_data, dict):
        raise InputFileError(f"{where}: board must be a mapping (squares, square, marker, dictionary)")
    try:
        board = Board(tuple(int(v) for v in board_data.get("squares", Board.squares)), float(board_data.get("square", Board.square)),
                      float(board_data.get("marker", Board.marker)), str(board_data.get("dictionary", Board.dictionary)))
    except (TypeError, ValueError) as error:
        raise InputFileError(f"{where}: board: {error}") from None
    poses = data.get("poses")
    if not isinstance(poses, list) or not poses:
        raise InputFileError(f"{where}: poses must be a list of {{image, flange_to_base}}")
    session = []
    for index, entry in enumerate(poses):
        if not isinstance(entry, dict) or "image" not in entry or "flange_to_base" not in entry:
            raise InputFileError(f"{where}: poses[{index}] must have image and flange_to_base")
        picture = folder / str(entry["image"])
        if not picture.is_file():
            raise InputFileError(f"{where}: poses[{index}].image {str(entry['image'])!r} is not in {str(folder)!r}")
        session.append((picture, read_pose(entry["flange_to_base"], where, f"poses[{index}].flange_to_base")))
    return mount, board, session


def calibrate_folder(folder: Path, camera: Path, intrinsics: bool = False,
                     flange_sigma: tuple[float, float] = FLANGE_SIGMA, on_picture=None) -> tuple[HandEye, dict]:
    """Solve the folder's session and write the result into ``camera`` (its intrinsics too with
    ``intrinsics``); (the solution, the calibration record written beside it)."""
    from binpick.picking.frames import read_colour

    mount, board, session = read_session(folder)
    found, flanges, names = [], [], []
    size = None
    for picture, flange in session:
        image = read_colour(picture, "board picture")
        size = (image.shape[1], image.shape[0])
        corners = board_corners(image, board)
        if on_picture is not None:
            on_picture(picture, corners is not None)
        if corners is not None:
            found.append(corners)
            flanges.append(flange)
            names.append(picture.name)
    if intrinsics:
        K, distortion, rms = intrinsics_from_board(found, size)
    else:
        K, distortion, width, height = read_intrinsics(camera)
        if size is not None and size != (width, height):
            raise InputFileError(f"the pictures are {size[0]}x{size[1]} but {str(camera)!r} is for {width}x{height}: "
                                 "take them with the camera as it runs, or solve the intrinsics too (--intrinsics)")
    views = [board_pose(objects, pixels, K, distortion) for objects, pixels in found]
    solved = calibrate(flanges, [v.board_to_camera for v in views], mount, found, K, distortion, flange_sigma)
    record = {**solved.summary(), "pictures": len(session), "board_seen": len(found),
              "dropped_pictures": [names[k] for k in solved.dropped],
              "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    if intrinsics:
        record["intrinsics_reprojection_px"] = round(rms, 3)
    write_calibration(camera, solved, record, K if intrinsics else None, distortion if intrinsics else None, size)
    return solved, record


def write_calibration(camera: Path, solved: HandEye, record: dict, K=None, distortion=None, size=None) -> None:
    """Put the solved pose (and the record of how it was solved) into the camera file, keeping its other fields."""
    import yaml

    from binpick.core.files import atomic_write_text, read_yaml

    data = read_yaml(camera, "camera file") if camera.is_file() else {}
    if K is not None:
        data.update({"image_width": int(size[0]), "image_height": int(size[1]), "camera_name": data.get("camera_name", "binpick"),
                     "camera_matrix": {"rows": 3, "cols": 3, "data": [round(float(v), 6) for v in np.ravel(K)]},
                     "distortion_model": "plumb_bob",
                     "distortion_coefficients": {"rows": 1, "cols": 5, "data": [round(float(v), 8) for v in np.ravel(distortion)[:5]]}})
    pose = solved.transform
    name = "camera_to_base" if solved.mount == "eye-to-hand" else "camera_to_flange"
    previous = data.get(name) if isinstance(data.get(name), dict) else {}
    data[name] = {**({"base_frame": previous.get("base_frame", "base_link")} if name == "camera_to_base" else {}),
                  "translation": [round(float(v), 6) for v in pose[:3, 3]],
                  "rotation": dict(zip("xyzw", (round(float(v), 8) for v in matrix_to_quaternion(pose[:3, :3]))))}
    data.pop("camera_to_flange" if name == "camera_to_base" else "camera_to_base", None)  # the other mounting's pose: stale now
    data["calibration"] = {k: v for k, v in record.items() if k not in ("camera_to_base", "camera_to_flange")}
    atomic_write_text(camera, yaml.safe_dump(data, sort_keys=False, default_flow_style=None))

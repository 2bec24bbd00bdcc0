"""A real camera's calibration in the files robot integrators already have: ROS's ``camera_info``
YAML (``camera_calibration_parsers`` layout: image_width, image_height, camera_matrix,
distortion_model, distortion_coefficients) plus binpick's one addition, ``camera_to_base``: where the
camera's optical frame (x right, y down, z forward) sits in the robot's base frame, from hand-eye
calibration. Every grasp is given in that frame, so the file must have it (one line says so when it
has not), and the planner checks it against the camera's own depth before planning
(:mod:`binpick.picking.pose_check`). Distorted images are rectified before planning, so everything
downstream is pinhole.

    camera_to_base:
      base_frame: base_link
      translation: [0.0, 0.0, 0.8]                   # metres
      rotation: {x: 1.0, y: 0.0, z: 0.0, w: 0.0}     # quaternion, its order named (this one: looking straight down)

``rotation`` may also be a list, read in ROS's order x, y, z, w (as ``geometry_msgs/Quaternion``);
binpick writes the named form, which cannot be read in the wrong order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from binpick.core.errors import ConfigError, InputFileError
from binpick.grasping.camera import PinholeCamera
from binpick.picking.workspace import Workspace

DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "equidistant", "none", "")
# coefficient counts each model may carry (none given: no distortion); OpenCV's own for the first two
DISTORTION_LENGTHS = {"plumb_bob": (4, 5, 8, 12, 14), "rational_polynomial": (8, 12, 14), "equidistant": (4, 5, 8)}


def quaternion_to_matrix(q) -> np.ndarray:
    """(x, y, z, w) -> 3x3 rotation (normalised first; a zero quaternion is an error)."""
    x, y, z, w = (float(v) for v in q)
    n = np.sqrt(x * x + y * y + z * z + w * w)
    if not np.isfinite(n) or n < 1e-9:
        raise ConfigError(f"camera_to_base.rotation must be a non-zero quaternion x, y, z, w, got {list(q)}")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def matrix_to_quaternion(R: np.ndarray) -> list[float]:
    """3x3 rotation -> (x, y, z, w) with w >= 0 (Shepperd's method: stable for every rotation)."""
    R = np.asarray(R, dtype=float)
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    q = np.array(q) / np.linalg.norm(q)
    return (q if q[3] >= 0 else -q).tolist()


@dataclass(frozen=True)
class CameraInfo:
    """Intrinsics (K, D, size) and extrinsic (camera-to-base) of one calibrated RGB-D camera."""

    camera: PinholeCamera  # the pinhole model planning uses (K, size, camera_to_base)
    D: np.ndarray = field(default_factory=lambda: np.zeros(0))  # distortion coefficients, ROS order
    distortion_model: str = "plumb_bob"
    base_frame: str = "base_link"
    workspace: Workspace | None = None  # where grasps may be (base frame); None: around the camera's view

    @property
    def distorted(self) -> bool:
        return self.distortion_model not in ("none", "") and bool(np.any(np.abs(self.D) > 1e-12))

    @classmethod
    def from_ros(cls, K, D, width: int, height: int, camera_to_base=None, distortion_model: str = "plumb_bob",
                 base_frame: str = "base_link") -> CameraInfo:
        """From a ``sensor_msgs/CameraInfo``'s fields (K row-major, 9 numbers) and a 4x4 transform."""
        K = np.asarray(K, dtype=float)
        if K.size != 9:
            raise ConfigError(f"camera intrinsics K must have 9 numbers (3x3, row-major), got {K.size}")
        if distortion_model not in DISTORTION_MODELS:
            raise ConfigError(f"distortion_model {distortion_model!r} is not one binpick rectifies: "
                              f"use one of {', '.join(m for m in DISTORTION_MODELS if m)}")
        D = np.asarray(D, dtype=float).ravel()
        if not np.all(np.isfinite(D)):
            raise ConfigError(f"distortion coefficients must be finite, got {D.tolist()[:8]}")
        wanted = DISTORTION_LENGTHS.get(distortion_model)
        if D.size and wanted is not None and D.size not in wanted:
            raise ConfigError(f"distortion model {distortion_model} takes {' or '.join(map(str, wanted))} coefficients, "
                              f"got {D.size}")
        if distortion_model == "equidistant" and np.any(D[4:] != 0):
            raise ConfigError(f"distortion model equidistant has 4 coefficients (k1-k4); got more that are not zero: {D.tolist()}")
        if distortion_model in ("none", "") and np.any(D != 0):
            raise ConfigError(f"distortion model {distortion_model or 'empty'!r} with non-zero coefficients {D.tolist()[:8]}")
        pose = np.eye(4) if camera_to_base is None else np.asarray(camera_to_base, dtype=float)
        return cls(PinholeCamera(K.reshape(3, 3), width, height, pose), D, distortion_model, base_frame)

    def scaled(self, width: int, height: int) -> CameraInfo:
        """The same camera seen at ``width`` x ``height`` pixels (the same field of view): K scaled about
        pixel centres; the distortion coefficients, which act on normalised coordinates, unchanged."""
        from dataclasses import replace

        sx, sy = width / self.camera.width, height / self.camera.height
        K = np.array(self.camera.K, dtype=float)
        K[0, 0], K[0, 1], K[0, 2] = K[0, 0] * sx, K[0, 1] * sx, (K[0, 2] + 0.5) * sx - 0.5
        K[1, 1], K[1, 2] = K[1, 1] * sy, (K[1, 2] + 0.5) * sy - 0.5
        return replace(self, camera=PinholeCamera(K, int(width), int(height), self.camera.camera_to_world))

    def rectify(self, rgb: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted colour (bilinear) and depth (nearest: never a depth between two surfaces),
        with the same K; unchanged when the camera has no distortion."""
        if not self.distorted:
            return rgb, depth
        import cv2

        K, size = self.camera.K, (int(self.camera.width), int(self.camera.height))
        if self.distortion_model == "equidistant":
            maps = cv2.fisheye.initUndistortRectifyMap(K, self.D[:4], np.eye(3), K, size, cv2.CV_32FC1)
        else:
            maps = cv2.initUndistortRectifyMap(K, self.D, np.eye(3), K, size, cv2.CV_32FC1)
        return (cv2.remap(rgb, *maps, cv2.INTER_LINEAR),
                cv2.remap(np.asarray(depth, np.float32), *maps, cv2.INTER_NEAREST, borderValue=0.0))

    def to_yaml_dict(self, camera_name: str = "binpick") -> dict[str, Any]:
        """The ``camera_info`` YAML layout (with ``camera_to_base``) that :func:`read_camera_info` reads."""
        K = self.camera.K.round(6).tolist()
        P = np.hstack([self.camera.K, np.zeros((3, 1))]).round(6).ravel().tolist()
        D = self.D.tolist() if self.D.size else [0.0] * DISTORTION_LENGTHS.get(self.distortion_model, (5,))[0]
        pose = self.camera.camera_to_world
        return {"image_width": int(self.camera.width), "image_height": int(self.camera.height), "camera_name": camera_name,
                "camera_matrix": {"rows": 3, "cols": 3, "data": [v for row in K for v in row]},
                "distortion_model": self.distortion_model or "plumb_bob",
                "distortion_coefficients": {"rows": 1, "cols": len(D), "data": D},
                "rectification_matrix": {"rows": 3, "cols": 3, "data": np.eye(3).ravel().tolist()},
                "projection_matrix": {"rows": 3, "cols": 4, "data": P},
                "camera_to_base": {"base_frame": self.base_frame, "translation": pose[:3, 3].round(6).tolist(),
                                   "rotation": dict(zip("xyzw", (round(v, 8) for v in matrix_to_quaternion(pose[:3, :3]))))},
                **({"workspace": self.workspace.to_mapping()} if self.workspace is not None else {})}


def _numbers(data: dict, key: str, count: int | None, where: str) -> np.ndarray:
    value = data.get(key)
    if isinstance(value, dict):
        value = value.get("data")
    if value is None:
        raise InputFileError(f"camera file {where} has no {key} (the camera_info YAML layout: {key}: {{data: [...]}})")
    try:
        array = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputFileError(f"camera file {where}: {key} must be numbers, got {value!r:.60}") from None
    if count is not None and array.size != count:
        raise InputFileError(f"camera file {where}: {key} must have {count} numbers, got {array.size}")
    if not np.all(np.isfinite(array)):
        raise InputFileError(f"camera file {where}: {key} has a number that is not finite")
    return array


def _rotation(value, where: str) -> np.ndarray:
    """camera_to_base's quaternion: ``{x, y, z, w}`` (its order named) or a list in ROS's order x, y, z, w."""
    if isinstance(value, dict):
        if set(value) != set("xyzw"):
            raise InputFileError(f"camera file {where}: camera_to_base.rotation must name x, y, z and w, got "
                                 f"{sorted(map(str, value))}")
        value = [value[k] for k in "xyzw"]
    if value is None:
        raise InputFileError(f"camera file {where}: camera_to_base has no rotation (a quaternion {{x, y, z, w}})")
    return _numbers({"rotation": value}, "rotation", 4, where)


def read_pose(value, where: str, name: str) -> np.ndarray:
    """A pose mapping (``translation: [x, y, z]`` in metres, ``rotation: {x, y, z, w}`` or a list in
    ROS's order x, y, z, w; or ``matrix``: 16 numbers) -> 4x4. Malformed: one line naming ``name``."""
    if not isinstance(value, dict):
        raise InputFileError(f"{where}: {name} must be a mapping with translation and rotation")
    try:
        return _pose_of(value, where)
    except (InputFileError, ConfigError) as error:
        raise InputFileError(f"{name}: {error}") from None


def _pose_of(value: dict, where: str) -> np.ndarray:
    """A pose mapping's 4x4 (``matrix``, or ``translation`` and ``rotation``)."""
    pose = np.eye(4)
    if "matrix" in value:
        return _numbers(value, "matrix", 16, where).reshape(4, 4)
    pose[:3, 3] = _numbers(value, "translation", 3, where)
    pose[:3, :3] = quaternion_to_matrix(_rotation(value.get("rotation"), where))
    return pose


def read_intrinsics(path: str | Path) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Only a camera file's K, distortion and size (a camera not yet calibrated has no camera_to_base)."""
    from binpick.core.files import read_yaml

    where = repr(str(path))
    data = read_yaml(path, "camera file")
    if not isinstance(data, dict):
        raise InputFileError(f"camera file {where} must be a mapping in the ROS camera_info YAML layout")
    for key in ("image_width", "image_height"):
        if isinstance(data.get(key), bool) or not isinstance(data.get(key), int) or data[key] < 1:
            raise InputFileError(f"camera file {where}: {key} must be a positive whole number of pixels, got {data.get(key)!r}")
    K = _numbers(data, "camera_matrix", 9, where).reshape(3, 3)
    D = _numbers(data, "distortion_coefficients", None, where) if "distortion_coefficients" in data else np.zeros(5)
    model = str(data.get("distortion_model", "plumb_bob") or "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial"):
        raise InputFileError(f"camera file {where}: distortion_model {model!r}: calibration reads plumb_bob or "
                             "rational_polynomial (OpenCV's pinhole model); rectify a fisheye camera's images first")
    return K, D, data["image_width"], data["image_height"]


def read_camera_info(path: str | Path, flange_to_base: np.ndarray | None = None) -> CameraInfo:
    """A ``camera_info`` YAML file with its ``camera_to_base``. Anything missing or malformed is one
    line naming the field. A camera on the wrist (eye-in-hand: ``camera_to_flange``, as ``binpick
    calibrate`` writes it) needs ``flange_to_base``, the flange's pose when the frame was taken."""
    from binpick.core.files import read_yaml

    where = repr(str(path))
    data = read_yaml(path, "camera file")  # a regular file, UTF-8, no key twice, no bomb
    if not isinstance(data, dict):
        raise InputFileError(f"camera file {where} must be a mapping in the ROS camera_info YAML layout")
    for key in ("image_width", "image_height"):
        if isinstance(data.get(key), bool) or not isinstance(data.get(key), int) or data[key] < 1:
            raise InputFileError(f"camera file {where}: {key} must be a positive whole number of pixels, got {data.get(key)!r}")
    K = _numbers(data, "camera_matrix", 9, where)
    D = _numbers(data, "distortion_coefficients", None, where) if "distortion_coefficients" in data else np.zeros(0)
    model = str(data.get("distortion_model", "plumb_bob") or "")
    base_frame = "base_link"
    extrinsic = data.get("camera_to_base")
    if extrinsic is not None and data.get("camera_to_flange") is not None:
        raise InputFileError(f"camera file {where} has both camera_to_base (a fixed camera) and camera_to_flange (a camera on "
                             "the wrist): keep the one your camera is mounted as")
    if extrinsic is None and data.get("camera_to_flange") is not None:
        if flange_to_base is None:
            raise InputFileError(f"camera file {where} is an eye-in-hand camera (camera_to_flange): give the flange's pose "
                                 "when the frame was taken (binpick plan --flange-pose x,y,z,qx,qy,qz,qw in the base frame; "
                                 "binpick cell and the ROS nodes take fixed cameras only)")
        on_flange = read_pose(data["camera_to_flange"], f"camera file {where}", "camera_to_flange")
        composed = np.asarray(flange_to_base, dtype=float) @ on_flange
        extrinsic = {"matrix": composed.ravel().tolist(), "base_frame": data["camera_to_flange"].get("base_frame", base_frame)
                     if isinstance(data["camera_to_flange"], dict) else base_frame}
    elif flange_to_base is not None:
        raise InputFileError(f"camera file {where} has camera_to_base (a fixed camera): --flange-pose is for a camera on the wrist")
    if extrinsic is None:
        raise InputFileError(f"camera file {where} has no camera_to_base: the camera's pose in the robot's base frame, in "
                             "which every grasp is given (from hand-eye calibration: translation [x, y, z] in metres, "
                             "rotation {x, y, z, w})")
    if not isinstance(extrinsic, dict):
        raise InputFileError(f"camera file {where}: camera_to_base must be a mapping with translation and rotation")
    pose = _pose_of(extrinsic, where)
    base_frame = str(extrinsic.get("base_frame", base_frame))
    try:
        info = CameraInfo.from_ros(K, D, data["image_width"], data["image_height"], pose, model, base_frame)
        if data.get("workspace") is not None:
            from dataclasses import replace

            info = replace(info, workspace=Workspace.from_mapping(data["workspace"]))
        return info
    except ConfigError as error:
        raise InputFileError(f"camera file {where}: {error}") from None


def write_camera_info(info: CameraInfo, path: str | Path) -> Path:
    import yaml

    from binpick.core.files import atomic_write_text

    path = Path(path)
    atomic_write_text(path, yaml.safe_dump(info.to_yaml_dict(), sort_keys=False, default_flow_style=None))
    return path

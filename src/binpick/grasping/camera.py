"""A calibrated pinhole camera: intrinsics as ROS's ``camera_info`` has them (K, width, height) and the
camera's pose in the world (or the robot's base) frame, OpenCV axes (x right, y down, z forward).

Grasp planning works in the world frame from depth alone, so it needs nothing else from a simulator:
a real camera's calibration gives exactly these numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from binpick.errors import ConfigError


@dataclass(frozen=True)
class PinholeCamera:
    K: np.ndarray  # (3, 3) intrinsics in pixels
    width: int
    height: int
    camera_to_world: np.ndarray = field(default_factory=lambda: np.eye(4))  # (4, 4), OpenCV camera axes

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        pose = np.asarray(self.camera_to_world, dtype=float)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ConfigError(f"camera intrinsics K must be a 3x3 matrix with positive focal lengths, got {K.tolist()}")
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise ConfigError("camera_to_world must be a finite 4x4 transform")
        if int(self.width) < 1 or int(self.height) < 1:
            raise ConfigError(f"camera width and height must be positive, got {self.width} x {self.height}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "camera_to_world", pose)

    @classmethod
    def from_record(cls, record: dict) -> PinholeCamera:
        """From a scene's ``camera`` record (binpick's scene JSON and COCO image entries)."""
        try:
            return cls(np.array(record["K"]), int(record["width"]), int(record["height"]),
                       np.array(record.get("camera_to_world", np.eye(4))))
        except KeyError as missing:
            raise ConfigError(f"camera record has no {missing.args[0]!r} field") from None

    def to_record(self) -> dict:
        return {"K": self.K.round(6).tolist(), "width": int(self.width), "height": int(self.height),
                "camera_to_world": self.camera_to_world.round(6).tolist()}

    def points(self, depth: np.ndarray) -> np.ndarray:
        """World xyz (H, W, 3) float32 of every pixel of ``depth`` (metres along the optical axis; 0 or
        non-finite: no reading, NaN out)."""
        z = np.asarray(depth, dtype=np.float32)
        z = np.where(np.isfinite(z) & (z > 0), z, np.float32(np.nan))
        fx, fy, cx, cy = (float(self.K[i, j]) for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))  # Python floats keep float32
        x = ((np.arange(z.shape[1], dtype=np.float32) - cx) / fx)[None, :] * z  # camera axes
        y = ((np.arange(z.shape[0], dtype=np.float32) - cy) / fy)[:, None] * z
        rotation, origin = self.camera_to_world[:3, :3].astype(np.float32), self.camera_to_world[:3, 3].astype(np.float32)
        return np.stack([float(rotation[i, 0]) * x + float(rotation[i, 1]) * y + float(rotation[i, 2]) * z + float(origin[i])
                         for i in range(3)], axis=-1)

    def project(self, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (..., 2) as (u, v) of world points (..., 3), and their depth along the axis."""
        world_to_camera = np.linalg.inv(self.camera_to_world)
        camera = np.asarray(world, dtype=float) @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
        z = camera[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.K[0, 0] * camera[..., 0] / z + self.K[0, 2]
            v = self.K[1, 1] * camera[..., 1] / z + self.K[1, 2]
        return np.stack([u, v], axis=-1), z


MAX_DEPTH = 10.0  # metres: anything farther is not a bin in front of a robot


def depth_problem(depth: np.ndarray) -> str | None:
    """What is wrong with a depth image in metres, or None: no valid reading, or a median beyond
    MAX_DEPTH (millimetres given as metres). Files and ROS frames are checked alike."""
    valid = depth[np.isfinite(depth) & (depth > 0)]
    if valid.size == 0:
        return "has no valid reading (all zero or not finite)"
    if float(np.median(valid)) > MAX_DEPTH:
        return f"reads {float(np.median(valid)):.0f} m at its median"
    return None


def depth_millimetres(depth: np.ndarray) -> np.ndarray:
    """Metres -> 16-bit whole millimetres (0: no reading), the ROS / RealSense convention."""
    depth = np.nan_to_num(np.asarray(depth, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(np.round(depth * 1000.0), 0, 65535).astype(np.uint16)


def millimetres_to_metres(raw: np.ndarray) -> np.ndarray:
    """16-bit millimetres -> metres (float32), exactly as :func:`read_depth` reads a PNG."""
    return np.asarray(raw).astype(np.float32) / 1000.0


def as_camera_depth(depth: np.ndarray) -> np.ndarray:
    """Depth as a real camera's 16-bit frame holds it: whole millimetres, back in metres."""
    return millimetres_to_metres(depth_millimetres(depth))


def read_depth(path: str | Path) -> np.ndarray:
    """A depth image in metres (float32): a 16-bit PNG in millimetres (the ROS / RealSense convention)
    or a ``.npy`` in metres (read without pickle). Wrong units or empty images are one clear line."""
    from binpick.errors import InputFileError
    from binpick.files import require_file

    path = require_file(Path(path), "depth image")
    if path.suffix.lower() == ".npy":
        try:
            loaded = np.load(path, allow_pickle=False)  # object arrays (pickles) are refused here
            if not isinstance(loaded, np.ndarray) or not np.issubdtype(loaded.dtype, np.number):
                raise ValueError("not a single numeric array")
            depth = loaded.astype(np.float32)
        except (ValueError, OSError) as error:
            raise InputFileError(f"depth image {str(path)!r} is not a numeric .npy array ({str(error)[:80]})") from None
    else:
        from PIL import Image, UnidentifiedImageError

        try:
            with Image.open(path) as image:
                raw = np.array(image)
        except (UnidentifiedImageError, OSError) as error:
            raise InputFileError(f"depth image {str(path)!r} cannot be read ({str(error)[:80]})") from None
        if raw.dtype not in (np.uint16, np.int32, np.uint32) or raw.ndim != 2:
            raise InputFileError(f"depth image {str(path)!r} must be a single-channel 16-bit PNG in millimetres "
                                 f"(got {raw.dtype} with shape {raw.shape})")
        depth = millimetres_to_metres(raw)
    if depth.ndim != 2:
        raise InputFileError(f"depth image {str(path)!r} must be 2-D (height x width), got shape {depth.shape}")
    problem = depth_problem(depth)
    if problem is not None:
        hint = "" if "no valid reading" in problem else ": give metres in .npy or millimetres in a 16-bit PNG"
        raise InputFileError(f"depth image {str(path)!r} {problem}{hint}")
    return depth

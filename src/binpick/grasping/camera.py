"""A calibrated pinhole camera: intrinsics as ROS's ``camera_info`` has them (K, width, height) and the
camera's pose in the world (or the robot's base) frame, OpenCV axes (x right, y down, z forward).

Grasp planning works in the world frame from depth alone, so it needs nothing else from a simulator:
a real camera's calibration gives exactly these numbers.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import numpy as np

from binpick.core.errors import ConfigError


MAX_SIDE = 16384  # pixels: the largest image side a calibration may describe
FIELD_OF_VIEW = (2.0, 170.0)  # degrees: a lens outside this is no camera binpick plans with
MAX_TRANSLATION = 100.0  # metres between the camera and the frame it is calibrated in
ROTATION_TOLERANCE = 0.02  # R^T R within this of I: a hand-eye matrix printed to 2 decimals passes, a scaled one not


MAX_SKEW = 0.05  # |s| / fx: real sensors' pixel axes are at right angles (a calibrated skew is 0 or nearly)


def check_intrinsics(K: np.ndarray, width: int, height: int) -> None:
    """A pinhole K a real camera can have: finite, the last row 0 0 1, focal lengths that give a field
    of view within ``FIELD_OF_VIEW`` and a principal point on the image. A calibration outside these
    (a focal length of 1e-6 puts a grasp 10^10 m away) is one line naming the number."""
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or np.abs(K).max() > 1e9:
        raise ConfigError(f"camera intrinsics K must be a finite 3x3 matrix, got {np.round(K, 6).tolist()}")
    if not np.allclose(K[2], [0.0, 0.0, 1.0], atol=1e-9) or abs(K[1, 0]) > 1e-9:
        raise ConfigError(f"camera intrinsics K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {np.round(K, 6).tolist()}")
    for name, focal, side in (("fx", K[0, 0], width), ("fy", K[1, 1], height)):
        low, high = (side / (2 * np.tan(np.radians(angle / 2))) for angle in FIELD_OF_VIEW[::-1])
        if not low <= focal <= high:
            raise ConfigError(f"camera focal length {name} = {focal:g} px gives no real lens's field of view over "
                              f"{side} px (expected {low:.3g} to {high:.3g} px)")
    if not (0 <= K[0, 2] <= width and 0 <= K[1, 2] <= height):
        raise ConfigError(f"camera principal point ({K[0, 2]:g}, {K[1, 2]:g}) lies outside the {width}x{height} image")
    if abs(K[0, 1]) > MAX_SKEW * K[0, 0]:  # pixels whose axes are not at right angles: no camera made today
        raise ConfigError(f"camera skew s = {K[0, 1]:g} px is more than {MAX_SKEW:g} of fx = {K[0, 0]:g} px (calibrations "
                          "give 0 or nearly: is the matrix row-major, [[fx, s, cx], [0, fy, cy], [0, 0, 1]]?)")


def check_rigid(pose: np.ndarray, name: str) -> None:
    """A rigid transform: a rotation (orthonormal, determinant +1), a finite translation within
    ``MAX_TRANSLATION``, the last row 0 0 0 1. A scaled, sheared, mirrored or projective matrix is
    one line."""
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)) or np.abs(pose).max() > 1e9:
        raise ConfigError(f"{name} must be a finite 4x4 transform")
    rotation = pose[:3, :3]
    if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise ConfigError(f"{name} must end in the row 0 0 0 1, got {np.round(pose[3], 6).tolist()}")
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=ROTATION_TOLERANCE) or np.linalg.det(rotation) < 0:
        raise ConfigError(f"{name}'s rotation is not a rotation (scaled, sheared or mirrored: determinant "
                          f"{np.linalg.det(rotation):.4g})")
    if np.linalg.norm(pose[:3, 3]) > MAX_TRANSLATION:
        raise ConfigError(f"{name} puts the camera {np.linalg.norm(pose[:3, 3]):.3g} m away (at most {MAX_TRANSLATION:g} m)")


def nearest_rigid(pose: np.ndarray) -> np.ndarray:
    """``pose`` with its rotation made exactly orthonormal (SVD; unchanged when it already is): a
    calibration printed with few decimals plans as the rotation it stands for."""
    rotation = pose[:3, :3]
    if np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-9):
        return pose
    u, _, vt = np.linalg.svd(rotation)
    fixed = pose.copy()
    fixed[:3, :3] = u @ vt
    return fixed


@dataclass(frozen=True)
class PinholeCamera:
    K: np.ndarray  # (3, 3) intrinsics in pixels
    width: int
    height: int
    camera_to_world: np.ndarray = field(default_factory=lambda: np.eye(4))  # (4, 4), OpenCV camera axes

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        pose = np.asarray(self.camera_to_world, dtype=float)
        for side in (self.width, self.height):
            if isinstance(side, bool) or not isinstance(side, numbers.Real) or not 1 <= side <= MAX_SIDE or side != int(side):
                raise ConfigError(f"camera width and height must be whole numbers of pixels from 1 to {MAX_SIDE}, "
                                  f"got {self.width} x {self.height}")
        with np.errstate(over="ignore", invalid="ignore"):  # a hostile number is reported, not warned about
            check_intrinsics(K, int(self.width), int(self.height))
            check_rigid(pose, "camera_to_world")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "camera_to_world", nearest_rigid(pose))

    @classmethod
    def from_record(cls, record: dict) -> PinholeCamera:
        """From a scene's ``camera`` record (binpick's scene JSON and COCO image entries)."""
        try:
            return cls(np.array(record["K"]), int(record["width"]), int(record["height"]),
                       np.array(record.get("camera_to_world", np.eye(4))))
        except KeyError as missing:
            raise ConfigError(f"camera record has no {missing.args[0]!r} field") from None
        except ConfigError:
            raise
        except (TypeError, ValueError) as error:
            raise ConfigError(f"camera record is malformed: {str(error)[:100]}") from None

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

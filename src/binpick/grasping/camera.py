"""A calibrated pinhole camera: intrinsics as ROS's ``camera_info`` has them (K, width, height) and the
camera's pose in the world (or the robot's base) frame, OpenCV axes (x right, y down, z forward).

Grasp planning works in the world frame from depth alone, so it needs nothing else from a simulator:
a real camera's calibration gives exactly these numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

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

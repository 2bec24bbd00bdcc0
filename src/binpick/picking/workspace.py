"""Where binpick may send the gripper: a box in the robot's base frame. Every grasp pose a planner
emits is checked against it, so that no calibration, depth reading or model error can hand a robot a
pose outside its cell (a pose outside is rejected with its reason, never emitted).

The box comes from, in order: the ``Picker``'s ``workspace`` setting, the ``workspace`` of
``camera.yaml`` (``{min: [x, y, z], max: [x, y, z]}``, metres in the base frame; the ROS nodes take
it from their ``--camera``), or the camera's view between ``NEAR`` and ``FAR`` metres in front of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from binpick.core.errors import ConfigError

NEAR, FAR = 0.05, 6.0  # metres along the optical axis: the default workspace is the view between them
MAX_EXTENT = 20.0  # metres: no robot cell is larger

OUTSIDE = "outside the workspace"


@dataclass(frozen=True)
class Workspace:
    """An axis-aligned box in the base frame, ``low`` to ``high`` (metres)."""

    low: tuple[float, float, float]
    high: tuple[float, float, float]

    def __post_init__(self) -> None:
        low, high = (tuple(float(v) for v in corner) for corner in (self.low, self.high))
        if len(low) != 3 or len(high) != 3 or not all(math.isfinite(v) for v in low + high):
            raise ConfigError(f"workspace min and max must be 3 finite numbers each, got {list(self.low)} and {list(self.high)}")
        if any(a >= b for a, b in zip(low, high)):
            raise ConfigError(f"workspace min {list(low)} must lie below max {list(high)} on every axis")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    def contains(self, point) -> bool:
        """Whether ``point`` (x, y, z) is finite and inside the box."""
        values = [float(v) for v in point]
        return len(values) == 3 and all(math.isfinite(v) and a <= v <= b for v, a, b in zip(values, self.low, self.high))

    @classmethod
    def from_mapping(cls, data: Any) -> Workspace:
        """From ``{min: [x, y, z], max: [x, y, z]}`` (camera.yaml's ``workspace``)."""
        if not isinstance(data, dict) or set(data) != {"min", "max"}:
            raise ConfigError("workspace must be a mapping with min: [x, y, z] and max: [x, y, z] (metres, base frame)")
        try:
            workspace = cls(tuple(data["min"]), tuple(data["max"]))
        except (TypeError, ValueError) as error:
            if isinstance(error, ConfigError):
                raise
            raise ConfigError(f"workspace min and max must be lists of 3 numbers, got {str(data)[:80]}") from None
        if any(b - a > MAX_EXTENT for a, b in zip(workspace.low, workspace.high)):
            raise ConfigError(f"workspace spans more than {MAX_EXTENT:g} m on an axis: no robot cell is that large")
        return workspace

    def to_mapping(self) -> dict[str, list[float]]:
        return {"min": list(self.low), "max": list(self.high)}

    @classmethod
    def around_view(cls, camera, near: float = NEAR, far: float = FAR) -> Workspace:
        """The box around what ``camera`` (a ``PinholeCamera``) sees between ``near`` and ``far`` metres."""
        corners = np.array([[0, 0], [camera.width, 0], [0, camera.height], [camera.width, camera.height]], dtype=float)
        rays = np.column_stack([(corners[:, 0] - camera.K[0, 2]) / camera.K[0, 0],
                                (corners[:, 1] - camera.K[1, 2]) / camera.K[1, 1], np.ones(4)])
        points = np.vstack([rays * near, rays * far]) @ camera.camera_to_world[:3, :3].T + camera.camera_to_world[:3, 3]
        return cls(tuple(points.min(axis=0)), tuple(points.max(axis=0) + 1e-9))

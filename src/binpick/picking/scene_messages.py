"""What a pick node shows beside its answer, whatever the ROS version: the camera's pose and each
planned grasp as tf frames, and RViz markers of the grasps (an arrow down the approach, the two
fingers at the grasp's width or the cup's disc, the rank, tool and score as text). The ROS 1 and ROS 2
nodes turn these into their own ``tf2_msgs``/``visualization_msgs`` messages.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from binpick.picking.camera_info import matrix_to_quaternion, quaternion_to_matrix

MARKER_TYPES = {"arrow": 0, "cube": 1, "cylinder": 3, "text": 9}  # visualization_msgs/Marker's codes (ROS 1 and 2 alike)
ARROW_LENGTH = 0.10  # m above the grasp point, along the approach
FINGER = (0.01, 0.02, 0.045)  # thickness (across the jaws), width, length (m): drawn, not simulated
CUP_RADIUS, CUP_HEIGHT = 0.015, 0.006


@dataclass(frozen=True)
class FramePose:
    """A transform ``parent`` -> ``child``: ``translation`` (m) and ``rotation`` (x, y, z, w)."""

    parent: str
    child: str
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]


@dataclass(frozen=True)
class MarkerSpec:
    """One ``visualization_msgs/Marker`` in the base frame (``kind``: a key of :data:`MARKER_TYPES`)."""

    marker_id: int
    kind: str
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]
    scale: tuple[float, float, float]
    colour: tuple[float, float, float, float]
    text: str = ""
    namespace: str = "binpick_grasps"

    @property
    def type_code(self) -> int:
        return MARKER_TYPES[self.kind]


def _floats(values, count: int) -> tuple:
    return tuple(float(v) for v in list(values)[:count])


def camera_frame_pose(camera_to_base: np.ndarray, base_frame: str, camera_frame: str) -> FramePose:
    """The camera's optical frame in the base frame (what hand-eye calibration gave): a static transform."""
    pose = np.asarray(camera_to_base, dtype=float)
    return FramePose(base_frame, camera_frame, _floats(pose[:3, 3], 3), _floats(matrix_to_quaternion(pose[:3, :3]), 4))


def grasp_frame_poses(grasps, base_frame: str, prefix: str = "binpick_grasp") -> list[FramePose]:
    """One frame per planned grasp, best first (``binpick_grasp_1``, ...): the tool point, z down the approach."""
    return [FramePose(base_frame, f"{prefix}_{rank}", _floats(plan.position, 3), _floats(plan.orientation, 4))
            for rank, plan in enumerate(grasps, start=1)]


def _colour(plan) -> tuple[float, float, float, float]:
    """Red to green with the predicted chance of holding (the detector's score where there is none)."""
    value = plan.quality if plan.quality is not None else plan.score
    value = float(np.clip(value if value is not None and np.isfinite(value) else 0.0, 0.0, 1.0))
    return (1.0 - value, value, 0.2, 0.9)


def grasp_markers(grasps, opening: float) -> list[MarkerSpec]:
    """Markers of each planned grasp, best first: ids ``4 * (rank - 1) + k``, so a later answer replaces them."""
    markers: list[MarkerSpec] = []
    for rank, plan in enumerate(grasps, start=1):
        base = 4 * (rank - 1)
        rotation = quaternion_to_matrix(plan.orientation)
        point = np.asarray(plan.position, dtype=float)
        approach, across = rotation[:, 2], rotation[:, 0]
        colour = _colour(plan)
        # an arrow's shaft runs along its own x: from ARROW_LENGTH above the grasp down to it
        side = np.cross(approach, [1.0, 0.0, 0.0] if abs(approach[0]) < 0.9 else [0.0, 1.0, 0.0])
        side /= np.linalg.norm(side)
        arrow = matrix_to_quaternion(np.stack([approach, side, np.cross(approach, side)], axis=1))
        markers.append(MarkerSpec(base, "arrow", _floats(point - ARROW_LENGTH * approach, 3), _floats(arrow, 4),
                                  (ARROW_LENGTH, 0.008, 0.012), colour))
        if plan.tool == "suction":
            markers.append(MarkerSpec(base + 1, "cylinder", _floats(point - 0.5 * CUP_HEIGHT * approach, 3), _floats(plan.orientation, 4),
                                      (2 * CUP_RADIUS, 2 * CUP_RADIUS, CUP_HEIGHT), colour))
        else:
            half = 0.5 * float(plan.width if plan.width is not None and np.isfinite(plan.width) else opening) + 0.5 * FINGER[0]
            for k, sign in ((1, -1.0), (2, 1.0)):
                centre = point + sign * half * across - 0.5 * FINGER[2] * approach  # the tips at the grasp's depth
                markers.append(MarkerSpec(base + k, "cube", _floats(centre, 3), _floats(plan.orientation, 4), FINGER, colour))
        score = plan.quality if plan.quality is not None else plan.score
        label = f"{rank} {plan.tool or 'jaws'} {float(score):.2f}" if score is not None else f"{rank} {plan.tool or 'jaws'}"
        markers.append(MarkerSpec(base + 3, "text", _floats(point - (ARROW_LENGTH + 0.02) * approach, 3), (0.0, 0.0, 0.0, 1.0),
                                  (0.0, 0.0, 0.02), (1.0, 1.0, 1.0, 1.0), label))
    return markers

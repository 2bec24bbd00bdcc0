"""What the planner answers: grasp plans in the robot's base frame, best first, with the reasons
the other candidates were rejected."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from binpick.grasping import PinholeCamera
from binpick.picking.camera_info import matrix_to_quaternion

APPROACH = (0.0, 0.0, -1.0)  # top-down: the gripper moves along the base frame's -z (z up)
LARGER = "larger than the ordered product"


def larger_than(surface, size, margin: float = 0.02, relative: float = 0.15) -> bool:
    """Whether what depth shows of an instance is too big to be a product of catalogue ``size`` (its
    bounding-box sides, any order): the visible top's long side against the product's longest,
    its short side against the middle one, its height against the longest. Occlusion only shrinks
    what is seen, so only too big counts (its margins: docs/notes.md, "Tuning notes")."""
    first, second, _ = sorted((float(v) for v in size), reverse=True)
    major, minor = surface.extents()
    slack = lambda side: max(margin, relative * side)  # noqa: E731
    return major > first + slack(first) or minor > second + slack(second) or surface.height > first + slack(first)


def grasp_orientation(yaw: float) -> list[float]:
    """The gripper frame's quaternion (x, y, z, w) in the base frame: z along the approach (down),
    x along the jaws' closing direction (``yaw`` about the base's z), y = z x x."""
    x_axis = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    z_axis = np.array(APPROACH)
    return matrix_to_quaternion(np.stack([x_axis, np.cross(z_axis, x_axis), z_axis], axis=1))


@dataclass
class GraspPlan:
    """One detection of the ordered product and the grasp chosen for it (``position`` None: no
    candidate was feasible; ``rejected`` says why, reason -> candidates)."""

    box: list[float]  # x, y, w, h pixels in the (rectified) colour image
    score: float  # the detector's
    same_product: float | None  # the product check's: P(the ordered product) from photos, colour similarity to a query box; None: not checked
    position: list[float] | None = None  # the tool's point, base frame (m): the fingertips' midpoint, or the cup's lip on the surface
    orientation: list[float] | None = None  # gripper frame, quaternion x, y, z, w in the base frame
    approach: list[float] = field(default_factory=lambda: list(APPROACH))
    yaw: float | None = None  # the jaws' closing direction (the hand's x axis) about the base's z (rad)
    width: float | None = None  # the instance's width across the jaws (m; None for suction)
    opening: float | None = None  # how far to open the jaws before descending (m; None for suction)
    quality: float | None = None  # the grasp policy's score of the chosen candidate (a success probability but for the analytic jaws)
    rejected: dict[str, int] = field(default_factory=dict)
    tool: str | None = None  # the tool the grasp is for: jaws or suction (None: no grasp)
    narrowest: float | None = None  # the instance's narrowest width across the jaws over every candidate (m; None: no jaw candidate)
    push: dict | None = None  # where no grasp fits well: a push that gives the fingers room (start, end: the closed fingertips, base frame; yaw)

    @property
    def feasible(self) -> bool:
        return self.position is not None


class Plans(list):
    """``list[GraspPlan]`` in the order to try them, with what the frame gave: ``grasps`` (the
    feasible ones), ``boxes``/``scores`` of every detection above the score threshold, ``frame``
    (the base frame's name) and ``timing_ms``."""

    def __init__(self, plans: list[GraspPlan], frame: str, timing_ms: dict[str, float], boxes: np.ndarray | None = None,
                 scores: np.ndarray | None = None, not_the_product: int = 0) -> None:
        super().__init__(plans)
        self.frame, self.timing_ms = frame, timing_ms
        self.not_the_product = not_the_product  # detections the product check dropped
        self.boxes = np.zeros((0, 4)) if boxes is None else np.asarray(boxes, dtype=float).reshape(-1, 4)  # every detection
        self.scores = np.zeros(0) if scores is None else np.asarray(scores, dtype=float)

    @property
    def detections(self) -> int:
        return len(self.boxes)

    @property
    def grasps(self) -> list[GraspPlan]:
        return [p for p in self if p.feasible]

    def to_json(self) -> dict[str, Any]:
        return {"frame": self.frame, "detections": self.detections, "not_the_product": self.not_the_product, "timing_ms": self.timing_ms,
                "grasps": len(self.grasps), "plans": [asdict(p) for p in self]}

    def plot(self, rgb: np.ndarray, camera: PinholeCamera, opening: float, photo=None,
             query_box=None) -> np.ndarray:
        """The frame with each detection's box and score, and each grasp's open jaws numbered in the
        order to try them (green)."""
        from binpick.picking.inputs import split_photo
        from binpick.viz.detection import draw_jaws, overlay

        boxes = np.array([p.box for p in self], dtype=float).reshape(-1, 4)
        if isinstance(photo, (list, tuple)):  # several photos of the product: the first is shown
            photo = photo[0] if photo else None
        photo = None if photo is None else split_photo(photo)[0]
        picture = overlay(rgb, boxes, np.array([p.score for p in self]), query_box, photo, min_score=0.0,
                          legend=f"{len(self)} planned of {self.detections} detections (orange, detector score); "
                                 f"{len(self.grasps)} grasps (green)")
        jaws = [(*jaw_pixels(camera, plan.position, plan.yaw, opening), True, str(number))
                for number, plan in enumerate(self.grasps, start=1) if plan.tool != "suction"]
        cups = [(*cup_pixels(camera, plan.position), True, str(number))
                for number, plan in enumerate(self.grasps, start=1) if plan.tool == "suction"]
        return draw_cups(draw_jaws(picture, jaws), cups)


def cup_pixels(camera: PinholeCamera, position, radius: float = 0.015) -> tuple[np.ndarray, float]:
    """A suction grasp's cup in the image: the lip's centre (u, v) and its radius in pixels."""
    centre = np.asarray(position, dtype=float)
    (middle, edge), _ = camera.project(np.stack([centre, centre + [radius, 0.0, 0.0]]))
    return middle, float(max(2.0, np.linalg.norm(edge - middle)))


def draw_cups(picture: np.ndarray, cups: list) -> np.ndarray:
    """``picture`` with each suction grasp's lip drawn as a circle and numbered (green: tried first)."""
    from binpick.viz.detection import draw_cups as draw

    return draw(picture, cups)


def jaw_pixels(camera: PinholeCamera, position, yaw: float, opening: float) -> tuple[np.ndarray, np.ndarray]:
    """The open fingers' pixels (u, v) of a grasp at ``position`` closing along ``yaw``: its jaw line."""
    centre = np.asarray(position, dtype=float)
    reach = np.array([np.cos(yaw), np.sin(yaw), 0.0]) * opening / 2
    (a, b), _ = camera.project(np.stack([centre - reach, centre + reach]))
    return a, b

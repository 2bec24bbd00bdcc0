"""The tote in one depth frame: its floor, the rim of its walls and the rectangle inside them, in the
robot's base frame, so that a cell's workspace is measured rather than typed.

The support plane the planner fits (:class:`binpick.grasping.DepthFrame`) is the tote's floor. The
walls stand out of it by more than ``wall_above``; everything the camera sees inside them that is
lower (the floor, the products lying on it, the walls' inner faces below that height) is one region
of the image, bounded by the walls' tops, and that region is found from the floor's visible pixels.
With the walls' pixels next to it (their inner edges: a tilted camera sees the near wall's top, not
its face), its points' minimum-area rectangle, each side at its 21st outermost point (the 20 beyond it,
flying pixels and noise at the walls' edges, left out), is the tote's inner rectangle. The camera's pose is
checked first (:mod:`binpick.picking.pose_check`; a tote lower than the base is what this measures,
so only the view and the floor's level): a workspace measured with a wrong pose would surround the
wrong place.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from binpick.core.errors import InputFileError
from binpick.picking.pose_check import check_camera_pose
from binpick.picking.workspace import Workspace

WALL_ABOVE = 0.06  # m: a tote's walls stand at least this far above its floor (products may be taller: they are inside)
ON_FLOOR = 0.01  # m: a pixel this close to the support plane is floor
EDGE_SHARE = 0.05  # the inside touching more than this share of an image edge: the tote runs out of view there
OUTLIERS = 20  # points left out on each side of the rectangle (noise, flying pixels); not a share: a side seen as a thin line counts
TOP_BAND = 0.01  # m: a wall's top is the walls' pixels within this of their highest (the 95th percentile)
NEAR_SIDE = 0.04  # m: a wall's top lies within this of the side found from the inside
CORNER = 0.03  # m: a wall's top is taken this far from the corners (the other walls' tops meet it there)
EDGE_OUTLIERS = 5  # readings left out at a wall top's inner edge (noise)
MIN_TOP_POINTS = 30  # readings of a wall's top needed to move a side to its inner edge
ABOVE_FLOOR = 0.45  # m: the workspace reaches this high above the floor (grasps, and the hand over the walls)


@dataclass(frozen=True)
class Tote:
    """A tote's inner rectangle in the base frame: ``centre`` (x, y), ``size`` (along its own axes, m),
    ``yaw`` (its first axis from the base's x, radians), the floor's height under its centre and the
    walls' height above the floor (their tops: the 95th percentile of the walls' readings)."""

    centre: tuple[float, float]
    size: tuple[float, float]
    yaw: float
    floor_z: float
    wall_height: float

    def corners(self) -> np.ndarray:
        """The rectangle's four corners (x, y), in order round it."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        axes = np.array([[c, s], [-s, c]])
        half = np.array(self.size) / 2
        return np.array(self.centre) + np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half @ axes

    def workspace(self, above: float = ABOVE_FLOOR) -> Workspace:
        """The axis-aligned box round the rectangle, from just under the floor to ``above`` over it."""
        corners = self.corners()
        return Workspace((*corners.min(axis=0), self.floor_z - 0.02), (*corners.max(axis=0), self.floor_z + above))

    def to_mapping(self) -> dict:
        return {"centre": [round(v, 4) for v in self.centre], "size": [round(v, 4) for v in self.size],
                "yaw_degrees": round(float(np.degrees(self.yaw)), 2), "floor_z": round(self.floor_z, 4),
                "wall_height": round(self.wall_height, 4)}


def find_tote(frame, wall_above: float = WALL_ABOVE) -> Tote:
    """The tote ``frame`` (a :class:`binpick.grasping.DepthFrame` with its camera's pose) looks into;
    one line when it shows none (no floor found, or no walls round it)."""
    import cv2

    if frame.plane is None:
        raise InputFileError("no tote floor in this depth frame: no level surface holds enough of the readings "
                             "(a camera aimed at the tote sees its floor between the products)")
    heights = np.where(np.isfinite(frame.heights), frame.heights, np.inf)
    walls = heights > wall_above
    if walls.mean() < 0.01:
        raise InputFileError(f"no tote walls in this depth frame: nothing stands {wall_above * 100:g} cm above the floor "
                             "round it (a tote with lower walls: --wall-above)")
    count, labels = cv2.connectedComponents((~walls).astype(np.uint8), connectivity=4)
    floor = (np.abs(heights) < ON_FLOOR) & frame.valid
    votes = np.bincount(labels[floor], minlength=count)
    votes[0] = 0  # the walls' own label
    border = np.unique(np.concatenate([labels[0, :], labels[-1, :], labels[:, 0], labels[:, -1]]))
    enclosed = votes.copy()
    enclosed[border] = 0  # the table round the tote reaches the image's edges; the tote's inside does not
    inside = labels == int(np.argmax(enclosed if enclosed.any() else votes))
    edges = {"top": inside[0, :], "bottom": inside[-1, :], "left": inside[:, 0], "right": inside[:, -1]}
    cut = [name for name, edge in edges.items() if edge.mean() > EDGE_SHARE]
    if cut:
        raise InputFileError(f"the tote is not wholly in view: its floor reaches the image's {' and '.join(cut)} edge "
                             f"(aim the camera so that the whole tote, walls included, is in view)")
    # the walls' pixels next to the inside: their inner faces' tops, where a near wall hides its own face and
    # the floor beside it from a tilted camera
    rim = walls & (cv2.dilate(inside.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    points = frame.points[(inside | rim) & frame.valid][:, :2].astype(np.float32)
    points = points[np.isfinite(points).all(axis=1)]
    (cx, cy), _, angle = cv2.minAreaRect(points)
    yaw = float(np.radians(angle))
    c, s = np.cos(yaw), np.sin(yaw)
    local = (points - [cx, cy]) @ np.array([[c, -s], [s, c]])  # the points along the rectangle's own axes
    ordered = np.sort(local, axis=0)  # each side at its OUTLIERS-th outermost point: a near wall's edge is a thin line
    low, high = ordered[min(OUTLIERS, len(ordered) - 1)], ordered[max(len(ordered) - 1 - OUTLIERS, 0)]
    # a wall whose face the camera cannot see (the near one, tilted camera) and beside which the sensor reads no
    # floor (a projector's shadow) leaves the inside short of it: its top's inner edge says where its face is
    near_inside = walls & frame.valid & np.isfinite(heights) & (cv2.dilate(inside.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0)
    if not near_inside.any():
        raise InputFileError("no tote walls round the floor in this depth frame: nothing stands out of the floor next to it")
    wall_height = float(np.percentile(heights[near_inside], 95))  # the tops of the walls round the inside (their faces are
    # lower: a low camera sees much of them; what stands elsewhere, the arm or a shelf, is not a wall)
    tops = frame.points[walls & frame.valid & (np.abs(heights - wall_height) < TOP_BAND)][:, :2]
    tops = (tops[np.isfinite(tops).all(axis=1)] - [cx, cy]) @ np.array([[c, -s], [s, c]])
    for axis in (0, 1):
        other = 1 - axis
        along = (tops[:, other] > low[other] + CORNER) & (tops[:, other] < high[other] - CORNER)  # off the corners
        for side, sign in ((low, -1.0), (high, 1.0)):
            near = tops[along & (np.abs(tops[:, axis] - side[axis]) < NEAR_SIDE), axis]
            if len(near) >= MIN_TOP_POINTS:  # the wall top's inner edge: its few innermost readings left out
                near = np.sort(near)
                edge = near[EDGE_OUTLIERS] if sign > 0 else near[-1 - EDGE_OUTLIERS]
                side[axis] = max(side[axis], edge) if sign > 0 else min(side[axis], edge)
    middle = (low + high) / 2
    centre = np.array([cx, cy]) + middle @ np.array([[c, s], [-s, c]])
    size = high - low
    if size[0] < size[1]:  # the first axis along the long side, its yaw within a half turn
        size, yaw = size[::-1], yaw + np.pi / 2
    yaw = float((yaw + np.pi / 2) % np.pi - np.pi / 2)
    a, b, c0 = (float(v) for v in frame.plane)
    return Tote((float(centre[0]), float(centre[1])), (float(size[0]), float(size[1])), yaw,
                a * float(centre[0]) + b * float(centre[1]) + c0, wall_height)


def tote_in_frame(rgb: np.ndarray, depth: np.ndarray, info, wall_above: float = WALL_ABOVE) -> Tote:
    """:func:`find_tote` on one frame as the planner reads it (depth registered to the colour,
    rectified, at the planner's working size): ``info`` is its :class:`CameraInfo`."""
    from binpick.grasping import DepthFrame
    from binpick.picking.inputs import working_frame

    _, depth, info, _ = working_frame(rgb, depth, info)
    frame = DepthFrame.from_depth(depth, info.camera)
    check_camera_pose(frame, heights=False)  # a tote measured with a wrong pose would put the workspace round the wrong place
    return find_tote(frame, wall_above)

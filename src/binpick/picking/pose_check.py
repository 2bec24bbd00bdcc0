"""The camera's pose checked against what its own depth shows, before any grasp is planned with it.

A wrong ``camera_to_base`` does not fail by itself: every grasp comes out in the wrong place (a
quaternion written w, x, y, z puts them tens of centimetres off, mirrored, below the table), or
none comes out ("finger blocked" everywhere when the pose is missing and the camera's own frame is
taken for the base). The support plane the planner fits to the depth is what a right pose puts
under the products, so three things are checked against it, each one line naming the fix:

- the camera looks down (its optical axis points below the horizon of the base frame);
- the plane is near level in the base frame (within :data:`MAX_SUPPORT_TILT`, where it holds a good
  share of the readings; the dominant plane at any tilt where the planner found none): binpick grasps along
  the base's -z, so it expects a tote on a level table, and a rotation read in the wrong order turns
  a tilted camera's level floor into a steep one (the sample frame's camera, tilted about 10 degrees:
  3 degrees with its quaternion read right, 20 read w-first);
- the plane lies where the cell's floor can be: inside the workspace's heights when the camera
  file gives one, else not below the robot base's floor (z = 0) by more than :data:`BELOW_BASE`.
"""

from __future__ import annotations

import numpy as np

from binpick.core.errors import InputFileError

MAX_SUPPORT_TILT = 12.0  # degrees from level, in the base frame
DOMINANT = 0.2  # the share of the depth's readings on a plane for its tilt to refuse the pose
ON_PLANE = 0.006  # m: a reading this close to a plane lies on it
SAMPLES = 4000  # readings the check looks at (every few pixels): the plane's tilt does not need them all
BELOW_BASE = 0.05  # m: a support plane this far below the base frame's z = 0 is no plane a base-mounted arm picks from
WORKSPACE_MARGIN = 0.05  # m: the plane may lie this far below the workspace's lowest point (a tote's floor under its box)
HINT = "check camera_to_base (translation in metres, rotation as a quaternion x, y, z, w: a w-first one does this)"


def check_camera_pose(frame, workspace=None, heights: bool = True) -> None:
    """Raise :class:`InputFileError` (one line) when ``frame``'s camera pose cannot be right for the
    surface its depth shows (``frame``: a :class:`binpick.grasping.DepthFrame`). The tilt is judged only
    where that surface holds a good share of the readings (:data:`DOMINANT`): a bin filled to the
    top, whose lowest broad plane may be a product's leaning top, is not refused for it. Where the
    planner found no near-level plane, the dominant plane at any tilt is looked for (a misread
    rotation can tilt the floor past what the planner fits). ``workspace``: the cell's box from the
    camera file, if it has one; ``heights`` False: the view and the floor's level only (``binpick cell``
    measures where the floor is)."""
    pose = np.asarray(frame.camera.camera_to_world, dtype=float)
    axis = pose[:3, 2]
    if axis[2] >= 0.0:
        raise InputFileError(f"camera_to_base points the camera's optical axis up or level (its z component {axis[2]:+.2f} "
                             f"in the base frame), not down at the tote: {HINT}")
    step = max(1, int(np.sqrt(frame.valid.size / SAMPLES)))  # a few thousand readings tell the plane's tilt
    points = frame.points[::step, ::step][frame.valid[::step, ::step]].astype(np.float64)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) < 50:
        return
    if frame.plane is not None:
        a, b, c = (float(v) for v in frame.plane)
        normal = np.array([-a, -b, 1.0]) / np.sqrt(a * a + b * b + 1.0)
        share = float(np.mean(np.abs((points - [0.0, 0.0, c]) @ normal) < ON_PLANE))
    else:
        normal, share = dominant_plane(points)
        if normal is None:
            return
    tilt = float(np.degrees(np.arccos(min(1.0, abs(float(normal[2]))))))
    if tilt > MAX_SUPPORT_TILT and share >= DOMINANT:
        raise InputFileError(f"camera_to_base tilts the surface under the products {tilt:.0f} degrees from level in the "
                             f"base frame ({share:.0%} of the depth lies on it; at most {MAX_SUPPORT_TILT:g} expected: binpick "
                             f"grasps from above, a tote on a level table): {HINT}")
    if frame.plane is None or not heights:
        return
    x, y = np.median(points[:, 0]), np.median(points[:, 1])
    height = a * x + b * y + c  # the plane under what the camera sees
    if workspace is not None:
        low, high = workspace.low[2] - WORKSPACE_MARGIN, workspace.high[2]
        if not low <= height <= high:
            raise InputFileError(f"camera_to_base puts the support plane at z = {height:.3f} m, outside the workspace's "
                                 f"heights {workspace.low[2]:g} to {workspace.high[2]:g} m (5 cm under them allowed): {HINT}")
    elif height < -BELOW_BASE:
        raise InputFileError(f"camera_to_base puts the support plane at z = {height:.3f} m, below the robot base's floor "
                             f"(z = 0): {HINT}; a tote lower than the base is declared by a workspace in the camera file")


def dominant_plane(points: np.ndarray, iterations: int = 200, seed: int = 0) -> tuple[np.ndarray | None, float]:
    """The unit normal (z up) of the plane through the most ``points`` at any tilt, and the share of
    them on it (RANSAC, then a least-squares refit on its points); (None, 0) when none holds any."""
    rng = np.random.default_rng(seed)
    triples = points[rng.integers(0, len(points), size=(iterations, 3))]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    lengths = np.linalg.norm(normals, axis=1)
    usable = lengths > 1e-12
    if not usable.any():
        return None, 0.0
    normals, triples = normals[usable] / lengths[usable, None], triples[usable]
    counts = (np.abs(np.einsum("pk,nk->pn", points, normals) - np.einsum("nk,nk->n", triples[:, 0], normals)) < ON_PLANE).sum(axis=0)
    best = int(np.argmax(counts))
    on = np.abs((points - triples[best, 0]) @ normals[best]) < ON_PLANE
    centred = points[on] - points[on].mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]  # the refit plane's normal
    return normal * np.sign(normal[2] + 1e-12), float(on.mean())

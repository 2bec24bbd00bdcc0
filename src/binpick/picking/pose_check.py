"""The camera's pose checked against what its own depth shows, before any grasp is planned with it.

A wrong ``camera_to_base`` does not fail by itself: every grasp comes out in the wrong place (a
quaternion written w, x, y, z puts them tens of centimetres off, mirrored, below the table), or
none comes out ("finger blocked" everywhere when the pose is missing and the camera's own frame is
taken for the base). The support plane the planner fits to the depth is what a right pose puts
under the products, so three things are checked against it, each one line naming the fix:

- the camera looks down (its optical axis points below the horizon of the base frame);
- the plane is near level in the base frame (within :data:`MAX_SUPPORT_TILT`): binpick grasps along
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
BELOW_BASE = 0.05  # m: a support plane this far below the base frame's z = 0 is no plane a base-mounted arm picks from
WORKSPACE_MARGIN = 0.05  # m: the plane may lie this far below the workspace's lowest point (a tote's floor under its box)
HINT = "check camera_to_base (translation in metres, rotation as a quaternion x, y, z, w: a w-first one does this)"


def check_camera_pose(frame, workspace=None) -> None:
    """Raise :class:`InputFileError` (one line) when ``frame``'s camera pose cannot be right for the
    support plane found in its depth (``frame``: a :class:`binpick.grasping.DepthFrame`); nothing to
    check when no plane was found. ``workspace``: the cell's box from the camera file, if it has one."""
    pose = np.asarray(frame.camera.camera_to_world, dtype=float)
    axis = pose[:3, 2]
    if axis[2] >= 0.0:
        raise InputFileError(f"camera_to_base points the camera's optical axis up or level (its z component {axis[2]:+.2f} "
                             f"in the base frame), not down at the tote: {HINT}; a camera file without camera_to_base "
                             "is one too")
    if frame.plane is None:
        return
    a, b, c = (float(v) for v in frame.plane)
    tilt = float(np.degrees(np.arctan(np.hypot(a, b))))
    if tilt > MAX_SUPPORT_TILT:
        raise InputFileError(f"camera_to_base tilts the support plane its depth shows {tilt:.0f} degrees from level in the "
                             f"base frame (at most {MAX_SUPPORT_TILT:g} expected: a tote on a level table): {HINT}")
    seen = frame.points[frame.valid] if frame.valid.any() else frame.points.reshape(-1, 3)
    x, y = np.median(seen[:, 0]), np.median(seen[:, 1])
    height = a * x + b * y + c  # the plane under what the camera sees
    if workspace is not None:
        low, high = workspace.low[2] - WORKSPACE_MARGIN, workspace.high[2]
        if not low <= height <= high:
            raise InputFileError(f"camera_to_base puts the support plane at z = {height:.3f} m, outside the workspace's "
                                 f"heights {workspace.low[2]:g} to {workspace.high[2]:g} m: {HINT}")
    elif height < -BELOW_BASE:
        raise InputFileError(f"camera_to_base puts the support plane at z = {height:.3f} m, below the robot base's floor "
                             f"(z = 0): {HINT}; a tote lower than the base is declared by a workspace in the camera file")

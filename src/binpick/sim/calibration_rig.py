"""A hand-eye calibration rig in the simulator: a ChArUco board and a camera of known pose, the board
on the flange (eye-to-hand) or the camera on it (eye-in-hand), rendered at any flange pose. What
``binpick calibrate`` recovers from its pictures can be checked against the pose it was given.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import mujoco
import numpy as np

from binpick.sim.rendering import renderer

CV_FROM_MUJOCO = np.diag([1.0, -1.0, -1.0])  # a MuJoCo camera looks along its -z with y up; OpenCV's along +z, y down


def _quaternion(R: np.ndarray) -> str:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(R, dtype=float).ravel())
    return " ".join(f"{v:.9f}" for v in q)


def _position(t) -> str:
    return " ".join(f"{v:.9f}" for v in t)


class CalibrationRig:
    """``CalibrationRig(picture, size, mount, camera_pose, board_pose).picture(flange_to_base)`` -> RGB.

    ``picture``: the board as printed (grey or RGB, :meth:`binpick.picking.charuco.Board.picture`),
    ``size``: its printed width and height (m). eye-to-hand: ``camera_pose`` is the camera in the base (OpenCV axes), ``board_pose`` the board on
    the flange. eye-in-hand: ``camera_pose`` is the camera on the flange, ``board_pose`` the board in
    the base. Both 4x4, the board's frame OpenCV's (:mod:`binpick.picking.charuco`)."""

    def __init__(self, picture: np.ndarray, board_size: tuple[float, float], mount: str, camera_pose: np.ndarray,
                 board_pose: np.ndarray, size: tuple[int, int] = (640, 480), fovy: float = 50.0) -> None:
        self.board_size, self.mount, self.size = board_size, mount, size
        self.camera_pose, self.board_pose = np.asarray(camera_pose, dtype=float), np.asarray(board_pose, dtype=float)
        width, height = size
        focal = (height / 2) / np.tan(np.radians(fovy) / 2)
        self.K = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
        with tempfile.TemporaryDirectory() as folder:
            from PIL import Image

            path = Path(folder) / "board.png"
            Image.fromarray(np.asarray(picture, dtype=np.uint8)).convert("RGB").save(path)
            self.model = mujoco.MjModel.from_xml_string(self._xml(path, fovy))
        self.data = mujoco.MjData(self.model)
        self.renderer = renderer(self.model, height, width)

    def _xml(self, picture: Path, fovy: float) -> str:
        w, h = self.board_size
        # the board's printed face: a box whose top (+z) face carries the picture; its frame's z points out of
        # the face, OpenCV's board z into it, and OpenCV's origin is the picture's top-left corner
        board_from_geom = np.eye(4)
        board_from_geom[:3, :3] = np.diag([1.0, -1.0, -1.0])
        board_from_geom[:3, 3] = [w / 2, h / 2, 0.0]
        geom = self.board_pose @ board_from_geom  # the geom's frame in its parent
        camera = self.camera_pose[:3, :3] @ CV_FROM_MUJOCO
        board_geom = (f'<geom type="box" size="{w / 2} {h / 2} 0.002" pos="{_position(geom[:3, 3] - 0.002 * geom[:3, 2])}" '
                      f'quat="{_quaternion(geom[:3, :3])}" material="board"/>')
        camera_xml = (f'<camera name="eye" pos="{_position(self.camera_pose[:3, 3])}" quat="{_quaternion(camera)}" '
                      f'fovy="{fovy}"/>')
        on_flange, in_world = (board_geom, camera_xml) if self.mount == "eye-to-hand" else (camera_xml, board_geom)
        return f"""<mujoco>
  <option gravity="0 0 0"/>
  <visual><global offwidth="{self.size[0]}" offheight="{self.size[1]}"/><headlight ambient="0.7 0.7 0.7" diffuse="0.3 0.3 0.3"/></visual>
  <asset>
    <texture name="board" type="2d" file="{picture}"/>
    <material name="board" texture="board" texrepeat="1 1" texuniform="false" specular="0" shininess="0"/>
  </asset>
  <worldbody>
    {in_world}
    <body name="flange" mocap="true">{on_flange}</body>
  </worldbody>
</mujoco>"""

    def picture(self, flange_to_base: np.ndarray) -> np.ndarray:
        """The camera's RGB image with the flange at ``flange_to_base`` (4x4)."""
        pose = np.asarray(flange_to_base, dtype=float)
        self.data.mocap_pos[0] = pose[:3, 3]
        quaternion = np.zeros(4)
        mujoco.mju_mat2Quat(quaternion, pose[:3, :3].ravel())
        self.data.mocap_quat[0] = quaternion
        mujoco.mj_forward(self.model, self.data)
        self.renderer.update_scene(self.data, camera="eye")
        return self.renderer.render().copy()

    def close(self) -> None:
        self.renderer.close()

"""What every binpick goal-conditioned MuJoCo env shares: an optional camera image observation and
the thesis's episode end at success (§3.1: an episode ends when the goal is reached or after T)."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from binpick.core.config import check_choice
from binpick.sim.camera import IMAGE_MODES, CameraPose, MujocoCamera, check_image_size


def sparse_goal_reward(achieved_goal: Any, desired_goal: Any, tolerance: float) -> np.ndarray:
    """The thesis's sparse reward, vectorised over leading axes: 0 within tolerance, -1 otherwise.

    The same rule the env applies at every step, so HER can recompute rewards for relabelled goals.
    """
    distance = np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1)
    return -(distance > tolerance).astype(np.float64)


class ImageObservationMixin:
    """Adds an ``image`` entry to a dict observation, rendered by dedicated off-screen cameras,
    and draws ``render()`` frames (``render_mode="rgb_array"``) with another, larger camera.

    With several observation views their frames are stacked along the channel axis, (H, W, C·views):
    one view cannot tell how far a small object is along its ray, a second one at an angle can.
    """

    _camera: MujocoCamera | None = None  # the first observation view
    _extra_cameras: tuple[MujocoCamera, ...] = ()
    observation_poses: tuple[CameraPose, ...] = ()
    _view: MujocoCamera | None = None
    view_pose: CameraPose  # set by each env class: where a person looks from

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._view is None:
            self._view = MujocoCamera(self.model, (self.width, self.height), "rgb", self.view_pose)
        self._prepare_frame()
        return self._view.render(self.data)

    def _prepare_frame(self) -> None:
        """Hook: bring visual-only state (e.g. a goal marker) up to date before drawing."""

    def _init_image_observation(self, model, image: str | None, image_size: int,
                                poses: CameraPose | tuple[CameraPose, ...]) -> None:
        self.image_mode = check_choice("image", image, [None, *IMAGE_MODES])
        self.image_size = check_image_size("image_size", image_size)
        self.observation_poses = (poses,) if isinstance(poses, CameraPose) else tuple(poses)
        self._camera, self._extra_cameras = None, ()
        if self.image_mode is None:
            return
        # observations skip multisampling: twice the speed, and a policy does not need smooth edges
        cameras = [MujocoCamera(model, self.image_size, self.image_mode, pose, multisample=False)
                   for pose in self.observation_poses]
        self._camera, self._extra_cameras = cameras[0], tuple(cameras[1:])
        channels = (3 if self.image_mode == "rgb" else 1) * len(cameras)
        image_space = spaces.Box(0, 255, (self.image_size, self.image_size, channels), np.uint8)
        self.observation_space = spaces.Dict({**self.observation_space.spaces, "image": image_space})

    def in_views(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> where each observation view shows them, (N, 2 · views): x, y per view in
        [-1, 1] (x right, y down), in the order the views' frames are stacked."""
        fovy = float(self.model.vis.global_.fovy)
        return np.concatenate([pose.project(points, fovy) for pose in self.observation_poses], axis=-1)

    def _with_image(self, observation: dict[str, Any], data) -> dict[str, Any]:
        if self._camera is not None:
            frames = [camera.render(data) for camera in (self._camera, *self._extra_cameras)]
            observation["image"] = frames[0] if len(frames) == 1 else np.concatenate(frames, axis=-1)
        return observation

    def _close_camera(self) -> None:
        for camera in (self._camera, *self._extra_cameras, self._view):
            if camera is not None:
                camera.close()
        self._camera = self._view = None
        self._extra_cameras = ()

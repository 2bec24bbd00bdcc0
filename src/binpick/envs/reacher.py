"""Goal-conditioned MuJoCo Reacher of thesis §4.5.1 (Fig 4.5), built on Gymnasium's Reacher-v5.

Differences from Reacher-v5, all from the thesis: actions are changes of the two joint angles,
Δα ∈ [-0.1, 0.1] rad, applied kinematically; the observation is a dict with the end point u as
``achieved_goal`` and the target as ``desired_goal``; the reward is sparse (0 within ``tolerance``
of the target, -1 otherwise) and the episode ends on success or after T=50 actions.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import EzPickle

from binpick.core.config import check_range
from binpick.envs.goal_env import ImageObservationMixin, sparse_goal_reward
from binpick.sim.camera import CameraPose, check_image_size, import_mujoco

import_mujoco()  # a missing OpenGL platform becomes one clear error, not an import traceback
from gymnasium.envs.mujoco.reacher_v5 import ReacherEnv  # noqa: E402

MAX_DELTA = 0.1
ELBOW_LIMIT = 3.0  # joint1's range in reacher.xml
TOP_DOWN = CameraPose(lookat=(0.0, 0.0, 0.0), distance=0.78, azimuth=90.0, elevation=-90.0)


class GoalReacherEnv(ImageObservationMixin, ReacherEnv):
    """Move the fingertip of a 2-link arm onto a red target by changing joint angles."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}
    view_pose = TOP_DOWN

    def __init__(
        self,
        tolerance: float = 0.02,
        image: str | None = None,
        image_size: int = 84,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
    ) -> None:
        self.tolerance = float(check_range("tolerance", tolerance, 0.0, 0.2, low_inclusive=False))
        check_image_size("width", width)
        check_image_size("height", height)
        ReacherEnv.__init__(self, render_mode=render_mode, width=width, height=height)
        EzPickle.__init__(
            self, tolerance=tolerance, image=image, image_size=image_size, render_mode=render_mode, width=width, height=height
        )
        self.metadata = {"render_modes": ["rgb_array"], "render_fps": int(np.round(1.0 / self.dt))}
        # Draw the target as the success region (it is purely visual: contype 0), so small image
        # observations still show it, as the thesis's Fig 4.5 does.
        self.model.geom_size[self.model.geom("target").id][0] = max(self.tolerance, 0.009)
        self.action_space = spaces.Box(-MAX_DELTA, MAX_DELTA, (2,), np.float32)
        self.observation_space = spaces.Dict(
            {
                "observation": spaces.Box(-np.inf, np.inf, (6,), np.float64),
                "achieved_goal": spaces.Box(-np.inf, np.inf, (2,), np.float64),
                "desired_goal": spaces.Box(-np.inf, np.inf, (2,), np.float64),
            }
        )
        self._init_image_observation(self.model, image, image_size, TOP_DOWN)

    def compute_reward(self, achieved_goal: Any, desired_goal: Any, info: Any = None) -> np.ndarray:
        """Sparse reward for HER, vectorised over leading axes: 0 within tolerance, -1 otherwise."""
        return sparse_goal_reward(achieved_goal, desired_goal, self.tolerance)

    def step(self, action):
        delta = np.clip(np.asarray(action, dtype=np.float64), -MAX_DELTA, MAX_DELTA)
        qpos = self.data.qpos.copy()
        qpos[:2] += delta
        qpos[1] = np.clip(qpos[1], -ELBOW_LIMIT, ELBOW_LIMIT)
        self.set_state(qpos, np.zeros_like(self.data.qvel))
        observation = self._get_obs()
        info = self._info(observation)
        reward = float(self.compute_reward(observation["achieved_goal"], observation["desired_goal"], info))
        return observation, reward, bool(info["is_success"]), False, info

    def reset_model(self):
        super().reset_model()  # Reacher-v5's start pose and target sampling
        self.set_state(self.data.qpos.copy(), np.zeros_like(self.data.qvel))
        for _ in range(100):  # an episode that starts solved says nothing: draw another target
            if np.linalg.norm(self._fingertip() - self.goal) > self.tolerance:
                break
            qpos = self.data.qpos.copy()
            qpos[-2:] = self.goal = self._sample_target()
            self.set_state(qpos, np.zeros_like(self.data.qvel))
        return self._get_obs()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        observation, _ = super().reset(seed=seed, options=options)
        return observation, self._info(observation)

    def close(self):
        self._close_camera()
        super().close()

    # ------------------------------------------------------------------ helpers
    def _sample_target(self) -> np.ndarray:
        while True:
            goal = self.np_random.uniform(low=-0.2, high=0.2, size=2)
            if np.linalg.norm(goal) < 0.2:
                return goal

    def _fingertip(self) -> np.ndarray:
        return self.data.body("fingertip").xpos[:2].copy()

    def _get_obs(self):
        angles = self.data.qpos[:2]
        fingertip = self._fingertip()
        observation = {
            "observation": np.concatenate([np.cos(angles), np.sin(angles), fingertip]),
            "achieved_goal": fingertip,
            "desired_goal": self.data.body("target").xpos[:2].copy(),
        }
        return self._with_image(observation, self.data)

    def _info(self, observation: dict[str, Any]) -> dict[str, Any]:
        distance = float(np.linalg.norm(observation["achieved_goal"] - observation["desired_goal"]))
        return {"is_success": distance <= self.tolerance, "distance": distance}

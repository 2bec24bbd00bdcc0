"""Fetch robot worlds of thesis §4.5.2–4.5.3, built on Gymnasium-Robotics' MuJoCo Fetch envs.

* ``FetchReach``: move the gripper to a red target (T=50).
* ``FetchReachObstacle`` (Fig 4.9): the same with a solid box placed at random in the workspace each
  episode; the arm collides with it and it can hide the goal from the camera.
* ``FetchPickAndPlace``: grasp a cube and carry it to the target (T=100), actions (Δz, a_g).

On top of Gymnasium-Robotics each env can add a camera ``image`` (grey or RGB) to the observation
and ends the episode at success, as the thesis counts "actions until the goal is reached".
"""

from __future__ import annotations

import contextlib
import io
from typing import Any

import numpy as np
from gymnasium.utils import EzPickle

from binpick.core.config import check_bool, check_choice, check_range, check_vector
from binpick.core.errors import ConfigError
from binpick.envs.goal_env import ImageObservationMixin
from binpick.sim.camera import CameraPose, check_image_size, import_mujoco

import_mujoco()  # a missing OpenGL platform becomes one clear error, not an import traceback
with contextlib.redirect_stderr(io.StringIO()):  # it prints an unrelated Adroit notice on import
    from gymnasium_robotics.envs.fetch.pick_and_place import MujocoFetchPickAndPlaceEnv
    from gymnasium_robotics.envs.fetch.reach import MujocoFetchReachEnv

# A fixed view of the table from the front-left, just wide enough for the whole goal range (±0.15 m
# around the gripper's start): at 64 px the 2 cm goal sphere is still 3-4 pixels across (APRiL, ch. 4).
WORKSPACE_VIEW = CameraPose(lookat=(1.34, 0.75, 0.5), distance=0.75, azimuth=150.0, elevation=-40.0)
# A second view from the robot's right, nearly level: it sees the goal's height and its distance from
# the robot, which the workspace view sees only through the sphere's size, and it sees past the arm
# where the arm hides the goal from the workspace view (``views: [workspace, side]``).
SIDE_VIEW = CameraPose(lookat=(1.34, 0.75, 0.55), distance=1.0, azimuth=90.0, elevation=-12.0)
VIEWS = {"workspace": WORKSPACE_VIEW, "side": SIDE_VIEW}
OBSTACLE_NAME = "obstacle"


class _BinpickFetchMixin(ImageObservationMixin):
    """Image observations, end at success and ``is_success`` in reset info for Fetch envs.

    Mixed in before a Gymnasium-Robotics Fetch class, whose ``__init__`` builds the simulation.
    """

    # Headless machines have no window: only off-screen frames are offered.
    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}
    view_pose = CameraPose(lookat=(1.25, 0.75, 0.5), distance=1.6, azimuth=150.0, elevation=-25.0)

    def __init__(
        self,
        image: str | None = None,
        image_size: int = 84,
        terminate_on_success: bool = True,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
        views: tuple[str, ...] | list[str] = ("workspace",),
    ) -> None:
        views = tuple(views) if isinstance(views, (list, tuple)) else (views,)
        if not views or len(set(views)) != len(views):
            raise ConfigError(f"views: name one or more distinct cameras of {', '.join(VIEWS)}, got {list(views)}")
        for view in views:
            check_choice("views", view, list(VIEWS))
        check_image_size("width", width)
        check_image_size("height", height)
        super().__init__(render_mode=render_mode, width=width, height=height)
        EzPickle.__init__(
            self, image=image, image_size=image_size, terminate_on_success=terminate_on_success,
            render_mode=render_mode, width=width, height=height, views=views,
        )
        self.terminate_on_success = check_bool("terminate_on_success", terminate_on_success)
        self._init_image_observation(self.model, image, image_size, tuple(VIEWS[view] for view in views))

    def _prepare_frame(self) -> None:
        self._render_callback()  # moves the target site to the current goal

    def compute_terminated(self, achieved_goal, desired_goal, info) -> bool:
        return bool(self.terminate_on_success and info["is_success"])

    def _get_obs(self):
        observation = super()._get_obs()
        if self._camera is not None:
            self._prepare_frame()
        return self._with_image(observation, self.data)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        observation, _ = super().reset(seed=seed, options=options)
        success = self._is_success(observation["achieved_goal"], self.goal)
        return observation, {"is_success": success}

    def step(self, action):
        """Gymnasium-Robotics returns a NumPy float32 reward; Gymnasium's API (and SB3's check) wants a float."""
        observation, reward, terminated, truncated, info = super().step(action)
        return observation, float(reward), terminated, truncated, info

    def close(self):
        self._close_camera()
        super().close()


class FetchReachEnv(_BinpickFetchMixin, MujocoFetchReachEnv):
    """Gymnasium-Robotics FetchReach-v4 with optional image observation and end at success.

    Thesis Table 3.3 set-ups: ``goal_offset`` fixes the goal (metres from the gripper's start);
    ``start_noise`` moves the gripper's start uniformly by up to that many metres per axis ("noisy s_0").
    """

    def __init__(self, goal_offset: tuple[float, float, float] | None = None, start_noise: float = 0.0,
                 **kwargs: Any) -> None:
        self.start_noise = float(check_range("start_noise", start_noise, 0.0, 0.15))
        self.goal_offset = None
        if goal_offset is not None:
            self.goal_offset = np.array(check_vector("goal_offset (x, y, z metres)", goal_offset, 3, -0.15, 0.15))
        super().__init__(**kwargs)
        EzPickle.__init__(self, goal_offset=goal_offset, start_noise=start_noise, **kwargs)

    def _sample_goal(self):
        if self.goal_offset is None:
            return super()._sample_goal()
        return self.initial_gripper_xpos[:3] + self.goal_offset

    def _reset_sim(self):
        done = super()._reset_sim()
        if self.start_noise > 0:  # drive the mocap to a jittered start, as _env_setup does at start-up
            self._utils.reset_mocap2body_xpos(self.model, self.data)
            self.data.mocap_pos[0] += self.np_random.uniform(-self.start_noise, self.start_noise, 3)
            for _ in range(10):
                self._mujoco_step(None)
            self._step_callback()
        return done


class FetchReachObstacleEnv(FetchReachEnv):
    """FetchReach with a solid box placed at random in the goal region each episode (Fig 4.9).

    The box never contains the goal (with a margin) and never starts touching the robot, so every
    episode stays solvable; it can block straight paths and occlude the target from the camera.
    Placed uniformly, it lies within 4 cm of the straight gripper-to-goal line in only 5% of
    episodes, so a policy blind to it loses almost nothing; with ``obstacle_on_path`` = p it is put
    across that line (30-70% of the way, jittered) in a share p of episodes, as the thesis's box
    "affects exploration and the potential solutions" (its state-only policy: 3.10 -> 8.45 actions).
    """

    def __init__(self, obstacle_half_size: float = 0.05, obstacle_on_path: float = 0.0, **kwargs: Any) -> None:
        self.obstacle_half_size = float(check_range("obstacle_half_size", obstacle_half_size, 0.01, 0.1))
        self.obstacle_on_path = float(check_range("obstacle_on_path", obstacle_on_path, 0.0, 1.0))
        super().__init__(**kwargs)
        EzPickle.__init__(self, obstacle_half_size=obstacle_half_size, obstacle_on_path=obstacle_on_path, **kwargs)

    def _initialize_simulation(self):
        # Same as MujocoRobotEnv._initialize_simulation, except the model gets the obstacle body.
        spec = self._mujoco.MjSpec.from_file(self.fullpath)
        body = spec.worldbody.add_body(name=OBSTACLE_NAME, pos=[0.0, 0.0, -1.0])
        half = self.obstacle_half_size
        body.add_geom(
            name=OBSTACLE_NAME, type=self._mujoco.mjtGeom.mjGEOM_BOX, size=[half, half, half],
            rgba=[0.15, 0.35, 0.85, 1.0], condim=3,
        )
        self.model = spec.compile()
        self.data = self._mujoco.MjData(self.model)
        self._model_names = self._utils.MujocoModelNames(self.model)
        self.model.vis.global_.offwidth = self.width
        self.model.vis.global_.offheight = self.height
        self._env_setup(initial_qpos=self.initial_qpos)
        self.initial_time = self.data.time
        self.initial_qpos = np.copy(self.data.qpos)
        self.initial_qvel = np.copy(self.data.qvel)
        self._obstacle_body = self.model.body(OBSTACLE_NAME).id
        self._obstacle_geom = self.model.geom(OBSTACLE_NAME).id
        table = self.model.body("table0")
        table_geom = table.geomadr[0]
        self._table_top = float(table.pos[2] + self.model.geom_size[table_geom][2])

    @property
    def obstacle_position(self) -> np.ndarray:
        return self.model.body_pos[self._obstacle_body].copy()

    def obstacle_contacts(self) -> int:
        """Number of active contacts between the obstacle and any other geom (i.e. the robot)."""
        contacts = self.data.contact[: self.data.ncon]
        return int(np.sum((contacts.geom1 == self._obstacle_geom) | (contacts.geom2 == self._obstacle_geom)))

    def _sample_goal(self):
        goal = super()._sample_goal()
        self._place_obstacle(goal)
        return goal

    def _place_obstacle(self, goal: np.ndarray) -> None:
        half = self.obstacle_half_size
        centre = self.initial_gripper_xpos[:3]
        gripper = self._utils.get_site_xpos(self.model, self.data, "robot0:grip").copy()
        low = centre - self.target_range
        low[2] = max(low[2], self._table_top + half + 0.01)  # static geoms do not collide: keep it off the table
        high = centre + self.target_range
        on_path = self.obstacle_on_path > 0 and self.np_random.uniform() < self.obstacle_on_path
        for attempt in range(200):
            across = on_path and attempt < 100  # across the straight line to the goal, else anywhere
            if across:
                position = gripper + self.np_random.uniform(0.3, 0.7) * (goal - gripper)
                position = position + self.np_random.uniform(-0.01, 0.01, 3)
                position[2] = max(position[2], low[2])
            else:
                position = self.np_random.uniform(low, high)
            goal_margin, gripper_margin = (0.02, 0.03) if across else (0.06, 0.08)
            if np.max(np.abs(position - goal)) < half + goal_margin or np.max(np.abs(position - gripper)) < half + gripper_margin:
                continue
            self.model.body_pos[self._obstacle_body] = position
            self._mujoco.mj_forward(self.model, self.data)
            if self.obstacle_contacts() == 0:
                return
        self.model.body_pos[self._obstacle_body] = [0.0, 0.0, -1.0]  # no free spot: out of the way
        self._mujoco.mj_forward(self.model, self.data)


class FetchPickAndPlaceEnv(_BinpickFetchMixin, MujocoFetchPickAndPlaceEnv):
    """Gymnasium-Robotics FetchPickAndPlace-v4 (actions Δz and gripper a_g) with optional images."""

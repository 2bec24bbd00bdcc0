"""Planar three-joint arm of thesis §3.1.3 (Fig 3.2): the mock manipulation task for DQN and A3C.

The arm's base sits at the centre of a square play area. Each of the six discrete actions turns one
joint by ±π/8. The observation is an RGB picture of the arm and the goal (default 64×64); the
semantic state (joint angles, end point, goal) is returned beside it in ``info`` and, with
``goal_conditioned=True``, as a Gymnasium-Robotics style dict (``observation``, ``achieved_goal``,
``desired_goal``, plus ``image`` unless ``image=None``) so HER and GP models can use it.

The goal is either fixed (``goal_area=0``) or drawn uniformly from a rectangle that grows from the
fixed goal to the whole play area: ``goal_area`` is the fraction of the play area it covers, and can
be changed while training (``env.unwrapped.set_goal_area``) for the curriculum of §3.2 (Fig 3.4).
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from PIL import Image, ImageDraw

from binpick.core.config import check_bool, check_choice, check_range, check_vector
from binpick.envs.goal_env import sparse_goal_reward
from binpick.sim.camera import IMAGE_MODES, check_image_size, to_mode
from binpick.core.errors import ConfigError

PLAY_HALF_WIDTH = 1.0  # the play area is [-1, 1]^2 in world units
VIEW_HALF_WIDTH = 1.1  # the picture shows a small margin around it
STEP_ANGLE = math.pi / 8
# The thesis does not give its success radius. 0.07 (7% of the reach) makes a random walk take
# ~350 actions on average, the thesis's random baseline (369 ± 341, Table 3.1); see docs/RESULTS.md.
DEFAULT_TOLERANCE = 0.07
_BACKGROUND = (20, 20, 28)
_LINK_COLOURS = ((90, 160, 255), (80, 220, 140), (250, 200, 70))
_GOAL_COLOUR = (230, 40, 40)


class Arm2DEnv(gym.Env):
    """Reach a goal with the end point of a planar 3-link arm, from pixels (thesis §3.1.3)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        image_size: int = 64,
        image: str | None = "rgb",
        goal_conditioned: bool = False,
        goal_area: float = 0.0,
        fixed_goal: tuple[float, float] = (-0.45, 0.45),
        tolerance: float = DEFAULT_TOLERANCE,
        link_lengths: tuple[float, float, float] = (0.4, 0.3, 0.3),
        render_size: int = 256,
        render_mode: str | None = None,
    ) -> None:
        self.image_size = check_image_size("image_size", image_size)
        self.goal_conditioned = check_bool("goal_conditioned", goal_conditioned)
        # a state-only Arm2D (image=None) exists for state-based RL; the pixel task needs a picture
        self.image_mode = check_choice("image", image, [None, *IMAGE_MODES] if self.goal_conditioned else IMAGE_MODES)
        self.render_size = check_image_size("render_size", render_size)
        self.render_mode = check_choice("render_mode", render_mode, [None, *self.metadata["render_modes"]])
        self.link_lengths = np.array(check_vector("link_lengths", link_lengths, 3, 0.0, 1.0, low_inclusive=False))
        self.reach = float(self.link_lengths.sum())
        self.tolerance = float(check_range("tolerance", tolerance, 0.0, 0.5, low_inclusive=False))
        self.fixed_goal = np.array(check_vector("fixed_goal", fixed_goal, 2, -PLAY_HALF_WIDTH, PLAY_HALF_WIDTH))
        if np.linalg.norm(self.fixed_goal) > 0.95 * self.reach:
            raise ConfigError(
                f"fixed_goal {tuple(self.fixed_goal)} is out of the arm's reach (|goal| must be <= {0.95 * self.reach:.3f})"
            )
        self.goal_area = 0.0
        self.set_goal_area(goal_area)

        self.action_space = spaces.Discrete(6)
        channels = 3 if self.image_mode == "rgb" else 1
        image_space = spaces.Box(0, 255, (self.image_size, self.image_size, channels), np.uint8)
        if self.goal_conditioned:
            self.observation_space = spaces.Dict(
                {
                    "observation": spaces.Box(-np.inf, np.inf, (8,), np.float64),
                    "achieved_goal": spaces.Box(-np.inf, np.inf, (2,), np.float64),
                    "desired_goal": spaces.Box(-np.inf, np.inf, (2,), np.float64),
                    **({"image": image_space} if self.image_mode else {}),
                }
            )
        else:
            self.observation_space = image_space

        self.angles = np.zeros(3)
        self.goal = self.fixed_goal.copy()

    # ------------------------------------------------------------------ curriculum
    def set_goal_area(self, goal_area: float) -> None:
        """Change the fraction of the play area goals are drawn from (0 = the fixed goal, 1 = all)."""
        self.goal_area = float(check_range("goal_area", goal_area, 0.0, 1.0))

    def place_goal(self, goal: np.ndarray) -> tuple[Any, dict[str, Any]]:
        """Move the goal, keeping the arm's pose; returns the new (observation, info). For pictures of the
        goal close to the end point, where episodes end but random poses seldom put it."""
        goal = np.asarray(goal, dtype=float)
        if goal.shape != (2,) or not np.isfinite(goal).all():
            raise ValueError(f"a goal is two finite numbers, got {goal!r}")
        self.goal = goal.copy()
        return self._observation(), self._info()

    def goal_region(self) -> tuple[np.ndarray, np.ndarray]:
        """Corners (low, high) of the rectangle goals are sampled from; it contains the fixed goal.

        The rectangle is the play area shrunk towards the fixed goal by sqrt(goal_area) on each
        side, so its area is ``goal_area`` times the play area's.
        """
        scale = math.sqrt(self.goal_area)
        low = self.fixed_goal + scale * (-PLAY_HALF_WIDTH - self.fixed_goal)
        high = self.fixed_goal + scale * (PLAY_HALF_WIDTH - self.fixed_goal)
        return low, high

    # ------------------------------------------------------------------ kinematics
    def joint_positions(self, angles: np.ndarray | None = None) -> np.ndarray:
        """Base, two elbows and end point as a (4, 2) array, forward kinematics of the chain."""
        angles = self.angles if angles is None else angles
        cumulative = np.cumsum(angles)
        steps = self.link_lengths[:, None] * np.stack([np.cos(cumulative), np.sin(cumulative)], axis=1)
        return np.vstack([np.zeros(2), np.cumsum(steps, axis=0)])

    @property
    def end_point(self) -> np.ndarray:
        return self.joint_positions()[-1]

    @property
    def state(self) -> np.ndarray:
        """Semantic state: joint angles (3), end point (2), goal (2)."""
        return np.concatenate([self.angles, self.end_point, self.goal])

    @property
    def state_continuous(self) -> np.ndarray:
        """The semantic state with each joint angle as its cosine and sine (3 + 3), end point, goal: a
        regression target without the jump at ±π. A network regressing the raw angles spends its loss on
        that jump (from 64 px images at A3C's learning rate, 6,000 updates left the end point
        0.34 off with raw angles, 0.10 with this)."""
        return _continuous(self.state)

    @property
    def compute_reward(self):
        """HER's reward function ``(achieved, desired, info) -> reward``, with ``goal_conditioned=True``
        only: tools such as SB3's env checker take any env with ``compute_reward`` for a goal env,
        and the pixel task's observation is an image, not a goal dict."""
        if not self.goal_conditioned:
            raise AttributeError("Arm2D has compute_reward only with goal_conditioned=True")
        return self._sparse_reward

    def _sparse_reward(self, achieved_goal: Any, desired_goal: Any, info: Any = None) -> np.ndarray:
        """Sparse reward for HER, vectorised over leading axes: 0 within tolerance, -1 otherwise."""
        return sparse_goal_reward(achieved_goal, desired_goal, self.tolerance)

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.goal = self._sample_goal()
        for _ in range(1000):  # never start on the goal: the episode would have length 0
            self.angles = self.np_random.uniform(-math.pi, math.pi, size=3)
            if np.linalg.norm(self.end_point - self.goal) > self.tolerance:
                break
        return self._observation(), self._info()

    def step(self, action):
        if not self.action_space.contains(action):
            raise ValueError(f"action must be an integer in [0, 5], got {action!r}")
        joint, direction = divmod(int(action), 2)
        self.angles[joint] += STEP_ANGLE if direction == 0 else -STEP_ANGLE
        self.angles = (self.angles + math.pi) % (2 * math.pi) - math.pi
        info = self._info()
        reward = float(self._sparse_reward(self.end_point, self.goal, info))
        return self._observation(), reward, bool(info["is_success"]), False, info

    def render(self):
        if self.render_mode == "rgb_array":
            return self._draw(self.render_size, "rgb")
        return None

    # ------------------------------------------------------------------ helpers
    def _sample_goal(self) -> np.ndarray:
        if self.goal_area == 0.0:
            return self.fixed_goal.copy()
        low, high = self.goal_region()
        for _ in range(10_000):
            goal = self.np_random.uniform(low, high)
            if np.linalg.norm(goal) <= 0.95 * self.reach:
                return goal
        return self.fixed_goal.copy()  # only for regions almost wholly out of reach

    def _info(self) -> dict[str, Any]:
        state = self.state  # one forward kinematics for the distance and both states
        distance = float(np.linalg.norm(state[3:5] - self.goal))
        return {"is_success": distance <= self.tolerance, "distance": distance, "state": state,
                "state_continuous": _continuous(state)}

    def _observation(self):
        if not self.goal_conditioned:
            return self._draw(self.image_size, self.image_mode)
        observation = {
            "observation": np.concatenate([np.cos(self.angles), np.sin(self.angles), self.end_point]),
            "achieved_goal": self.end_point.copy(),
            "desired_goal": self.goal.copy(),
        }
        if self.image_mode is not None:
            observation["image"] = self._draw(self.image_size, self.image_mode)
        return observation

    def _draw(self, size: int, mode: str) -> np.ndarray:
        """Draw at 4x and downsample, so thin links stay visible and edges are anti-aliased."""
        scale = 4
        canvas = size * scale
        picture = Image.new("RGB", (canvas, canvas), _BACKGROUND)
        draw = ImageDraw.Draw(picture)

        def to_pixels(point: np.ndarray) -> tuple[float, float]:
            x = (point[0] + VIEW_HALF_WIDTH) / (2 * VIEW_HALF_WIDTH) * canvas
            y = (VIEW_HALF_WIDTH - point[1]) / (2 * VIEW_HALF_WIDTH) * canvas
            return x, y

        pixels_per_unit = canvas / (2 * VIEW_HALF_WIDTH)
        goal_radius = max(self.tolerance * pixels_per_unit, 1.5 * scale)
        gx, gy = to_pixels(self.goal)
        draw.ellipse([gx - goal_radius, gy - goal_radius, gx + goal_radius, gy + goal_radius], fill=_GOAL_COLOUR)
        points = [to_pixels(p) for p in self.joint_positions()]
        width = max(int(round(0.045 * pixels_per_unit)), 2 * scale)
        for start, end, colour in zip(points[:-1], points[1:], _LINK_COLOURS):
            draw.line([start, end], fill=colour, width=width)
        joint_radius = width * 0.7
        for x, y in points[:-1]:
            draw.ellipse([x - joint_radius, y - joint_radius, x + joint_radius, y + joint_radius], fill=(235, 235, 235))
        picture = picture.resize((size, size), Image.Resampling.BOX)
        return to_mode(np.array(picture, dtype=np.uint8), mode)  # writable: learners may wrap it in-place


def _continuous(state: np.ndarray) -> np.ndarray:
    """Arm2D's state (angles, end point, goal) with each angle as its cosine and sine."""
    return np.concatenate([np.cos(state[:3]), np.sin(state[:3]), state[3:]])

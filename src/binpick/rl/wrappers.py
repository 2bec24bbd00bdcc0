"""Env wrappers that put a goal env in the thesis's set-up for GP + HER learning."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from binpick.config import check_range


class SemanticState(gym.ObservationWrapper):
    """The policy sees only the semantic state: ``observation`` := ``achieved_goal`` (z), beside g.

    Thesis §3.3.1: "the RL input state is the position of the arm z and the goal position g". With it,
    a GP on (z, a) -> Δz predicts everything the policy needs, so imagined episodes are complete.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        goal_space = env.observation_space["achieved_goal"]
        self.observation_space = spaces.Dict(
            {"observation": goal_space, "achieved_goal": goal_space, "desired_goal": env.observation_space["desired_goal"]}
        )

    def observation(self, observation):
        return {"observation": observation["achieved_goal"].copy(), "achieved_goal": observation["achieved_goal"],
                "desired_goal": observation["desired_goal"]}

    def compute_reward(self, achieved_goal, desired_goal, info):
        return self.env.unwrapped.compute_reward(achieved_goal, desired_goal, info)


class MinActionScale(gym.ActionWrapper):
    """Actions smaller than ``scale`` of the maximum are stretched to it (thesis §3.3.1: 0.4).

    The simulator executes very small Fetch moves poorly (Fig 3.9), so the thesis limits the
    smallest action. The direction is kept; only the largest component is raised to ``scale``.
    """

    def __init__(self, env: gym.Env, scale: float = 0.4) -> None:
        super().__init__(env)
        self.scale = check_range("min_action_scale", scale, 0.0, 1.0)
        self._high = np.asarray(env.action_space.high, np.float64)

    def action(self, action):
        return scale_up_small_action(action, self._high, self.scale).astype(self.env.action_space.dtype)


def scale_up_small_action(action, high, scale: float) -> np.ndarray:
    """Stretch the position part of ``action`` so its largest component is at least ``scale`` of ``high``."""
    action = np.asarray(action, np.float64)
    relative = np.abs(action[:3] / np.asarray(high, np.float64)[:3]).max()  # a gripper component stays as it is
    if 0 < relative < scale:
        action = action.copy()
        action[:3] *= scale / relative
    return action

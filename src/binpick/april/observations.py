"""What an APRiL policy sees: the semantic state s̄, the encoded image φ_enc(I), or both.

For the reach envs the semantic state is s̄ = (z, g): the end point and the goal (thesis §4.5.1,
§4.5.2). A policy trained on s̄ (``SemanticState`` observations) is deployed on pixels by putting
φ_enc(I)^{1:m} in place of s̄ (:class:`PixelsAsSemantic`); a latent policy sees a flat vector
(:class:`EncodedObservation`).
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from binpick.rl.common.wrappers import gripper_dims, semantic_part


def semantic_state(observation: dict, gripper: bool = False, opening: bool = False) -> np.ndarray:
    """s̄ = (z, g) for the reach envs; (gripper, object, goal) for pick and place (``gripper``), with
    ``opening`` (gripper, fingers' opening, object, goal)."""
    return np.concatenate([semantic_part(observation, gripper, opening), observation["desired_goal"]]).astype(np.float32)


def semantic_observation(state: np.ndarray, goal_dim: int) -> dict[str, np.ndarray]:
    """s̄ as the dict a ``SemanticState``-trained policy takes: the goal is last, the achieved goal
    (z, or the object) just before it, and ``observation`` is everything before the goal."""
    state = np.asarray(state, np.float64)
    observation, goal = state[:-goal_dim], state[-goal_dim:]
    return {"observation": observation.copy(), "achieved_goal": observation[-goal_dim:].copy(), "desired_goal": goal.copy()}


class PixelsAsSemantic(gym.ObservationWrapper):
    """Deployment for m = n (Eq 4.8): the policy gets φ_enc(I) where it was trained on s̄."""

    def __init__(self, env: gym.Env, encode: Callable[[np.ndarray], np.ndarray], gripper: bool = False,
                 opening: bool = False) -> None:
        super().__init__(env)
        goal_space = env.observation_space["achieved_goal"]
        self.goal_dim = goal_space.shape[0]
        self.encode = encode
        size = self.goal_dim + gripper_dims(gripper, opening)
        self.observation_space = spaces.Dict({"observation": spaces.Box(-np.inf, np.inf, (size,), np.float64),
                                              "achieved_goal": goal_space,
                                              "desired_goal": env.observation_space["desired_goal"]})

    def observation(self, observation):
        return semantic_observation(self.encode(observation["image"])[0], self.goal_dim)


class EncodedObservation(gym.ObservationWrapper):
    """A flat observation for latent policies (Eq 4.9): φ_enc(I), optionally after the true s̄.

    ``with_state`` puts the ground-truth s̄ first and only the free latent after it (the "ground truth
    plus free latent" baseline, like Finn et al.); otherwise the whole latent is the observation.
    """

    def __init__(self, env: gym.Env, encode: Callable[[np.ndarray], np.ndarray], latent: int, conditioned: int,
                 with_state: bool = False, gripper: bool = False, opening: bool = False) -> None:
        super().__init__(env)
        self.encode, self.conditioned, self.with_state, self.gripper = encode, conditioned, with_state, gripper
        self.opening = opening
        state_dim = 2 * env.observation_space["achieved_goal"].shape[0] + gripper_dims(gripper, opening)
        size = state_dim + latent - conditioned if with_state else latent
        self.observation_space = spaces.Box(-np.inf, np.inf, (size,), np.float32)

    last_raw: dict | None = None  # the env's own observation behind the latest one (s̄ for a teacher)

    def observation(self, observation):
        self.last_raw = observation
        latent = self.encode(observation["image"])[0].astype(np.float32)
        if self.with_state:
            return np.concatenate([semantic_state(observation, self.gripper, self.opening), latent[self.conditioned:]])
        return latent


class GoalRecorder(gym.Wrapper):
    """Remembers each episode's goal, for heat maps of episode length by goal position (Fig 4.7)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.goals: list[np.ndarray] = []

    def reset(self, **kwargs):
        observation, info = self.env.reset(**kwargs)
        self.goals.append(_goal_of(self.env))
        return observation, info


def _goal_of(env: gym.Env) -> np.ndarray:
    goal = getattr(env.unwrapped, "goal", None)
    if goal is None:  # Reacher keeps its target as a body
        goal = env.unwrapped.data.body("target").xpos[:2]
    return np.asarray(goal, np.float64).copy()

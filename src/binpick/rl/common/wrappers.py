"""Env wrappers that put a goal env in the thesis's set-up for GP + HER learning."""

from __future__ import annotations

from collections.abc import Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from binpick.core.config import check_range
from binpick.core.errors import ConfigError


class SemanticState(gym.ObservationWrapper):
    """The policy sees only the semantic state: ``observation`` := ``achieved_goal`` (z), beside g.

    Thesis §3.3.1: "the RL input state is the position of the arm z and the goal position g". With it,
    a GP on (z, a) -> Δz predicts everything the policy needs, so imagined episodes are complete.
    With ``gripper`` (pick and place, §4.5.3) the observation is (gripper position, object position):
    the object is the achieved goal, and the policy must also know where its hand is.
    """

    def __init__(self, env: gym.Env, gripper: bool = False, privileged: Sequence[str] = (), opening: bool = False) -> None:
        super().__init__(env)
        self.gripper, self.privileged, self.opening = gripper, tuple(privileged), bool(opening)
        goal_space = env.observation_space["achieved_goal"]
        size = goal_space.shape[0] + gripper_dims(gripper, opening) + len(privileged_values(env, self.privileged))
        self.observation_space = spaces.Dict({
            "observation": spaces.Box(-np.inf, np.inf, (size,), np.float64),
            "achieved_goal": goal_space, "desired_goal": env.observation_space["desired_goal"]})

    def observation(self, observation):
        return semantic_inputs(observation, self.gripper, privileged_values(self.env, self.privileged), self.opening)

    def compute_reward(self, achieved_goal, desired_goal, info):
        return self.env.unwrapped.compute_reward(achieved_goal, desired_goal, info)


def semantic_inputs(observation: dict, gripper: bool = False, privileged: np.ndarray | None = None,
                    opening: bool = False) -> dict:
    """An env's raw observation as a :class:`SemanticState`-trained policy reads it (s̄ as a dict);
    ``privileged`` (see :func:`privileged_values`) follows z in ``observation``."""
    part = semantic_part(observation, gripper, opening)
    if privileged is not None and len(privileged):
        part = np.concatenate([part, np.asarray(privileged, np.float64)])
    return {"observation": part, "achieved_goal": observation["achieved_goal"], "desired_goal": observation["desired_goal"]}


def privileged_values(env: gym.Env, names: Sequence[str]) -> np.ndarray:
    """The env's own state named in an RL config's ``privileged_state`` (e.g. ``obstacle_position``),
    one vector; what a teacher in the simulator may read and a camera-driven policy may not."""
    values = []
    for name in names:
        value = getattr(env.unwrapped, name, None)
        if value is None:
            raise ConfigError(f"privileged_state: {env.unwrapped.spec.id if env.unwrapped.spec else env.unwrapped} "
                              f"has no {name!r}")
        values.append(np.asarray(value, np.float64).ravel())
    return np.concatenate(values) if values else np.zeros(0)


def semantic_part(observation: dict, gripper: bool = False, opening: bool = False) -> np.ndarray:
    """What :class:`SemanticState` puts in ``observation``: z, or (gripper position, object position),
    or with ``opening`` (gripper position, the fingers' opening, object position)."""
    achieved = np.asarray(observation["achieved_goal"], np.float64)
    if gripper:
        raw = np.asarray(observation["observation"], np.float64)
        hand = np.concatenate([raw[:3], [raw[9:11].sum()]]) if opening else raw[:3]  # Fetch: finger joints 9, 10
        return np.concatenate([hand, achieved])
    return achieved.copy()


def gripper_dims(gripper: bool, opening: bool = False) -> int:
    """How many numbers of s̄ describe the hand before the achieved goal: none for reach (z is the
    achieved goal), its position for pick and place, and with ``opening`` the fingers' opening too."""
    return (3 + int(bool(opening))) if gripper else 0


def needs_gripper(env_id: str) -> bool:
    """Envs whose achieved goal is an object, so the semantic state also holds the gripper."""
    from binpick.envs import env_spec

    return env_spec(env_id).moves_object


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


class _SeededPerturbation(gym.ObservationWrapper):
    """A vector-observation wrapper with its own generator, seeded from reset's seed, so the env's goals
    and starts stay as they are without it."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.rng = np.random.default_rng()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.rng = np.random.default_rng(seed + 7_777)
        return super().reset(seed=seed, options=options)


class GaussianObservationNoise(_SeededPerturbation):
    """Adds independent Gaussian noise (``std``) to every component of a vector observation, fresh each step.

    Why: a learner on the true state stands in for one on a state read off pictures only if the
    reading's error does not matter; with the noise set to the reading's error it measures whether it does."""

    def __init__(self, env: gym.Env, std: float) -> None:
        super().__init__(env)
        self.std = check_range("state_noise", std, 0.0, 1e3)

    def observation(self, observation):
        return observation + self.rng.normal(0.0, self.std, np.shape(observation))


class ReadingErrors(_SeededPerturbation):
    """Adds a row of ``errors`` (N, D), a random row each step, to a D-vector observation.

    Why: a perception's error is tied to the pose -- the same each time the arm is there, so a
    learner cannot average it out. Rows of that perception's own errors, measured on other pictures and
    drawn at random, are the same errors untied from the pose: a learner that keeps its pace with these
    and not with the perception itself is slowed by the tie, not by the size of the errors."""

    def __init__(self, env: gym.Env, errors: np.ndarray) -> None:
        super().__init__(env)
        self.errors = np.asarray(errors, np.float64)
        size = env.observation_space.shape
        if self.errors.ndim != 2 or not len(self.errors) or size is None or (self.errors.shape[1],) != tuple(size):
            raise ConfigError(f"reading errors must be a non-empty (N, {size[0] if size else '?'}) table for this "
                              f"env's observations, got shape {self.errors.shape}")

    def observation(self, observation):
        return observation + self.errors[self.rng.integers(len(self.errors))]

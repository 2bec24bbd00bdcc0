"""The env a run trains on, whatever its algorithm: what ``binpick rl eval``, the trainers, Ray's
simulator actors and :meth:`binpick.rl.policy.Policy.make_env` all build."""

from __future__ import annotations

import gymnasium as gym

from binpick.core.errors import ConfigError
from binpick.envs import make
from binpick.rl.algorithms import ALGORITHMS
from binpick.rl.common.wrappers import MinActionScale, SemanticState, needs_gripper
from binpick.rl.config import RLConfig


def no_wrap_env(config: RLConfig, wrap_env) -> None:
    """``wrap_env`` reaches only A3C's envs (binpick.rl.a3c.envs.make_a3c_env); anywhere else it is a mistake."""
    if wrap_env is not None:
        raise ConfigError(f"wrap_env is an A3C option; this run is {config.algorithm}")


def make_env(config: RLConfig, wrap_env=None) -> gym.Env:
    """The env exactly as the run trains on it, as its algorithm builds it (semantic state, minimum action
    scale; A3C's flattened state, after A3C's ``wrap_env`` if the run was made with one)."""
    return ALGORITHMS[config.algorithm].load("env")(config, wrap_env)


def sb3_env(config: RLConfig, wrap_env=None) -> gym.Env:
    """The env of an SB3-based run: s̄ = (z, g) for the algorithms that read it, the minimum action scale."""
    no_wrap_env(config, wrap_env)
    env = make(config.env, **config.env_kwargs)
    if config.semantic_state and ALGORITHMS[config.algorithm].reads_semantic_state:
        env = SemanticState(env, gripper=needs_gripper(config.env), privileged=config.privileged_state,
                            opening=config.gripper_opening)
    if config.min_action_scale:
        env = MinActionScale(env, config.min_action_scale)
    return env

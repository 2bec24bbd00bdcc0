"""A3C's env: the run's env, its goal-env dictionary flattened for the state encoder, with the reading
noise the config asks for."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np

from binpick.core.errors import ConfigError
from binpick.rl.config import RLConfig

EnvWrapper = Callable[[gym.Env], gym.Env]  # e.g. a frozen perception between the env and the learner


def make_a3c_env(config: RLConfig, wrap_env: EnvWrapper | None = None) -> gym.Env:
    """The run's env; for ``a3c.encoder: state`` a goal env's dict observation is flattened into one vector.

    ``wrap_env`` (env -> env) is applied first: e.g. a frozen perception that turns the pictures into the
    state vector a state learner reads (binpick.april.arm2d.ReadStateOffPixels). It must pickle, as the
    workers are spawned processes."""
    from gymnasium import spaces
    from gymnasium.wrappers import FlattenObservation

    from binpick.envs import make
    from binpick.rl.common.wrappers import GaussianObservationNoise

    env = make(config.env, **config.env_kwargs)
    if wrap_env is not None:
        env = wrap_env(env)
    space = env.observation_space
    if config.a3c.encoder == "state":
        parts = space.spaces if isinstance(space, spaces.Dict) else {"observation": space}
        not_vectors = [key for key, part in parts.items() if len(part.shape or ()) != 1]
        if not_vectors:
            env.close()
            raise ConfigError(f"a3c.encoder 'state' needs vector observations; {config.env}'s {not_vectors} are not "
                              f"(for Arm2D set env_kwargs: {{goal_conditioned: true, image: null}})")
        if isinstance(space, spaces.Dict):
            env = FlattenObservation(env)
        if config.a3c.state_noise:
            env = GaussianObservationNoise(env, config.a3c.state_noise)
    elif len(space.shape or ()) != 3:
        env.close()
        raise ConfigError(f"a3c.encoder {config.a3c.encoder!r} needs image observations; {config.env} gives "
                          f"{type(space).__name__} (use a3c.encoder: state for vector observations)")
    return env


def semantic_state_size(config: RLConfig, wrap_env: EnvWrapper | None = None) -> int:
    """Length of the env's semantic state (info[a3c.state_key]) when the auxiliary state loss is on, else 0."""
    if config.a3c.state_weight == 0:
        return 0
    env = make_a3c_env(config, wrap_env)
    try:
        state = env.reset(seed=0)[1].get(config.a3c.state_key)
    finally:
        env.close()
    if state is None:
        raise ConfigError(f"a3c.state_weight needs an env that returns its semantic state in info[{config.a3c.state_key!r}] "
                          f"(a3c.state_key); {config.env} does not")
    return int(np.asarray(state).size)

"""An RL run's policy, whatever its algorithm (the latest checkpoint: SAC, SB3 SAC+HER, DQN's
``policy.safetensors`` or A3C's actor), and the env it acts in. Users call
:meth:`binpick.Policy.load`, which reaches these through the job registry."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym

from binpick.core.config import load_run_config
from binpick.core.errors import ConfigError, InputFileError
from binpick.core.policy import Policy
from binpick.core.runs import latest_checkpoint
from binpick.rl.algorithms import ALGORITHMS
from binpick.rl.common.persistence import POLICY_FILE, load_saved_policy
from binpick.rl.config import RLConfig
from binpick.rl.envs import make_env


def load_policy(run_dir: Path, env_id: str | None = None) -> tuple[Policy, RLConfig]:
    """The latest checkpoint's policy of a run and the run's config; asking for another env than it was
    trained on is an error."""
    run_dir = Path(run_dir)
    if not (run_dir / "config.yaml").is_file():
        raise ConfigError(f"{str(run_dir)!r} is not a run folder (no config.yaml)")
    config = load_run_config(RLConfig, run_dir)
    if env_id is not None:
        from binpick.envs import resolve_env_id

        if resolve_env_id(env_id) != config.env:
            raise ConfigError(f"checkpoint {run_dir} was trained on {config.env}, not {resolve_env_id(env_id)}")
    checkpoint = latest_checkpoint(run_dir / "checkpoints")
    if checkpoint is None:
        raise ConfigError(f"run {run_dir} has no checkpoint yet")
    return ALGORITHMS[config.algorithm].load("policy")(checkpoint), config


def load_sb3_policy(checkpoint: Path) -> Policy:
    """The policy network an SB3-based run saved in a checkpoint folder (``policy.safetensors``)."""
    if not (checkpoint / POLICY_FILE).is_file():
        raise InputFileError(f"checkpoint {checkpoint} has no {POLICY_FILE} (older runs saved SB3 zips, "
                             "which binpick no longer loads because they can run code)")
    return load_saved_policy(checkpoint / POLICY_FILE)


def load_run_policy(run_dir: Path, env_id: str | None = None) -> Policy:
    """An RL run's policy, for :meth:`binpick.core.policy.Policy.load`."""
    return load_policy(run_dir, env_id)[0]


def make_run_env(run_dir: Path) -> gym.Env:
    """The env exactly as an RL run trained on it (semantic state, minimum action scale), for
    :meth:`binpick.core.policy.Policy.make_env`."""
    return make_env(load_run_config(RLConfig, run_dir))

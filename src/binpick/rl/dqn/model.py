"""SB3's DQN with the run's settings (thesis §3.1.1: replay of M transitions, target network every C steps)."""

from __future__ import annotations

import gymnasium as gym
from stable_baselines3 import DQN

from binpick.rl.config import RLConfig


def build_dqn(config: RLConfig, env: gym.Env, tensorboard: str | None, envs=None) -> DQN:
    """The DQN learner on Arm2D's pictures (SB3's NatureCNN); one simulator (``envs`` is not taken)."""
    dqn = config.dqn
    return DQN("CnnPolicy", env, buffer_size=dqn.buffer_size, target_update_interval=dqn.target_update_interval,
               learning_rate=dqn.learning_rate, batch_size=dqn.batch_size, gamma=dqn.gamma,
               learning_starts=dqn.learning_starts, train_freq=dqn.train_freq,
               exploration_fraction=dqn.exploration_fraction, exploration_final_eps=dqn.exploration_final_eps,
               optimize_memory_usage=False, seed=config.seed, tensorboard_log=tensorboard, device="cpu")

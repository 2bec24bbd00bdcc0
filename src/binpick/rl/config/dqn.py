"""DQN's settings (thesis §3.1.1), SB3's DQN underneath."""

from __future__ import annotations

from dataclasses import dataclass

from binpick.core.config import check_range
from binpick.core.errors import ConfigError


@dataclass(frozen=True)
class DQNConfig:
    """SB3's DQN (§3.1.1): replay of capacity M transitions, target network refreshed every C steps."""

    buffer_size: int = 50_000  # M
    target_update_interval: int = 1000  # C
    learning_rate: float = 1e-4
    batch_size: int = 32
    gamma: float = 0.99
    learning_starts: int = 5000
    train_freq: int = 4
    exploration_fraction: float = 0.2
    exploration_final_eps: float = 0.05

    def __post_init__(self) -> None:
        check_range("dqn.buffer_size (M)", self.buffer_size, 1, 10_000_000, integer=True)
        check_range("dqn.target_update_interval (C)", self.target_update_interval, 1, None, integer=True)
        check_range("dqn.learning_rate", self.learning_rate, 0.0, 1.0, low_inclusive=False)
        check_range("dqn.batch_size", self.batch_size, 1, 100_000, integer=True)
        check_range("dqn.gamma", self.gamma, 0.0, 1.0, high_inclusive=False)
        check_range("dqn.learning_starts", self.learning_starts, 0, None, integer=True)
        check_range("dqn.train_freq", self.train_freq, 1, None, integer=True)
        check_range("dqn.exploration_fraction", self.exploration_fraction, 0.0, 1.0)
        check_range("dqn.exploration_final_eps", self.exploration_final_eps, 0.0, 1.0)
        if self.buffer_size < self.batch_size:
            raise ConfigError(f"dqn.buffer_size (M={self.buffer_size}) must be >= dqn.batch_size ({self.batch_size})")

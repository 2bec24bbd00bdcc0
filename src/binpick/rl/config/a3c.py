"""A3C's settings (thesis §3.2, §4.5): workers, rollouts, losses and the network's encoder."""

from __future__ import annotations

from dataclasses import dataclass

from binpick.core.config import check_bool, check_choice, check_range
from binpick.core.errors import ConfigError


@dataclass(frozen=True)
class A3CConfig:
    """Asynchronous advantage actor-critic (§3.1.2)."""

    workers: int = 2  # n; the thesis used two
    n_steps: int = 20  # actions per update (n-step returns, Eq 3.7)
    gamma: float = 0.99
    learning_rate: float = 1e-4
    entropy_beta: float = 0.01  # β of Eq 3.6
    value_coef: float = 0.5
    max_grad_norm: float = 40.0
    reward_scale: float = 0.01  # keeps value targets in [-1, 0] for the -1-per-step reward
    encoder: str = "flatten"  # "keypoints": expected positions of feature maps (goals anywhere; see rl/a3c/networks.py);
    # "state": an MLP on the env's vector observation (a goal env's dict is flattened): perception taken away
    state_weight: float = 0.0  # > 0: auxiliary loss, the features also regress the env's info[state_key]
    state_key: str = "state"  # which info entry; Arm2D's "state_continuous" has cos/sin for the joint angles
    pretrain_pictures: int = 0  # > 0: before RL, fit trunk and state head to the state on this many pictures
    pretrain_epochs: int = 10
    pretrain_learning_rate: float = 1e-3
    pretrain_near_goal: float = 0.0  # fraction of pretraining pictures with the goal next to the end point
    policy_input: str = "features"  # "state_estimate": policy and value read an MLP on the state head's output
    detach_perception: bool = False  # True: the RL losses stop at what the heads read; only the state loss trains the trunk
    state_noise: float = 0.0  # encoder "state": Gaussian noise (std) on every component, each step, as a reading's error
    hidden_layers: int = 1  # 256-unit layers between the trunk (or the state estimate) and the heads; see rl/a3c/networks.py

    def __post_init__(self) -> None:
        check_choice("a3c.encoder", self.encoder, ["flatten", "keypoints", "state"])
        check_range("a3c.state_weight", self.state_weight, 0.0, 1e6)
        if not isinstance(self.state_key, str) or not self.state_key:
            raise ConfigError(f"a3c.state_key must be the name of an info entry, got {self.state_key!r}")
        check_range("a3c.pretrain_pictures", self.pretrain_pictures, 0, 10_000_000, integer=True)
        check_range("a3c.pretrain_epochs", self.pretrain_epochs, 1, 10_000, integer=True)
        check_range("a3c.pretrain_learning_rate", self.pretrain_learning_rate, 0.0, 1.0, low_inclusive=False)
        check_range("a3c.pretrain_near_goal", self.pretrain_near_goal, 0.0, 1.0)
        if self.pretrain_pictures and self.state_weight == 0:
            raise ConfigError("a3c.pretrain_pictures needs the auxiliary state head: set a3c.state_weight > 0")
        check_choice("a3c.policy_input", self.policy_input, ["features", "state_estimate"])
        if self.policy_input == "state_estimate" and self.state_weight == 0:
            raise ConfigError("a3c.policy_input 'state_estimate' reads the auxiliary state head: set a3c.state_weight > 0")
        if self.policy_input == "state_estimate" and self.encoder == "state":
            raise ConfigError("a3c.policy_input 'state_estimate' estimates the state from pictures; a3c.encoder 'state' has it already")
        check_range("a3c.state_noise", self.state_noise, 0.0, 1e3)
        check_range("a3c.hidden_layers", self.hidden_layers, 0, 16, integer=True)
        check_bool("a3c.detach_perception", self.detach_perception)
        if self.detach_perception and self.state_weight == 0:
            raise ConfigError("a3c.detach_perception leaves the trunk to the auxiliary state loss alone: set a3c.state_weight > 0")
        if self.state_noise and self.encoder != "state":
            raise ConfigError("a3c.state_noise perturbs the state vector of a3c.encoder 'state'; pictures have none")
        if self.pretrain_pictures and self.encoder == "state":
            raise ConfigError("a3c.pretrain_pictures teaches a picture trunk to read the state; a3c.encoder 'state' has none")
        check_range("a3c.reward_scale", self.reward_scale, 0.0, 1e6, low_inclusive=False)
        check_range("a3c.workers", self.workers, 1, 256, integer=True)
        check_range("a3c.n_steps", self.n_steps, 1, 10_000, integer=True)
        check_range("a3c.gamma", self.gamma, 0.0, 1.0, high_inclusive=False)
        check_range("a3c.learning_rate", self.learning_rate, 0.0, 1.0, low_inclusive=False)
        check_range("a3c.entropy_beta", self.entropy_beta, 0.0, 10.0)
        check_range("a3c.value_coef", self.value_coef, 0.0, 100.0)
        check_range("a3c.max_grad_norm", self.max_grad_norm, 0.0, 1e6, low_inclusive=False)

"""RL run configuration: one YAML file per thesis experiment (``configs/rl_*.yaml``).

Every field has a default; a YAML file names only what differs. Loading checks key names, types
and ranges, and says which key is wrong in one line.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from binpick.config import check_range, from_dict, load_yaml
from binpick.errors import ConfigError

ALGORITHMS = ("sac", "sb3_sac_her")


@dataclass
class ReplayConfig:
    """Thesis Ω (§3.1.1) with episode HER (§3.3.2); for ``sb3_sac_her`` only ``future_k`` is used."""

    capacity_episodes: int = 10_000  # M
    her_additions: int = 1  # α_HER
    start_fraction: float = 0.1  # train once Ω is this full
    future_k: int = 4  # SB3 HER: relabelled goals per transition ('future' strategy)

    def __post_init__(self) -> None:
        check_range("replay.capacity_episodes (M)", self.capacity_episodes, 1, 10_000_000, integer=True)
        check_range("replay.her_additions (alpha_HER)", self.her_additions, 0, 100_000, integer=True)
        check_range("replay.start_fraction", self.start_fraction, 0.0, 1.0)
        check_range("replay.future_k", self.future_k, 1, 64, integer=True)


@dataclass
class GPConfig:
    """GP dynamics and imagined episodes (§3.3.1)."""

    enabled: bool = False
    warmup_episodes: int = 15  # random-policy episodes before the first fit (thesis: 15)
    refit_every: int = 500  # new real transitions (simulator steps) between fits
    imagined_per_real: float = 20.0  # ratio of imagined to real episodes
    batch_episodes: int = 500  # imagined episodes rolled together
    max_points: int = 1000
    iterations: int = 60

    def __post_init__(self) -> None:
        check_range("gp.warmup_episodes", self.warmup_episodes, 2, None, integer=True)
        check_range("gp.refit_every", self.refit_every, 1, None, integer=True)
        check_range("gp.imagined_per_real", self.imagined_per_real, 0.0, 10_000.0)
        check_range("gp.batch_episodes", self.batch_episodes, 1, 100_000, integer=True)
        check_range("gp.max_points", self.max_points, 10, 20_000, integer=True)
        check_range("gp.iterations", self.iterations, 1, 10_000, integer=True)


@dataclass
class SACConfig:
    learning_rate: float = 1e-3
    batch_size: int = 256
    gamma: float = 0.95
    tau: float = 0.05
    net_arch: list[int] = field(default_factory=lambda: [64, 64])
    gradient_steps: int = 1  # per simulator step
    learning_starts: int = 1000  # random-action simulator steps before learning

    def __post_init__(self) -> None:
        check_range("sac.learning_rate", self.learning_rate, 0.0, 1.0, low_inclusive=False)
        check_range("sac.batch_size", self.batch_size, 1, 1_000_000, integer=True)
        check_range("sac.gamma", self.gamma, 0.0, 1.0, high_inclusive=False)
        check_range("sac.tau", self.tau, 0.0, 1.0, low_inclusive=False)
        check_range("sac.gradient_steps", self.gradient_steps, 1, 1000, integer=True)
        check_range("sac.learning_starts", self.learning_starts, 0, None, integer=True)
        for i, width in enumerate(self.net_arch):
            check_range(f"sac.net_arch[{i}]", width, 1, 4096, integer=True)


@dataclass
class EvalConfig:
    every: int = 1000  # simulator steps between evaluations
    episodes: int = 50
    success_threshold: float = 0.95
    seed: int = 10_000  # evaluation episodes never share seeds with training

    def __post_init__(self) -> None:
        check_range("eval.every", self.every, 1, None, integer=True)
        check_range("eval.episodes", self.episodes, 1, 100_000, integer=True)
        check_range("eval.success_threshold", self.success_threshold, 0.0, 1.0)


@dataclass
class RLConfig:
    """One training run: env, algorithm, the thesis's additions, evaluation and checkpoints."""

    name: str = "run"
    env: str = "binpick/FetchReach-v0"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    algorithm: Literal["sac", "sb3_sac_her"] = "sac"
    total_timesteps: int = 20_000  # simulator steps
    seed: int = 0
    semantic_state: bool = True  # policy input (z, g), thesis §3.3.1
    min_action_scale: float | None = None  # thesis: 0.4 for Fetch
    checkpoint_every: int = 2000
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    gp: GPConfig = field(default_factory=GPConfig)
    sac: SACConfig = field(default_factory=SACConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)

    def __post_init__(self) -> None:
        from binpick.envs import resolve_env_id

        self.env = resolve_env_id(self.env)
        check_range("total_timesteps", self.total_timesteps, 1, 100_000_000, integer=True)
        check_range("checkpoint_every", self.checkpoint_every, 1, None, integer=True)
        if self.min_action_scale is not None:
            check_range("min_action_scale", self.min_action_scale, 0.0, 1.0)
        if self.algorithm == "sac" and self.replay.capacity_episodes < self.sac.batch_size:
            raise ConfigError(
                f"replay.capacity_episodes (M={self.replay.capacity_episodes}) must be >= sac.batch_size "
                f"({self.sac.batch_size})"
            )
        if self.gp.enabled and (self.algorithm != "sac" or not self.semantic_state):
            raise ConfigError("gp.enabled needs algorithm: sac and semantic_state: true (the GP models z -> z')")


def load_config(path: str | Path) -> RLConfig:
    return from_dict(RLConfig, load_yaml(path), where=Path(path).name)

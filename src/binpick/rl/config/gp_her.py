"""The GP + HER learner's settings (thesis ch. 3, §4.5.3): its SAC, the GP
dynamics that imagine episodes, demonstrations before RL and noise on the state its actor reads."""

from __future__ import annotations

from dataclasses import dataclass, field

from binpick.core.config import check_range, check_vector
from binpick.core.errors import ConfigError


@dataclass(frozen=True)
class GPConfig:
    """GP dynamics and imagined episodes (§3.3.1)."""

    enabled: bool = False
    warmup_episodes: int = 15  # random-policy episodes before the first fit (thesis: 15)
    refit_every: int = 500  # new real transitions (simulator steps) between fits
    imagined_per_real: float = 20.0  # ratio of imagined to real episodes
    batch_episodes: int = 500  # imagined episodes rolled together
    fill_until_ready: bool = True  # imagine episodes until Ω is start_fraction full (thesis §3.3.2)
    max_points: int = 1000
    iterations: int = 60

    def __post_init__(self) -> None:
        check_range("gp.warmup_episodes", self.warmup_episodes, 2, None, integer=True)
        check_range("gp.refit_every", self.refit_every, 1, None, integer=True)
        check_range("gp.imagined_per_real", self.imagined_per_real, 0.0, 10_000.0)
        check_range("gp.batch_episodes", self.batch_episodes, 1, 100_000, integer=True)
        check_range("gp.max_points", self.max_points, 10, 20_000, integer=True)
        check_range("gp.iterations", self.iterations, 1, 10_000, integer=True)


@dataclass(frozen=True)
class SACConfig:
    learning_rate: float = 1e-3
    batch_size: int = 256
    gamma: float = 0.95
    tau: float = 0.05
    net_arch: list[int] = field(default_factory=lambda: [64, 64])
    gradient_steps: int = 1  # per simulator step
    learning_starts: int = 1000  # random-action simulator steps before learning
    ent_coef: str | float = "auto"  # SB3's entropy weight: a number, "auto" or "auto_<initial value>"

    def __post_init__(self) -> None:
        check_range("sac.learning_rate", self.learning_rate, 0.0, 1.0, low_inclusive=False)
        if isinstance(self.ent_coef, str):
            try:
                valid = self.ent_coef == "auto" or (self.ent_coef.startswith("auto_")
                                                    and float(self.ent_coef[len("auto_"):]) > 0)
            except ValueError:
                valid = False
            if not valid:
                raise ConfigError(f"sac.ent_coef must be a number, 'auto' or 'auto_<value>', got {self.ent_coef!r}")
        else:
            check_range("sac.ent_coef", self.ent_coef, 0.0, 100.0)
        check_range("sac.batch_size", self.batch_size, 1, 1_000_000, integer=True)
        check_range("sac.gamma", self.gamma, 0.0, 1.0, high_inclusive=False)
        check_range("sac.tau", self.tau, 0.0, 1.0, low_inclusive=False)
        check_range("sac.gradient_steps", self.gradient_steps, 1, 1000, integer=True)
        check_range("sac.learning_starts", self.learning_starts, 0, None, integer=True)
        for i, width in enumerate(self.net_arch):
            check_range(f"sac.net_arch[{i}]", width, 1, 4096, integer=True)


@dataclass(frozen=True)
class DemonstrationConfig:
    """Scripted demonstrations before RL (thesis §4.5.3): replay episodes and behaviour cloning."""

    episodes: int = 0  # heuristic episodes (0: none)
    bc_steps: int = 2000  # actor gradient steps on their actions
    noise: float = 0.1  # Gaussian noise on the heuristic's moves, for varied demonstrations
    likelihood_weight: float = 0.0  # > 0: also fit the actor's exploration σ to the demonstrations
    bc_alpha: float = 0.0  # > 0: keep cloning during RL; weight of the RL term (TD3+BC's α)
    critic_steps: int = 0  # with bc_alpha: critic-only updates on the demonstrations before RL starts
    q_filter: bool = False  # with bc_alpha: clone only where the critic prefers the demonstrated action

    def __post_init__(self) -> None:
        check_range("demonstrations.episodes", self.episodes, 0, 1_000_000, integer=True)
        check_range("demonstrations.bc_steps", self.bc_steps, 0, 10_000_000, integer=True)
        check_range("demonstrations.noise", self.noise, 0.0, 1.0)
        check_range("demonstrations.likelihood_weight", self.likelihood_weight, 0.0, 100.0)
        check_range("demonstrations.bc_alpha", self.bc_alpha, 0.0, 1000.0)
        check_range("demonstrations.critic_steps", self.critic_steps, 0, 10_000_000, integer=True)


@dataclass(frozen=True)
class ActorNoiseConfig:
    """Gaussian noise (std in metres: one for all axes, or [x, y, z]) on the semantic state the actor
    reads in its updates, never on the critic's: a state policy that APRiL will deploy on perceived s̄
    learns actions that hold up under perception's errors, while its values stay those of the true
    state (an asymmetric actor-critic). ``achieved`` is z for reach, the object for pick and place."""

    gripper: float | list[float] = 0.0  # pick and place: the gripper position in s̄
    achieved: float | list[float] = 0.0
    goal: float | list[float] = 0.0

    def __post_init__(self) -> None:
        for name in ("gripper", "achieved", "goal"):
            value = getattr(self, name)
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                value = [check_range(f"actor_noise.{name}", value, 0.0, 1.0)] * 3
            object.__setattr__(self, name, check_vector(f"actor_noise.{name}", value, 3, 0.0, 1.0))

    @property
    def enabled(self) -> bool:
        return any(any(getattr(self, name)) for name in ("gripper", "achieved", "goal"))

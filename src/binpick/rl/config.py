"""RL run configuration: one YAML file per thesis experiment (``configs/rl/rl_*.yaml``).

Every field has a default; a YAML file names only what differs. Loading checks key names, types
and ranges, and says which key is wrong in one line.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from binpick.core.config import check_bool, check_choice, check_range, check_vector
from binpick.core.errors import ConfigError

ALGORITHMS = ("sac", "sb3_sac_her", "a3c", "dqn")
MAX_SEED = 2**32 - 1  # NumPy's legacy seeding (used by SB3) takes 32-bit seeds


@dataclass(frozen=True)
class ReplayConfig:
    """Thesis Ω (§3.1.1) with episode HER (§3.3.2); for ``sb3_sac_her`` only ``future_k`` is used."""

    capacity_episodes: int = 10_000  # M
    her_additions: int = 1  # α_HER
    start_fraction: float = 0.1  # train once Ω is this full
    future_k: int = 4  # SB3 HER: relabelled goals per transition ('future' strategy)
    her_min_motion: float = 0.0  # HER copies only if the achieved goal moved this far (thesis §4.5.3, metres)

    def __post_init__(self) -> None:
        check_range("replay.capacity_episodes (M)", self.capacity_episodes, 1, 10_000_000, integer=True)
        check_range("replay.her_additions (alpha_HER)", self.her_additions, 0, 100_000, integer=True)
        check_range("replay.start_fraction", self.start_fraction, 0.0, 1.0)
        check_range("replay.future_k", self.future_k, 1, 64, integer=True)
        check_range("replay.her_min_motion", self.her_min_motion, 0.0, None)


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


@dataclass(frozen=True)
class CurriculumStage:
    """Widen the goal area to ``area`` over ``ramp_steps``, then hold it ``hold_steps`` to re-converge."""

    area: float
    ramp_steps: int = 0
    hold_steps: int = 0

    def __post_init__(self) -> None:
        check_range("curriculum.stages[].area", self.area, 0.0, 1.0)
        check_range("curriculum.stages[].ramp_steps", self.ramp_steps, 0, None, integer=True)
        check_range("curriculum.stages[].hold_steps", self.hold_steps, 0, None, integer=True)


@dataclass(frozen=True)
class CurriculumConfig:
    """Goal-area curriculum of §3.2 (Fig 3.4); empty = the env's own goal area throughout.

    ``advance: steps`` follows the stages' ramps and holds in simulator steps. ``advance: converged``
    is the thesis's rule: a stage's area is held (at least ``hold_steps``) until the training
    episodes have re-converged there, i.e. the mean length of the last ``window`` episodes is within
    ``tolerance`` of the ``window`` before; then the next stage ramps in
    (:class:`binpick.rl.common.curriculum.CurriculumProgress`).
    """

    stages: list[CurriculumStage] = field(default_factory=list)
    advance: Literal["steps", "converged"] = "steps"
    window: int = 200  # episodes per average (advance: converged)
    tolerance: float = 0.1  # relative change between the two last averages that counts as converged

    def __post_init__(self) -> None:
        check_choice("curriculum.advance", self.advance, ("steps", "converged"))
        check_range("curriculum.window", self.window, 1, 1_000_000, integer=True)
        check_range("curriculum.tolerance", self.tolerance, 0.0, 1.0, low_inclusive=False)
        if self.advance == "converged" and not self.stages:
            raise ConfigError("curriculum.advance: converged needs curriculum.stages")

    def goal_area(self, step: int) -> float | None:
        """The goal area at a simulator step: piecewise linear ramps with holds, then the last area."""
        if not self.stages:
            return None
        area, start = 0.0, 0
        for stage in self.stages:
            if step < start + stage.ramp_steps:
                return area + (stage.area - area) * (step - start) / stage.ramp_steps
            start += stage.ramp_steps
            area = stage.area
            if step < start + stage.hold_steps:
                return area
            start += stage.hold_steps
        return area

    @property
    def total_steps(self) -> int:
        return sum(s.ramp_steps + s.hold_steps for s in self.stages)


@dataclass(frozen=True)
class EvalConfig:
    every: int = 1000  # simulator steps between evaluations
    episodes: int = 50
    success_threshold: float = 0.95
    stop_after_successes: int = 0  # end the run after this many evaluations in a row at the threshold (0: never)
    seed: int = 10_000  # evaluation episodes never share seeds with training

    def __post_init__(self) -> None:
        check_range("eval.every", self.every, 1, None, integer=True)
        check_range("eval.episodes", self.episodes, 1, 100_000, integer=True)
        check_range("eval.success_threshold", self.success_threshold, 0.0, 1.0)
        check_range("eval.stop_after_successes", self.stop_after_successes, 0, None, integer=True)


# privileged_state names: attributes of the unwrapped env, each a vector
PRIVILEGED_STATE = {"obstacle_position": "binpick/FetchReachObstacle-v0: the box's centre (x, y, z)"}


@dataclass(frozen=True)
class RLConfig:
    """One training run: env, algorithm, the thesis's additions, evaluation and checkpoints."""

    name: str = "run"
    env: str = "binpick/FetchReach-v0"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    algorithm: Literal["sac", "sb3_sac_her", "a3c", "dqn"] = "sac"
    total_timesteps: int = 20_000  # simulator steps
    seed: int = 0
    semantic_state: bool = True  # policy input (z, g), thesis §3.3.1 (continuous-control envs only)
    # simulator state beside s̄ that only a teacher may read (e.g. obstacle_position): a state policy
    # that knows what pixels show but s̄ leaves out, for APRiL's partly-semantic students to imitate
    privileged_state: list[str] = field(default_factory=list)
    # pick and place: s̄ also holds the fingers' opening (after the gripper's position). Without it
    # "just closed on the cube" and "holding it" are the same s̄, and the policy tells them apart by
    # sub-millimetre drifts that perception from pixels cannot see
    gripper_opening: bool = False
    min_action_scale: float | None = None  # thesis: 0.4 for Fetch
    checkpoint_every: int = 2000
    init_from: str | None = None  # a3c: an earlier run folder whose latest checkpoint this run continues
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    gp: GPConfig = field(default_factory=GPConfig)
    sac: SACConfig = field(default_factory=SACConfig)
    a3c: A3CConfig = field(default_factory=A3CConfig)
    dqn: DQNConfig = field(default_factory=DQNConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)
    demonstrations: DemonstrationConfig = field(default_factory=DemonstrationConfig)
    actor_noise: ActorNoiseConfig = field(default_factory=ActorNoiseConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)

    def __post_init__(self) -> None:
        from binpick.envs import env_spec, resolve_env_id

        object.__setattr__(self, "env", resolve_env_id(self.env))  # frozen: normalised once, here
        check_range("total_timesteps", self.total_timesteps, 1, 100_000_000, integer=True)
        check_range("seed", self.seed, 0, MAX_SEED, integer=True)
        check_range("checkpoint_every", self.checkpoint_every, 1, None, integer=True)
        if self.min_action_scale is not None:
            check_range("min_action_scale", self.min_action_scale, 0.0, 1.0)
        if self.init_from is not None and self.algorithm != "a3c":
            raise ConfigError(f"init_from continues an A3C run; algorithm {self.algorithm} cannot use it")
        if self.algorithm == "sac" and self.replay.capacity_episodes < self.sac.batch_size:
            raise ConfigError(
                f"replay.capacity_episodes (M={self.replay.capacity_episodes}) must be >= sac.batch_size "
                f"({self.sac.batch_size})"
            )
        if self.gp.enabled and (self.algorithm != "sac" or not self.semantic_state):
            raise ConfigError("gp.enabled needs algorithm: sac and semantic_state: true (the GP models z -> z')")
        for name in self.privileged_state:
            check_choice("privileged_state", name, list(PRIVILEGED_STATE))
        if self.privileged_state and (self.algorithm != "sac" or not self.semantic_state or self.gp.enabled):
            raise ConfigError("privileged_state extends the semantic state: it needs algorithm: sac, semantic_state: true "
                              "and gp.enabled: false (the GP imagines z alone, so it would drive through the obstacle)")
        spec = env_spec(self.env)
        if self.actor_noise.enabled and (self.algorithm != "sac" or not self.semantic_state):
            raise ConfigError("actor_noise perturbs the semantic state the actor reads: it needs algorithm: sac and "
                              "semantic_state: true")
        if self.gripper_opening and (not spec.moves_object or not self.semantic_state or self.algorithm != "sac"):
            raise ConfigError(f"gripper_opening adds the fingers to a pick-and-place semantic state: it needs algorithm: "
                              f"sac, semantic_state: true and an env that moves an object ({self.env} given)")
        if any(self.actor_noise.gripper) and not spec.moves_object:
            raise ConfigError(f"actor_noise.gripper: {self.env}'s semantic state has no gripper position beside z "
                              "(only pick and place has one); use actor_noise.achieved")
        if self.gp.enabled and spec.moves_object:
            raise ConfigError("gp.enabled: the GP models the gripper alone; pick and place moves an object by contact - "
                              "set gp.enabled: false")
        if self.demonstrations.episodes and (self.algorithm != "sac" or not spec.moves_object):
            raise ConfigError("demonstrations come from the scripted pick-and-place heuristic: algorithm sac on "
                              "binpick/FetchPickAndPlace-v0 only")
        goal_conditioned = self.env_kwargs.get("goal_conditioned", False)
        if self.algorithm in ("a3c", "dqn") and not spec.discrete_actions:
            raise ConfigError(f"algorithm {self.algorithm} learns with discrete actions: use env binpick/Arm2D-v0")
        if self.algorithm == "dqn" and goal_conditioned:
            raise ConfigError("algorithm dqn learns from Arm2D's images: remove env_kwargs.goal_conditioned")
        if self.algorithm == "a3c" and goal_conditioned != (self.a3c.encoder == "state"):
            raise ConfigError("a3c.encoder 'state' learns from Arm2D's state vector (env_kwargs: {goal_conditioned: true, "
                              "image: null}); the image encoders need env_kwargs.goal_conditioned unset")
        if self.algorithm in ("sac", "sb3_sac_her") and spec.discrete_actions:
            raise ConfigError(f"algorithm {self.algorithm} needs continuous actions; Arm2D takes a3c or dqn")
        if self.algorithm == "dqn" and self.env_kwargs.get("image_size", 64) < 36:
            raise ConfigError("algorithm dqn uses SB3's NatureCNN, which needs env_kwargs.image_size >= 36")
        if self.curriculum.stages and not spec.goal_area:
            raise ConfigError("curriculum widens Arm2D's goal area: use env binpick/Arm2D-v0")


def never_learns(config: RLConfig) -> str | None:
    """Why a run with this config would end before its first gradient step, or None. A warning, not
    an error: a run that only collects (a baseline, a smoke test) is allowed."""
    from binpick.envs import env_spec

    if config.algorithm == "a3c":
        return None
    if config.algorithm == "dqn":
        starts = config.dqn.learning_starts
    elif config.gp.enabled:
        horizon = config.env_kwargs.get("max_episode_steps", env_spec(config.env).max_episode_steps)
        starts = config.gp.warmup_episodes * horizon  # the GP needs its warm-up episodes first
    else:
        starts = config.sac.learning_starts
    if config.total_timesteps <= starts:
        return (f"total_timesteps {config.total_timesteps} ends before learning starts (after {starts} simulator steps): "
                "the policy will not learn")
    return None

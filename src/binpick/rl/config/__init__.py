"""RL run configuration: one YAML file per thesis experiment (``configs/rl/rl_*.yaml``): what every run
has (env, algorithm, steps, seed, evaluation, curriculum, replay) and a section per algorithm, each a
dataclass of its own in this package (``gp_her``: SAC, GP, demonstrations, actor noise; ``a3c``; ``dqn``).

Every field has a default; a YAML file names only what differs. Loading checks key names, types
and ranges, and says which key is wrong in one line.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from binpick.core.config import check_choice, check_range
from binpick.core.errors import ConfigError
from binpick.rl.config.a3c import A3CConfig
from binpick.rl.config.common import CurriculumConfig, EvalConfig, ReplayConfig
from binpick.rl.config.dqn import DQNConfig
from binpick.rl.config.gp_her import ActorNoiseConfig, DemonstrationConfig, GPConfig, SACConfig

ALGORITHMS = ("sac", "sb3_sac_her", "a3c", "dqn")  # each declared in binpick.rl.algorithms
MAX_SEED = 2**32 - 1  # NumPy's legacy seeding (used by SB3) takes 32-bit seeds


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

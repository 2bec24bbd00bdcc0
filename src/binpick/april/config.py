"""APRiL run configuration (``configs/april/april_*.yaml``): env and camera, data collection, perception
network, how the policy is trained and what it sees at deployment, evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from binpick.core.config import check_choice, check_range
from binpick.core.errors import ConfigError
from binpick.april.perception.autoencoder import PerceptionConfig


POLICY_MODES = ("semantic", "latent", "state_plus_latent")


@dataclass(frozen=True)
class CollectConfig:
    """Episodes with images and semantic state for perception (thesis §4.2): a random policy, or for
    pick and place the scripted heuristic (§4.5.3), since random arms almost never move the object."""

    episodes: int = 200
    seed: int = 0
    policy: str = "random"  # random | heuristic (pick and place only)
    noise: float = 0.2  # heuristic: Gaussian noise on its moves, so the images cover more states
    # Fetch envs: draw a new goal every this many steps (0: one goal per episode, the env's own).
    # The goal is only drawn, never touched, so any goal suits any arm pose; 300 episodes show
    # perception 300 goals but 13,000 arm poses, and its goal estimate is what fails on new goals.
    goal_every: int = 0

    def __post_init__(self) -> None:
        check_range("collect.episodes", self.episodes, 2, 1_000_000, integer=True)
        check_range("collect.goal_every", self.goal_every, 0, 1_000_000, integer=True)
        check_choice("collect.policy", self.policy, ["random", "heuristic"])
        check_range("collect.noise", self.noise, 0.0, 1.0)


@dataclass(frozen=True)
class PerceptionTraining:
    epochs: int = 20
    batch_size: int = 64
    learning_rate: float = 1e-3
    # constant, or cosine: the rate decays to 0 over the run, for long runs whose loss still falls
    # at a constant rate (pick and place's s̄ loss was still dropping steeply after 30 epochs)
    schedule: str = "constant"

    def __post_init__(self) -> None:
        check_range("perception_training.epochs", self.epochs, 1, 10_000, integer=True)
        check_choice("perception_training.schedule", self.schedule, ["constant", "cosine"])
        check_range("perception_training.batch_size", self.batch_size, 1, 65_536, integer=True)
        check_range("perception_training.learning_rate", self.learning_rate, 0.0, 1.0, low_inclusive=False)


@dataclass(frozen=True)
class PolicyConfig:
    """How the policy learns and what it sees.

    - ``semantic`` (m = n, Eq 4.8): trained on the ground-truth s̄ with GP + HER (``rl_config``),
      deployed on φ_enc(I).
    - ``latent`` (Eq 4.9): SAC on φ_enc(I) in the simulator. With ``pretrain: true`` (m < n) it
      first trains on s̄ like ``semantic``, then widens the first layers for the n − m free features
      and fine-tunes; without, it learns from scratch (the unconditioned baseline when ω = 0).
    - ``state_plus_latent``: ground-truth s̄ plus the free latent (like Finn et al.).
    """

    mode: str = "semantic"
    rl_config: str = "configs/rl/rl_fetchreach_gp_her.yaml"  # the semantic-state run (GP + HER)
    state_run: str | None = None  # a finished `binpick rl` run to use as the state policy instead of training one
    pretrain: bool = True
    finetune_steps: int = 20_000  # simulator steps with images for latent / state_plus_latent
    learning_starts: int = 1000
    # how the latent policy learns on φ_enc(I): "sac" (plain SB3 SAC from the widened weights) or
    # "distill" (DAgger: it acts, the state policy labels each visited image with its action on the
    # true s̄, the actor regresses onto every label so far), which keeps what the state policy knows
    finetune: str = "sac"
    distill_every: int = 500  # distill: simulator steps between regressions (the first round follows the teacher)
    distill_gradient_steps: int = 300  # distill: actor updates per round, batches of 256
    # distill: train the encoder too (action regression + its own L_VP, batches of 64), so the free
    # features learn what the teacher's actions depend on rather than only what reconstruction needs
    distill_encoder: bool = False
    # who labels the images in distill: the trained "state_policy", or "detour", a scripted teacher
    # that knows where FetchReachObstacle's box is (binpick.rl.common.heuristic.ObstacleDetour)
    teacher: str = "state_policy"

    def __post_init__(self) -> None:
        check_choice("policy.mode", self.mode, POLICY_MODES)
        check_choice("policy.teacher", self.teacher, ["state_policy", "detour"])
        check_choice("policy.finetune", self.finetune, ["sac", "distill"])
        check_range("policy.distill_every", self.distill_every, 1, 100_000_000, integer=True)
        check_range("policy.distill_gradient_steps", self.distill_gradient_steps, 0, 100_000_000, integer=True)
        check_range("policy.finetune_steps", self.finetune_steps, 0, 100_000_000, integer=True)
        check_range("policy.learning_starts", self.learning_starts, 0, 100_000_000, integer=True)


@dataclass(frozen=True)
class RefineConfig:
    """Perception trained further on the state policy's own episodes (thesis §4.5.2: "the data from the
    random policy and any episodes collected using the simulator are used to train the perception
    network"): random walks rarely show the poses a good policy visits."""

    episodes: int = 0  # 0: no refinement (per round)
    epochs: int = 10
    action_noise: float = 0.2  # Gaussian noise on the policy's actions, for varied views
    # what the policy acts on while the images are recorded: the true s̄ ("state"), or, for
    # policy.mode semantic, φ_enc(I) from the current perception ("pixels"), which visits the states
    # where perception is wrong and the deployed policy drifts (DAgger for the perception network)
    act_on: str = "state"
    rounds: int = 1  # pixels: collect with the latest perception, retrain, repeat

    def __post_init__(self) -> None:
        check_range("refine.episodes", self.episodes, 0, 1_000_000, integer=True)
        check_choice("refine.act_on", self.act_on, ["state", "pixels"])
        check_range("refine.rounds", self.rounds, 1, 1000, integer=True)
        check_range("refine.epochs", self.epochs, 1, 10_000, integer=True)
        check_range("refine.action_noise", self.action_noise, 0.0, 2.0)


@dataclass(frozen=True)
class AprilEval:
    episodes: int = 100
    seed: int = 20_000

    def __post_init__(self) -> None:
        check_range("eval.episodes", self.episodes, 1, 100_000, integer=True)


@dataclass(frozen=True)
class AprilConfig:
    name: str = "april"
    env: str = "binpick/FetchReach-v0"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    image: str = "grey"  # the thesis used grey-scale for Fetch Reach, RGB for pick and place
    image_size: int = 64
    seed: int = 0
    collect: CollectConfig = field(default_factory=CollectConfig)
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    perception_training: PerceptionTraining = field(default_factory=PerceptionTraining)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    eval: AprilEval = field(default_factory=AprilEval)

    def __post_init__(self) -> None:
        from binpick.envs import ENVS, env_spec

        spec = env_spec(self.env)
        if not spec.goal_conditioned or spec.discrete_actions:
            raise ConfigError(f"APRiL needs a goal-conditioned env with continuous actions, not {spec.env_id}; "
                              f"choose one of {', '.join(s.env_id for s in ENVS.values() if s.goal_conditioned)}")
        object.__setattr__(self, "env", spec.env_id)  # frozen: normalised once
        check_choice("image", self.image, ["rgb", "grey"])
        if self.collect.goal_every and "Fetch" not in spec.env_id:
            raise ConfigError(f"collect.goal_every redraws the goal of the Fetch envs; {self.env} keeps its own")
        if self.collect.policy == "heuristic" and not spec.moves_object:
            raise ConfigError(f"collect.policy heuristic is the pick-and-place script; {self.env} collects with random")
        check_range("image_size", self.image_size, 64, 512, integer=True)
        if self.image_size % 64:
            raise ConfigError(f"image_size must be a multiple of 64 (6 stride-2 layers), got {self.image_size}")
        keypoints = self.perception.goal_keypoints
        if keypoints:
            views = self.views
            if "Fetch" not in spec.env_id or keypoints != len(views):
                raise ConfigError(f"perception.goal_keypoints: one per camera view of a Fetch env ({len(views)} in "
                                  f"env_kwargs.views here), got {keypoints}")
        m, n = self.perception.conditioned, self.perception.latent
        if self.policy.mode == "semantic" and (m != n or self.perception.omega == 0):
            raise ConfigError(f"policy.mode semantic deploys on the conditioned latent alone: it needs "
                              f"perception.conditioned == perception.latent (m={m}, n={n}) and omega > 0")
        if self.policy.mode == "state_plus_latent" and m == n:
            raise ConfigError("policy.mode state_plus_latent needs free latent features: perception.conditioned < latent")
        detour = self.policy.teacher == "detour"
        if detour and (self.policy.mode != "latent" or self.policy.finetune != "distill" or self.policy.pretrain
                       or spec.env_id != "binpick/FetchReachObstacle-v0"):
            raise ConfigError("policy.teacher detour is a scripted teacher for binpick/FetchReachObstacle-v0 students: "
                              "it needs policy.mode latent, finetune distill and pretrain: false")
        if self.policy.distill_encoder and (self.policy.mode != "latent" or self.policy.finetune != "distill"):
            raise ConfigError("policy.distill_encoder trains the encoder on the teacher's labels: it needs policy.mode "
                              "latent and finetune distill")
        if self.policy.finetune == "distill" and self.policy.mode == "latent" and not self.policy.pretrain and not detour:
            raise ConfigError("policy.finetune distill learns from the state policy: it needs policy.pretrain: true")
        if self.refine.episodes and self.refine.act_on == "pixels" and self.policy.mode != "semantic":
            raise ConfigError("refine.act_on pixels deploys the state policy on φ_enc(I): it needs policy.mode semantic")
        if self.refine.episodes and self.policy.mode == "latent" and not self.policy.pretrain:
            raise ConfigError("refine rolls the state policy: it needs policy.mode semantic, state_plus_latent, or pretrain: true")
        if self.policy.mode != "latent" or self.policy.pretrain:
            if not Path(self.policy.rl_config).is_file():
                raise ConfigError(f"policy.rl_config: no such file {self.policy.rl_config!r}")


    @property
    def views(self) -> list[str]:
        """The observation cameras (``env_kwargs.views``; the Fetch envs' default is the workspace view)."""
        views = self.env_kwargs.get("views", ["workspace"])
        return [views] if isinstance(views, str) else list(views)

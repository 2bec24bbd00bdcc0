"""Settings every RL algorithm shares: the episode replay with HER, the goal-area curriculum and evaluation."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from binpick.core.config import check_choice, check_range
from binpick.core.errors import ConfigError


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

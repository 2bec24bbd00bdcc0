"""The goal-area curriculum of thesis §3.2 (Fig 3.4): where the goal area stands, and an SB3 callback.

The schedule is :class:`binpick.rl.config.common.CurriculumConfig`. With ``advance: steps`` the area is a
function of the simulator step (ramps and holds). With ``advance: converged`` it depends on how
training goes — the thesis widens the area only once the agent has re-converged at the current one
— so :class:`CurriculumProgress` keeps that state, and the run's checkpoints keep it too. A3C's
trainer drives it between episodes itself; SB3 learners through :class:`GoalAreaCurriculum`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from binpick.core.errors import InputFileError
from binpick.rl.config.common import CurriculumConfig


class CurriculumProgress:
    """The goal area over a run, advanced by steps or by re-convergence (``schedule.advance``).

    In ``converged`` mode stage i ramps from stage i-1's area to its own over ``ramp_steps``, then
    holds it for at least ``hold_steps`` and until the mean length of the last ``window`` training
    episodes at that area is within ``tolerance`` (relative) of the ``window`` before; then stage
    i+1 begins. Episodes that ran at another area (during a ramp) do not count.
    """

    def __init__(self, schedule: CurriculumConfig) -> None:
        self.schedule = schedule
        self.stage = 0
        self.stage_start = 0
        self.lengths: list[int] = []
        self.advanced_at: list[int] = []  # the step each stage after the first began

    @property
    def converged_mode(self) -> bool:
        return self.schedule.advance == "converged"

    def goal_area(self, step: int) -> float | None:
        """The area at ``step`` (None: no curriculum, the env keeps its own)."""
        if not self.schedule.stages:
            return None
        if not self.converged_mode:
            return self.schedule.goal_area(step)
        stage = self.schedule.stages[self.stage]
        previous = self.schedule.stages[self.stage - 1].area if self.stage > 0 else 0.0
        into = step - self.stage_start
        if stage.ramp_steps and into < stage.ramp_steps:
            return previous + (stage.area - previous) * into / stage.ramp_steps
        return stage.area

    def record(self, step: int, lengths: list[int], area: float) -> bool:
        """Count finished training episodes that ran at ``area``; True when the next stage began."""
        if not self.converged_mode or self.stage >= len(self.schedule.stages) - 1:
            return False
        stage = self.schedule.stages[self.stage]
        if abs(area - stage.area) > 1e-9:
            return False
        window = self.schedule.window
        self.lengths = (self.lengths + [int(n) for n in lengths])[-2 * window:]
        held = step - self.stage_start - stage.ramp_steps
        if held < stage.hold_steps or len(self.lengths) < 2 * window:
            return False
        before, recent = float(np.mean(self.lengths[:window])), float(np.mean(self.lengths[window:]))
        if abs(recent - before) > self.schedule.tolerance * before:
            return False
        self.stage, self.stage_start, self.lengths = self.stage + 1, step, []
        self.advanced_at.append(step)
        return True

    def state_dict(self) -> dict[str, Any]:
        return {"stage": self.stage, "stage_start": self.stage_start, "lengths": list(self.lengths),
                "advanced_at": list(self.advanced_at)}

    def load_state_dict(self, state: dict[str, Any] | None) -> None:
        """Restore from a checkpoint (a run saved before this state existed starts at stage 0)."""
        if not state:
            return
        try:
            self.stage = min(int(state.get("stage", 0)), max(len(self.schedule.stages) - 1, 0))
            self.stage_start = int(state.get("stage_start", 0))
            self.lengths = [int(n) for n in state.get("lengths", [])]
            self.advanced_at = [int(n) for n in state.get("advanced_at", [])]
        except (AttributeError, TypeError, ValueError) as error:
            raise InputFileError(f"checkpoint's curriculum state is damaged ({error})") from None


class GoalAreaCurriculum(BaseCallback):
    """Sets every training env's goal area from the curriculum as simulator steps go by."""

    def __init__(self, schedule: CurriculumConfig, progress: CurriculumProgress | None = None) -> None:
        super().__init__()
        self.progress = progress or CurriculumProgress(schedule)
        self.area: float | None = None

    def _on_step(self) -> bool:
        if self.area is not None:  # SB3's Monitor reports each finished episode in its info
            lengths = [info["episode"]["l"] for info in self.locals.get("infos", []) if "episode" in info]
            if lengths:
                self.progress.record(self.num_timesteps, lengths, self.area)
        area = self.progress.goal_area(self.num_timesteps)
        if area is not None and area != self.area:
            self.area = area
            self.training_env.env_method("set_goal_area", area)  # takes effect at each env's next reset
            self.logger.record("curriculum/goal_area", area)
        return True

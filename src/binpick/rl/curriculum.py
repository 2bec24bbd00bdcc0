"""The goal-area curriculum of thesis §3.2 (Fig 3.4) as a Stable-Baselines3 callback.

The schedule itself is :class:`binpick.rl.config.CurriculumConfig` (ramps and holds over simulator
steps); A3C workers apply it between episodes themselves, SB3 learners through this callback.
"""

from __future__ import annotations

from stable_baselines3.common.callbacks import BaseCallback

from binpick.rl.config import CurriculumConfig


class GoalAreaCurriculum(BaseCallback):
    """Sets every training env's goal area from the schedule as simulator steps go by."""

    def __init__(self, schedule: CurriculumConfig) -> None:
        super().__init__()
        self.schedule = schedule
        self.area: float | None = None

    def _on_step(self) -> bool:
        area = self.schedule.goal_area(self.num_timesteps)
        if area is not None and area != self.area:
            self.area = area
            self.training_env.env_method("set_goal_area", area)  # takes effect at each env's next reset
            self.logger.record("curriculum/goal_area", area)
        return True

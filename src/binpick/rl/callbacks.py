"""The SB3 callbacks of a run: evaluation on seeded episodes, checkpoints, progress, and the metrics they
keep (steps to the success threshold, evaluations, wall time)."""

from __future__ import annotations

from dataclasses import dataclass, field
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

from binpick.core.runs import Task
from binpick.rl.common.evaluate import evaluate_policy
from binpick.rl.common.replay import EpisodeReplayBuffer
from binpick.rl.config import RLConfig
from binpick.rl.envs import make_env

if TYPE_CHECKING:
    from binpick.rl.gp_her.agents import GPImagination


@dataclass
class Metrics:
    """What a run reports: evaluations over simulator steps and the thesis's counts."""

    evaluations: list[dict[str, float]] = field(default_factory=list)
    sim_steps_to_threshold: int | None = None
    gradient_steps_to_5_actions: int | None = None  # thesis Table 3.4: iterations until < 5 actions
    demo_episodes: int = 0  # scripted demonstrations (simulator episodes outside SB3's step count)
    demo_steps: int = 0
    bc_final_loss: float | None = None
    wall_seconds: float = 0.0
    worker_restarts: int = 0  # simulator processes (Ray actors) that died and were started again, each losing its episode

    def to_dict(self, config: RLConfig, model: BaseAlgorithm, gp: GPImagination | None) -> dict[str, Any]:
        buffer = model.replay_buffer
        last = self.evaluations[-1] if self.evaluations else {}
        data = {"name": config.name, "env": config.env, "algorithm": config.algorithm, "seed": config.seed,
                "sim_steps": int(model.num_timesteps), "sim_steps_to_threshold": self.sim_steps_to_threshold,
                "success_threshold": config.eval.success_threshold, "final_success": last.get("success_rate"),
                "final_avg_actions": last.get("mean_length"), "final_std_actions": last.get("std_length"),
                "gradient_steps": int(model._n_updates), "wall_seconds": round(self.wall_seconds, 1),
                "evaluations": self.evaluations}
        data["gradient_steps_to_5_actions"] = self.gradient_steps_to_5_actions
        data.update(demo_episodes=self.demo_episodes, demo_steps=self.demo_steps, bc_final_loss=self.bc_final_loss,
                    worker_restarts=self.worker_restarts)
        if isinstance(buffer, EpisodeReplayBuffer):
            data.update(sim_episodes=buffer.added["real"], her_episodes=buffer.added["her"],
                        imagined_episodes=buffer.added["imagined"], episodes_when_training_started=buffer.added_when_ready)
        if gp is not None:
            data.update(gp_fits=gp.fits, gp_steps=gp.imagined_steps)
        return data


def stopped_early(config: RLConfig, metrics: Metrics) -> bool:
    """True when the last ``stop_after_successes`` evaluations all passed: training ends there, and a
    resumed run that ended so must not train on to ``total_timesteps``."""
    wanted, threshold = config.eval.stop_after_successes, config.eval.success_threshold
    last = metrics.evaluations[-wanted:] if wanted else []
    return bool(wanted) and len(last) == wanted and all(e["success_rate"] >= threshold for e in last)


class Evaluate(BaseCallback):
    """Every ``config.eval.every`` simulator steps: seeded evaluation episodes, logged and kept."""

    def __init__(self, config: RLConfig, metrics: Metrics) -> None:
        super().__init__()
        self.config, self.metrics = config, metrics
        self.env = make_env(config)
        self._next = config.eval.every

    def _on_training_start(self) -> None:
        self._next = next_multiple(self.model.num_timesteps, self.config.eval.every)  # right after a resume too

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:  # (N simulators: the first vector step at or past the multiple)
            self._next = next_multiple(self.num_timesteps, self.config.eval.every)
            self.evaluate()
            if stopped_early(self.config, self.metrics):
                return False  # SB3 ends learn() when a callback returns False
        return True

    def evaluate(self) -> dict[str, float]:
        steps = int(self.model.num_timesteps)
        result = evaluate_policy(self.model, self.env, episodes=self.config.eval.episodes, seed=self.config.eval.seed)
        row = {"sim_steps": steps, "gradient_steps": int(self.model._n_updates), "success_rate": result.success_rate,
               "mean_length": result.mean_length, "std_length": result.std_length}
        buffer = self.model.replay_buffer
        if isinstance(buffer, EpisodeReplayBuffer):  # what it took so far (thesis Tables 3.3-3.4)
            row.update(sim_episodes=buffer.added["real"], imagined_episodes=buffer.added["imagined"],
                       her_episodes=buffer.added["her"])
        self.metrics.evaluations.append(row)
        if self.metrics.sim_steps_to_threshold is None and result.success_rate >= self.config.eval.success_threshold:
            self.metrics.sim_steps_to_threshold = steps
        if self.metrics.gradient_steps_to_5_actions is None and result.mean_length < 5:
            self.metrics.gradient_steps_to_5_actions = int(self.model._n_updates)
        self.logger.record("eval/success_rate", result.success_rate)
        self.logger.record("eval/avg_actions", result.mean_length)
        self.logger.dump(steps)
        return row


class Checkpoint(BaseCallback):
    """Every ``config.checkpoint_every`` simulator steps: ``save()`` (the trainer's whole checkpoint)."""

    def __init__(self, config: RLConfig, save: Callable[[], Any]) -> None:
        super().__init__()
        self.config, self.save = config, save
        self._next = config.checkpoint_every

    def _on_training_start(self) -> None:
        self._next = next_multiple(self.model.num_timesteps, self.config.checkpoint_every)

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            self._next = next_multiple(self.num_timesteps, self.config.checkpoint_every)
            self.save()
        return True


class ReportProgress(BaseCallback):
    """Simulator steps and the latest evaluation, to the run's :class:`~binpick.core.runs.Task`."""

    def __init__(self, task: Task, metrics: Metrics) -> None:
        super().__init__()
        self.task, self.metrics = task, metrics

    def _on_step(self) -> bool:
        last = self.metrics.evaluations[-1] if self.metrics.evaluations else None
        self.task.update(self.num_timesteps, status=f"success {last['success_rate']:.0%}" if last else "")
        return True


def next_multiple(steps: int, every: int) -> int:
    """The first multiple of ``every`` after ``steps``: when a periodic job next runs."""
    return (int(steps) // every + 1) * every

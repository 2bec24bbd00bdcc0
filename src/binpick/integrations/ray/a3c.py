"""A3C with its workers as Ray actors (thesis §3.1.2 over §6.1's distributed simulators), from the same
RL config and into the same run folder as a local run (``binpick train CONFIG --address ...``).

Each actor owns a simulator and an :class:`~binpick.rl.a3c.networks.A3CWorker` built as a local worker is
(:func:`binpick.rl.a3c.train.make_worker`: encoder, state head, policy input, layers, reward scale):
given the global weights and the curriculum's goal area it plays up to ``n_steps`` and returns
gradients (Eq 3.5-3.7). The learner on the driver applies whichever gradients arrive first and hands
out step budgets so that no rollout crosses the next evaluation, checkpoint or the end: evaluations
fall on exact multiples of ``eval.every`` and the run ends at exactly ``total_timesteps``. A worker that
dies is restarted by Ray (its process seeded anew); the steps of its lost rollout are handed out
again, so the run's steps and evaluations are those of a run without the fault. Curriculum,
TensorBoard, evaluations, checkpoints and outputs are the local trainer's own
(:meth:`binpick.rl.a3c.train.A3CTrainer.take`); ``--resume`` continues either way.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

from binpick.core.errors import WorkerError
from binpick.integrations.ray.actors import RestartingActors

FAILING_S = 120.0  # a worker whose rollouts all fail for this long (it cannot start, or dies each time) fails the run
WAIT_S = 600.0  # no rollout back from any worker for this long fails the run (a restart that cannot be placed)


class A3CActor:
    """One rollout worker of an A3C run, in its own process."""

    def __init__(self, config, rank: int, state_size: int, wrap_env, start_step: int) -> None:
        os.environ.setdefault("MUJOCO_GL", "egl")
        import ray
        import torch

        from binpick.rl.a3c.train import make_worker

        torch.set_num_threads(1)
        # a process Ray started again after a death plays other episodes than the one it replaces
        restarts = 1 + os.getpid() % 997 if ray.get_runtime_context().was_current_actor_reconstructed else 0
        self.worker = make_worker(config, rank, state_size, wrap_env, start_step, restarts)
        self.area = -1.0

    def pid(self) -> int:
        return os.getpid()

    def gradients(self, weights, area: float, max_steps: int) -> tuple[list, int, tuple]:
        """Gradients of a rollout of at most ``max_steps`` in goal area ``area`` (from the next episode)."""
        from binpick.rl.a3c.train import rollout_record, set_goal_area

        self.area = set_goal_area(self.worker, area, self.area)
        gradients, stats = self.worker.compute_gradients(weights, max_steps)
        return gradients, stats.steps, rollout_record(stats, self.area)


def learn_on_ray(address: str | None = None, on_update: Callable[[Any, RestartingActors], None] | None = None):
    """The ``learn`` of :meth:`A3CTrainer.run <binpick.rl.a3c.train.A3CTrainer.run>` that plays the run's
    ``a3c.workers`` rollouts on Ray actors (``address`` None or ``local``: a private cluster on this
    machine, 127.0.0.1 only). ``on_update(trainer, actors)`` runs after every applied rollout."""

    def learn(trainer, task) -> None:
        _learn(trainer, task, None if address == "local" else address, on_update)

    return learn


def _learn(trainer, task, address: str | None, on_update) -> None:
    import ray

    from binpick.rl.a3c.networks import apply_gradients

    config = trainer.config
    total, n_steps = config.total_timesteps, config.a3c.n_steps
    arguments = [(config, rank, trainer.state_size, trainer.wrap_env, trainer.steps) for rank in range(config.a3c.workers)]
    pool = RestartingActors(A3CActor, arguments, address)
    log = trainer.open_log()
    weights = ray.put(trainer.model.state_dict())
    area = trainer.goal_area(trainer.steps)
    budgets: dict[int, int] = {}  # steps handed to each busy worker
    failing_since: dict[int, float] = {}  # workers whose rollouts fail, since when (cleared by a success)
    trainer.metrics.setdefault("worker_restarts", 0)
    trainer.metrics.setdefault("lost_rollouts", 0)
    restarts_before = trainer.metrics["worker_restarts"]
    resume = f"{trainer.run_dir} resumes from its last checkpoint (binpick train --resume RUN --address ...)"
    try:
        while trainer.steps < total:
            boundary = min(total, log.next_eval, log.next_save)  # no rollout crosses an evaluation, a checkpoint or the end
            room = boundary - trainer.steps - sum(budgets.values())
            for index in pool.idle():
                grant = min(n_steps, room)
                if grant <= 0:
                    break
                pool.start(index, pool.actors[index].gradients.remote(weights, area, grant))
                budgets[index], room = grant, room - grant
            if not pool.in_flight:
                raise WorkerError(f"A3C on Ray: no rollout to wait for at step {trainer.steps:,} (boundary {boundary:,})")
            try:
                index, result, ok = pool.next_result(timeout=WAIT_S)
            except TimeoutError:
                raise WorkerError(f"A3C on Ray: no rollout came back within {WAIT_S:.0f} s at step {trainer.steps:,} "
                                  f"(a worker that cannot be restarted?); {resume}") from None
            budgets.pop(index, None)
            if not ok:  # the worker died with its rollout: Ray restarts it, the steps are handed out again
                trainer.metrics["lost_rollouts"] += 1
                trainer.metrics["worker_restarts"] = restarts_before + pool.deaths
                since = failing_since.setdefault(index, time.monotonic())
                if time.monotonic() - since > FAILING_S:
                    raise WorkerError(f"A3C on Ray: every rollout of worker {index} failed for {FAILING_S:.0f} s at step "
                                      f"{trainer.steps:,} (its simulator cannot start there?); {resume}")
                continue
            failing_since.pop(index, None)
            gradients, steps, record = result
            apply_gradients(trainer.model, trainer.optimizer, gradients)
            weights = ray.put(trainer.model.state_dict())
            trainer.steps += steps
            area = trainer.take(record, log, task)
            if on_update is not None:
                on_update(trainer, pool)
    finally:
        pool.close()
        log.close()
    trainer.metrics["wall_seconds"] = log.elapsed()

"""Run A3C (thesis §3.1.2) with real worker processes, the goal-area curriculum (§3.2) and the same
run folder, checkpoints and outputs as :mod:`binpick.rl.train`.

The main process owns the global network (in shared memory), the shared Adam, a shared step
counter and the current goal area; it drains finished-episode statistics from a queue, evaluates,
checkpoints atomically and plots. Workers run :class:`~binpick.rl.a3c.networks.A3CWorker` in a loop.
"""

from __future__ import annotations

import multiprocessing
import queue
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.tensorboard import SummaryWriter

from binpick.core import tensorfile
from binpick.core.config import load_run_config
from binpick.core.errors import ConfigError, WorkerError
from binpick.core.files import atomic_write_json, read_json_object, require_fields
from binpick.core.processes import worker_context
from binpick.rl.a3c.envs import EnvWrapper, make_a3c_env, semantic_state_size
from binpick.rl.a3c.networks import A3CWorker, ActorCritic, SharedAdam, apply_gradients
from binpick.rl.a3c.policy import A3C_FILE, FORMAT, SampledPolicy, read_a3c_checkpoint
from binpick.core.runs import SILENT, RunCallback, Task, commit_checkpoint, latest_checkpoint, new_run, removed_on_error
from binpick.rl.config import RLConfig
from binpick.rl.common.curriculum import CurriculumProgress
from binpick.rl.common.evaluate import evaluate_policy


def make_worker(config: RLConfig, rank: int, state_size: int, wrap_env: EnvWrapper | None = None, start_step: int = 0,
                restarts: int = 0) -> A3CWorker:
    """One A3C worker of the run (its simulator and its copy of the network), seeded by its rank, the
    step it starts at and how often its process was started again, so no two play the same episodes."""
    a3c = config.a3c
    env_shape = make_a3c_env(config, wrap_env).observation_space.shape
    return A3CWorker(lambda: make_a3c_env(config, wrap_env), env_shape, 6,
                     seed=config.seed * 1000 + rank * 7919 + start_step + restarts * 1_000_003,
                     n_steps=a3c.n_steps, gamma=a3c.gamma, entropy_beta=a3c.entropy_beta,
                     value_coef=a3c.value_coef, max_grad_norm=a3c.max_grad_norm, reward_scale=a3c.reward_scale,
                     encoder=a3c.encoder, state_weight=a3c.state_weight, state_size=state_size,
                     state_key=a3c.state_key, policy_input=a3c.policy_input, detach_perception=a3c.detach_perception,
                     hidden_layers=a3c.hidden_layers)


def set_goal_area(worker: A3CWorker, area: float, current: float) -> float:
    """The worker's goal area becomes ``area`` between episodes only (the one it plays now otherwise)."""
    if area != current and worker._episode_steps == 0:
        worker.env.unwrapped.set_goal_area(area)
        worker.reset_env()
        return area
    return current


def _worker(rank: int, config: RLConfig, model: ActorCritic, optimizer: SharedAdam, counter, goal_area,
            stats_queue, stop, wrap_env: EnvWrapper | None = None) -> None:
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the trainer stops its workers
    torch.set_num_threads(1)
    worker = make_worker(config, rank, model.state_size, wrap_env, counter.value)
    area, trainer = -1.0, multiprocessing.parent_process()
    while not stop.is_set() and counter.value < config.total_timesteps:
        if trainer is not None and not trainer.is_alive():  # killed (daemon workers outlive a SIGKILL): nobody saves this
            return
        area = set_goal_area(worker, goal_area.value, area)
        gradients, stats = worker.compute_gradients(model.state_dict())
        apply_gradients(model, optimizer, gradients)
        with counter.get_lock():
            counter.value += stats.steps
        stats_queue.put(rollout_record(stats, area))


def rollout_record(stats, area: float) -> tuple:
    """What the trainer learns of one rollout: finished episodes, losses and the goal area it played in."""
    return (stats.finished_lengths, stats.finished_successes, stats.policy_loss, stats.value_loss, stats.entropy,
            stats.state_loss, area)


def _source_checkpoint(config: RLConfig) -> Path:
    """The checkpoint named by ``config.init_from``, checked to be an A3C run on the same env."""
    source = Path(config.init_from)
    if not (source / "config.yaml").is_file():
        raise ConfigError(f"init_from: {str(source)!r} is not a run folder (no config.yaml)")
    settings = load_run_config(RLConfig, source)
    if settings.algorithm != "a3c" or settings.env != config.env:
        raise ConfigError(f"init_from: run {source} is {settings.algorithm} on {settings.env}, "
                          f"this run is a3c on {config.env}")
    checkpoint = latest_checkpoint(source / "checkpoints")
    if checkpoint is None:
        raise ConfigError(f"init_from: run {source} has no checkpoint yet")
    return checkpoint


class TrainingLog:
    """What one training session keeps beside the run's state: TensorBoard, its clock (carried over
    from earlier sessions), the episode lengths seen, and the next evaluation and checkpoint steps."""

    def __init__(self, run_dir: Path, steps: int, wall_seconds: float, eval_every: int, save_every: int) -> None:
        self.writer = SummaryWriter(str(run_dir / "tb"))
        self.started = time.perf_counter() - wall_seconds
        self.next_eval = (steps // eval_every + 1) * eval_every
        self.next_save = (steps // save_every + 1) * save_every
        self.lengths: list[int] = []

    def elapsed(self) -> float:
        return time.perf_counter() - self.started

    def close(self) -> None:
        self.writer.close()


class A3CTrainer:
    """Owns a run folder for an A3C run; ``run()`` trains to ``total_timesteps`` and can resume."""

    TASK = "rl"  # its kind of job (binpick.core.jobs)

    def __init__(self, config: RLConfig, run_dir: Path, wrap_env: EnvWrapper | None = None) -> None:
        self.config, self.run_dir, self.wrap_env = config, Path(run_dir), wrap_env
        self.ckpt_dir = self.run_dir / "checkpoints"
        env = make_a3c_env(config, wrap_env)
        self.observation_shape = env.observation_space.shape
        self.base_area = float(env.unwrapped.goal_area)
        env.close()
        torch.manual_seed(config.seed)
        self.state_size = semantic_state_size(config, wrap_env)
        self.model = ActorCritic(self.observation_shape, 6, self.config.a3c.encoder, self.state_size, self.config.a3c.policy_input,
                                 self.config.a3c.detach_perception, self.config.a3c.hidden_layers)
        self.model.share_memory()
        self.optimizer = SharedAdam(self.model.parameters(), lr=config.a3c.learning_rate)
        self.steps = 0
        self.metrics: dict[str, Any] = {"evaluations": [], "episodes": 0, "wall_seconds": 0.0}
        self.curriculum = CurriculumProgress(config.curriculum)

    @classmethod
    def new(cls, config: RLConfig, runs_root: Path = Path("runs"), wrap_env: EnvWrapper | None = None) -> A3CTrainer:
        """A fresh run; with ``init_from`` it starts where that run's latest checkpoint ended.

        The thesis's curriculum (§3.2) starts from the network trained on the single goal (§3.1.3):
        weights, optimiser state, the step count and the evaluation history carry over, so the
        curriculum schedule and the budget count the single-goal steps too.
        """
        source = None if config.init_from is None else _source_checkpoint(config)
        with removed_on_error(new_run(runs_root, config, cls.TASK)) as run_dir:
            trainer = cls(config, run_dir, wrap_env)
            if source is not None:
                trainer.load_checkpoint(source)
                trainer.curriculum = CurriculumProgress(config.curriculum)  # this run's own schedule starts here
            return trainer

    @classmethod
    def resume(cls, run_dir: Path, wrap_env: EnvWrapper | None = None) -> A3CTrainer:
        """Continue run folder ``run_dir`` from its latest checkpoint (or from zero if it has none); a run
        made with ``wrap_env`` needs the same one again."""
        trainer = cls(load_run_config(RLConfig, run_dir), Path(run_dir), wrap_env)
        trainer.load_checkpoint()
        return trainer

    @property
    def steps_done(self) -> int:
        return self.steps

    def goal_area(self, step: int) -> float:
        scheduled = self.curriculum.goal_area(step)
        return self.base_area if scheduled is None else scheduled

    # ------------------------------------------------------------------ checkpoints
    def save_checkpoint(self) -> Path:
        def write(folder: Path) -> None:
            tensorfile.save(folder / A3C_FILE, FORMAT, state={"model": self.model.state_dict(), "optimizer": self.optimizer.state_dict()},
                            meta={"observation_shape": list(self.observation_shape), "env": self.config.env,
                                  "encoder": self.config.a3c.encoder, "state_size": self.state_size,
                                  "policy_input": self.config.a3c.policy_input,
                                  "hidden_layers": self.config.a3c.hidden_layers})
            atomic_write_json(folder / "state.json", {"steps": self.steps, "metrics": self.metrics, "env": self.config.env,
                                                      "curriculum": self.curriculum.state_dict()})

        return commit_checkpoint(self.ckpt_dir, self.steps, write)

    def load_checkpoint(self, checkpoint: Path | None = None) -> None:
        checkpoint = latest_checkpoint(self.ckpt_dir) if checkpoint is None else checkpoint
        if checkpoint is None:
            return
        state, meta = read_a3c_checkpoint(checkpoint)
        if tuple(meta["observation_shape"]) != tuple(self.observation_shape):
            raise ConfigError(f"checkpoint {checkpoint} sees observations of shape {tuple(meta['observation_shape'])}, "
                              f"this run's env gives {tuple(self.observation_shape)}")
        if str(meta.get("encoder", "flatten")) != self.config.a3c.encoder:
            raise ConfigError(f"checkpoint {checkpoint} has a3c.encoder {meta.get('encoder', 'flatten')!r}, "
                              f"this run's config says {self.config.a3c.encoder!r}")
        if str(meta.get("policy_input", "features")) != self.config.a3c.policy_input:
            raise ConfigError(f"checkpoint {checkpoint} has a3c.policy_input {meta.get('policy_input', 'features')!r}, "
                              f"this run's config says {self.config.a3c.policy_input!r}")
        if int(meta.get("hidden_layers", 1)) != self.config.a3c.hidden_layers:
            raise ConfigError(f"checkpoint {checkpoint} has a3c.hidden_layers {meta.get('hidden_layers', 1)}, "
                              f"this run's config says {self.config.a3c.hidden_layers}")
        if int(meta.get("state_size", 0)) != self.state_size:
            raise ConfigError(f"checkpoint {checkpoint} was trained {'with' if meta.get('state_size') else 'without'} "
                              f"the auxiliary state head, this run's config (a3c.state_weight) says otherwise")
        tensorfile.restore({"model": self.model, "optimizer": self.optimizer}, state, f"A3C checkpoint {checkpoint}")
        for group in self.optimizer.state.values():  # load_state_dict replaces tensors: share them again
            for value in group.values():
                if torch.is_tensor(value):
                    value.share_memory_()
        progress = read_json_object(checkpoint / "state.json", "A3C checkpoint state", {"steps": int, "metrics": dict})
        require_fields(progress["metrics"], {"evaluations": list, "episodes": int, "wall_seconds": (int, float)},
                       f"A3C checkpoint state {str(checkpoint / 'state.json')!r}")
        self.steps, self.metrics = progress["steps"], progress["metrics"]
        self.curriculum.load_state_dict(progress.get("curriculum"))

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, area: float) -> dict[str, float]:
        env = make_a3c_env(self.config, self.wrap_env)
        env.unwrapped.set_goal_area(area)
        result = evaluate_policy(SampledPolicy(self.model), env, episodes=self.config.eval.episodes,
                                 seed=self.config.eval.seed)
        env.close()
        return {"sim_steps": self.steps, "goal_area": area, "success_rate": result.success_rate,
                "mean_length": result.mean_length, "std_length": result.std_length}

    # ------------------------------------------------------------------ training
    def run(self, callback: RunCallback = SILENT, learn: Callable[[A3CTrainer, Task], None] | None = None) -> dict[str, Any]:
        """Pre-train perception if asked, train to ``total_timesteps`` with the run's workers (``learn``:
        another way to play the rollouts, e.g. Ray actors, sharing :meth:`take`), measure, write outputs."""
        torch.set_num_threads(1)  # the workers need the cores; evaluation is one small forward pass a step
        if self.config.a3c.pretrain_pictures and self.steps == 0 and "pretrain" not in self.metrics:
            self._pretrain(callback)
        if self.steps < self.config.total_timesteps:
            with callback.task(self.config.name, self.config.total_timesteps, self.steps) as task:
                (learn or A3CTrainer._train)(self, task)
        evaluations = self.metrics["evaluations"]
        if not evaluations or evaluations[-1]["sim_steps"] != self.steps:  # the final policy is always measured
            evaluations.append(self.evaluate(self.goal_area(self.steps)))
            self.save_checkpoint()
        return self.write_outputs()

    def _pretrain(self, callback: RunCallback) -> None:
        """Perception first (:mod:`binpick.rl.a3c.pretrain`); checkpointed, so a resumed run does not redo it."""
        from binpick.rl.a3c.pretrain import pretrain_perception

        a3c = self.config.a3c
        started = time.perf_counter()
        with callback.task(f"{self.config.name}: perception", a3c.pretrain_epochs) as task:
            result = pretrain_perception(self.model, lambda: make_a3c_env(self.config, self.wrap_env), a3c.state_key, a3c.pretrain_pictures,
                                         a3c.pretrain_epochs, a3c.pretrain_learning_rate, self.config.seed + 777_777, task,
                                         near_goal=a3c.pretrain_near_goal)
        self.metrics["pretrain"] = asdict(result) | {"wall_seconds": round(time.perf_counter() - started, 1)}
        self.save_checkpoint()

    def _train(self, task: Task) -> None:
        """Worker processes until ``total_timesteps``, evaluating and checkpointing on the way."""
        context = worker_context(__name__)  # this process's simulators and threads must not be forked
        counter = context.Value("l", self.steps)
        goal_area = context.Value("d", self.goal_area(self.steps))
        stats_queue = context.Queue()
        stop = context.Event()
        workers = [context.Process(target=_worker, args=(rank, self.config, self.model, self.optimizer, counter,
                                                         goal_area, stats_queue, stop, self.wrap_env), daemon=True)
                   for rank in range(self.config.a3c.workers)]
        log = self.open_log()
        for worker in workers:
            worker.start()
        try:
            while any(w.is_alive() for w in workers) and self.steps < self.config.total_timesteps:
                try:
                    record = stats_queue.get(timeout=1.0)
                except queue.Empty:
                    continue
                self.steps = counter.value
                self.take(record, log, task, on_area=lambda area: setattr(goal_area, "value", area))
        finally:
            stop.set()
            for worker in workers:
                worker.join(timeout=10)
                if worker.is_alive():
                    worker.terminate()
            log.close()
        self.steps = counter.value
        self.metrics["wall_seconds"] = log.elapsed()
        failed = [worker.exitcode for worker in workers if worker.exitcode]
        if self.steps < self.config.total_timesteps and failed:  # not a finished run: no final evaluation, no metrics
            raise WorkerError(f"A3C workers exited with an error (exit codes {failed}, traceback above) at step "
                              f"{self.steps:,}; {self.run_dir} resumes from its last checkpoint (binpick rl train --resume)")

    def open_log(self) -> TrainingLog:
        """TensorBoard, the wall clock and the next evaluation and checkpoint, from where the run stands."""
        return TrainingLog(self.run_dir, self.steps, self.metrics["wall_seconds"], self.config.eval.every,
                           self.config.checkpoint_every)

    def take(self, record: tuple, log: TrainingLog, task: Task, on_area: Callable[[float], None] | None = None) -> float:
        """One rollout's record (:func:`rollout_record`) at ``self.steps``: episodes, curriculum, losses,
        progress, then the evaluation and checkpoint that are due. Returns the goal area from now on,
        given to ``on_area`` first, before any evaluation, so workers still playing meanwhile play it
        (the local workers and the Ray learner share this bookkeeping)."""
        finished, successes, policy_loss, value_loss, entropy, state_loss, area = record
        writer = log.writer
        for length in finished:
            log.lengths.append(length)
            self.metrics["episodes"] += 1
            writer.add_scalar("episode/length", length, self.steps)
        if self.curriculum.record(self.steps, finished, area):  # re-converged: the next stage ramps in
            writer.add_scalar("curriculum/stage", self.curriculum.stage, self.steps)
        now = self.goal_area(self.steps)
        if on_area is not None:
            on_area(now)
        writer.add_scalar("loss/policy", policy_loss, self.steps)
        writer.add_scalar("loss/value", value_loss, self.steps)
        writer.add_scalar("loss/entropy", entropy, self.steps)
        if self.state_size:
            writer.add_scalar("loss/state", state_loss, self.steps)
        writer.add_scalar("curriculum/goal_area", now, self.steps)
        recent = f"last 100 episodes {np.mean(log.lengths[-100:]):.1f} actions" if log.lengths else ""
        task.update(self.steps, status=f"area {now:.2f} · {recent}")
        if self.steps >= log.next_eval:
            log.next_eval += self.config.eval.every
            row = self.evaluate(now)
            self.metrics["evaluations"].append(row)
            writer.add_scalar("eval/avg_actions", row["mean_length"], self.steps)
            writer.add_scalar("eval/success_rate", row["success_rate"], self.steps)
        if self.steps >= log.next_save:
            log.next_save += self.config.checkpoint_every
            self.metrics["wall_seconds"] = log.elapsed()
            self.save_checkpoint()
        return now

    def write_outputs(self) -> dict[str, Any]:
        from binpick.viz.plots import plot_learning_curve

        last = self.metrics["evaluations"][-1]
        data = {"name": self.config.name, "env": self.config.env, "algorithm": "a3c", "seed": self.config.seed,
                "sim_steps": self.steps, "episodes": self.metrics["episodes"], "final_goal_area": last["goal_area"],
                "final_success": last["success_rate"], "final_avg_actions": last["mean_length"],
                "final_std_actions": last["std_length"], "wall_seconds": round(self.metrics["wall_seconds"], 1),
                "curriculum_advanced_at": list(self.curriculum.advanced_at),
                **{key: self.metrics[key] for key in ("worker_restarts", "lost_rollouts") if key in self.metrics},
                **({"pretrain": self.metrics["pretrain"]} if "pretrain" in self.metrics else {}),
                "evaluations": self.metrics["evaluations"]}
        atomic_write_json(self.run_dir / "metrics.json", data)
        plot_learning_curve(self.metrics["evaluations"], self.run_dir / "curves.png", title=self.config.name,
                            goal_areas=[e["goal_area"] for e in self.metrics["evaluations"]])
        return data



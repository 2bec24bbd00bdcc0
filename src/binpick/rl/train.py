"""Train one RL run from an :class:`RLConfig`, top to bottom, resumable after a crash.

Run folder ``runs/<name>/<timestamp>/``: ``config.yaml``, ``tb/`` (TensorBoard), ``checkpoints/``
(``ckpt-<steps>/`` written whole, then named in ``checkpoints/latest`` with an atomic rename, so a
``kill -9`` leaves the previous checkpoint intact), ``metrics.json`` and ``curves.png``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList

from binpick.core.config import load_run_config
from binpick.core.errors import ConfigError, InputFileError
from binpick.core.files import (
    atomic_write,
    atomic_write_json,
    read_json_object,
    read_npz,
    require_fields,
)
from binpick.core.runs import (
    SILENT,
    RunCallback,
    StopRequested,
    commit_checkpoint,
    latest_checkpoint,
    new_run,
    removed_on_error,
)
from binpick.rl.gp_her.agents import GPImagination
from binpick.rl.config import RLConfig
from binpick.rl.common.curriculum import CurriculumProgress, GoalAreaCurriculum
from binpick.rl.gp_her.dynamics import GPDynamics
from binpick.rl.algorithms import ALGORITHMS
from binpick.rl.callbacks import Checkpoint, Evaluate, Metrics, ReportProgress, stopped_early
from binpick.rl.common.persistence import (
    ALGORITHM_FILE,
    POLICY_FILE,
    copy_algorithm,
    load_algorithm,
    load_replay,
    save_algorithm,
    save_policy,
    save_replay,
)
from binpick.rl.common.wrappers import gripper_dims, needs_gripper
from binpick.rl.envs import make_env, no_wrap_env


def build_model(config: RLConfig, env: gym.Env, tensorboard: str | None, envs=None) -> BaseAlgorithm:
    """The run's learner on ``env`` (the run's env; its reward and episode length for the replay), or on
    ``envs``, a ``VecEnv`` of several simulators of it (Ray actors), which only the GP + HER SAC takes."""
    algorithm = ALGORITHMS[config.algorithm]
    if envs is not None and not algorithm.simulators_on_ray:
        raise ConfigError(f"several simulators feed the sac learner (GP + HER) only; this run is {config.algorithm}")
    return algorithm.load("learner")(config, env, tensorboard, envs)


class Trainer:
    """Owns a run folder; ``run()`` trains to ``total_timesteps``, resuming from the latest checkpoint."""

    TASK = "rl"  # its kind of job (binpick.core.jobs)

    def __init__(self, config: RLConfig, run_dir: Path) -> None:
        self.config, self.run_dir = config, Path(run_dir)
        self.ckpt_dir = self.run_dir / "checkpoints"
        self.metrics = Metrics()
        self.curriculum = CurriculumProgress(config.curriculum)  # where the goal-area curriculum stands
        self._started: float | None = None  # perf_counter() minus the wall time of earlier sessions
        self._envs, self._restarts_before = None, 0  # simulators as Ray actors (run(envs=...)), their restarts before
        self.env = make_env(config)
        self.model = self._new_model()
        self.gp = None
        if config.gp.enabled:
            dynamics = GPDynamics(config.gp.max_points, config.gp.iterations, seed=config.seed)
            self.gp = GPImagination(config.gp.warmup_episodes, config.gp.refit_every, config.gp.imagined_per_real,
                                    config.gp.batch_episodes, dynamics, seed=config.seed,
                                    fill_until_ready=config.gp.fill_until_ready)

    def _new_model(self, envs=None) -> BaseAlgorithm:
        model = build_model(self.config, self.env, str(self.run_dir / "tb"), envs)
        if self.config.actor_noise.enabled:
            noise = self.config.actor_noise
            model.perturb_actor_inputs((noise.gripper, noise.achieved, noise.goal),
                                       gripper_dims(needs_gripper(self.config.env), self.config.gripper_opening))
        return model

    def train_on(self, envs) -> None:
        """Learn from ``envs`` from now on: a ``VecEnv`` of several simulators of this run's env (Ray actors,
        :class:`binpick.integrations.ray.envs.RayVecEnv`), or None for the run's own env again. The learner
        is built again for their number and takes over the current one's weights, optimisers, counters,
        replay and demonstrations."""
        old = self.model
        self.model = self._new_model(envs)
        copy_algorithm(old, self.model)
        old.replay_buffer.for_envs(1 if envs is None else envs.num_envs)
        self.model.replay_buffer = old.replay_buffer
        if getattr(old, "demonstrations", None) is not None:
            self.model.keep_cloning(old.demonstrations, old.bc_alpha, old.bc_likelihood_weight, old.bc_q_filter)

    @property
    def steps_done(self) -> int:
        return int(self.model.num_timesteps)

    # ------------------------------------------------------------------ construction
    @classmethod
    def new(cls, config: RLConfig, runs_root: Path = Path("runs"), wrap_env=None) -> Trainer:
        no_wrap_env(config, wrap_env)
        with removed_on_error(new_run(runs_root, config, cls.TASK)) as run_dir:
            return cls(config, run_dir)

    @classmethod
    def resume(cls, run_dir: Path, wrap_env=None) -> Trainer:
        run_dir = Path(run_dir)
        config = load_run_config(RLConfig, run_dir)
        no_wrap_env(config, wrap_env)
        trainer = cls(config, run_dir)
        trainer.load_checkpoint()
        return trainer

    # ------------------------------------------------------------------ checkpoints
    def save_checkpoint(self) -> Path:
        """Everything a resume needs, in files that hold no code (see :mod:`binpick.rl.common.persistence`)."""
        if self._started is not None:  # wall time carries over resumes
            self.metrics.wall_seconds = time.perf_counter() - self._started
        self._count_restarts()

        def write(folder: Path) -> None:
            save_algorithm(self.model, folder / ALGORITHM_FILE)
            save_policy(self.model, folder / POLICY_FILE, algorithm=self.config.algorithm, env=self.config.env)
            if ALGORITHMS[self.config.algorithm].keeps_replay:  # an image replay is GBs: a resumed DQN refills its own
                save_replay(self.model.replay_buffer, folder)
            demonstrations = getattr(self.model, "demonstrations", None)
            if demonstrations is not None:
                atomic_write(folder / "demonstrations.npz", lambda handle: np.savez(handle, **demonstrations.arrays()))
            state = {"metrics": self.metrics.__dict__, "env": self.config.env,
                     "num_timesteps": int(self.model.num_timesteps), "gp": self.gp.state() if self.gp else None,
                     "curriculum": self.curriculum.state_dict()}
            atomic_write_json(folder / "state.json", state, indent=None)
            if self.gp is not None and self.gp.dynamics.fitted:
                self.gp.dynamics.save(folder / "gp.safetensors")

        return commit_checkpoint(self.ckpt_dir, int(self.model.num_timesteps), write)

    def load_checkpoint(self) -> None:
        checkpoint = latest_checkpoint(self.ckpt_dir)
        if checkpoint is None:
            return  # crashed before the first checkpoint: start again from zero
        if not (checkpoint / ALGORITHM_FILE).is_file() and (checkpoint / "model.zip").is_file():
            raise InputFileError(f"checkpoint {checkpoint} was written by an older binpick (model.zip, replay.pkl), whose "
                                 "pickles can run code when loaded: binpick no longer reads them; start the run again")
        where = f"RL checkpoint state {str(checkpoint / 'state.json')!r}"
        state = read_json_object(checkpoint / "state.json", "RL checkpoint state", {"metrics": dict, "num_timesteps": int})
        load_algorithm(self.model, checkpoint / ALGORITHM_FILE)
        if ALGORITHMS[self.config.algorithm].keeps_replay:
            load_replay(self.model.replay_buffer, checkpoint)
        try:
            self.metrics = Metrics(**state["metrics"])
        except TypeError as error:
            raise InputFileError(f"{where} is damaged ({error})") from None
        require_fields(self.metrics.__dict__, {"evaluations": list, "wall_seconds": (int, float)}, where)
        self.curriculum.load_state_dict(state.get("curriculum"))
        if (checkpoint / "demonstrations.npz").is_file():
            self._restore_demonstrations(checkpoint / "demonstrations.npz")
        if self.gp is not None and state.get("gp") is not None:
            if (checkpoint / "gp.safetensors").is_file():  # else: refitted at the next step
                self.gp.dynamics = GPDynamics.load(checkpoint / "gp.safetensors")
            try:
                self.gp.restore(state["gp"])
            except (KeyError, TypeError) as error:
                raise InputFileError(f"{where} is damaged: GP schedule {error}") from None

    def _restore_demonstrations(self, path: Path) -> None:
        """Pick and place keeps cloning its demonstrations while SAC learns (§4.5.3): they resume too."""
        from binpick.rl.common.demonstrations import DemonstrationSet

        demos = self.config.demonstrations
        try:
            demonstrations = DemonstrationSet.from_arrays(read_npz(path, "demonstrations"))
        except KeyError as error:
            raise InputFileError(f"demonstrations {str(path)!r} are damaged: no {error}") from None
        self.model.keep_cloning(demonstrations, demos.bc_alpha, demos.likelihood_weight, demos.q_filter)

    # ------------------------------------------------------------------ training
    def learn_from_demonstrations(self) -> None:
        """Thesis §4.5.3: heuristic episodes into the replay, then behaviour cloning of the actor."""
        from binpick.rl.common.demonstrations import (
            DemonstrationSet,
            add_demonstrations,
            behaviour_clone,
            collect_demonstrations,
        )
        from binpick.rl.common.heuristic import PickAndPlaceHeuristic

        demos = self.config.demonstrations
        expert = PickAndPlaceHeuristic(noise=demos.noise, seed=self.config.seed)
        episodes, steps = collect_demonstrations(self.env, expert, demos.episodes, seed=self.config.seed + 500_000)
        add_demonstrations(self.model.replay_buffer, episodes)
        demonstrations = DemonstrationSet(episodes, self.model.action_space.low, self.model.action_space.high)
        losses = behaviour_clone(self.model, demonstrations, demos.bc_steps, self.config.sac.batch_size,
                                 self.config.seed, demos.likelihood_weight)
        if demos.bc_alpha:  # keep cloning while SAC learns
            self.model.keep_cloning(demonstrations, demos.bc_alpha, demos.likelihood_weight, demos.q_filter)
            if demos.critic_steps and self.model.replay_buffer.ready:
                self.model.pretrain_critic(demos.critic_steps, self.config.sac.batch_size)
        self.metrics.demo_episodes, self.metrics.demo_steps = len(episodes), steps
        self.metrics.bc_final_loss = losses[-1] if losses else None

    def run(self, callback: RunCallback = SILENT, envs=None) -> dict[str, Any]:
        """Train to ``total_timesteps`` on the run's env, or on ``envs`` (see :meth:`train_on`; closed at the end)."""
        if envs is not None:
            self._envs, self._restarts_before = envs, self.metrics.worker_restarts
            try:
                self.train_on(envs)
                return self._run(callback)
            finally:
                envs.close()
                self._envs = None
                self.train_on(None)  # the trainer can run again, here
        return self._run(callback)

    def _count_restarts(self) -> None:
        """``metrics.worker_restarts`` up to date while the simulators are actors that Ray restarts."""
        if self._envs is not None:
            self.metrics.worker_restarts = self._restarts_before + int(getattr(self._envs, "deaths", 0))

    def _run(self, callback: RunCallback) -> dict[str, Any]:
        torch.set_num_threads(1)  # small networks: threads cost more than they give on 2 cores
        remaining = 0 if stopped_early(self.config, self.metrics) else self.config.total_timesteps - int(self.model.num_timesteps)
        self._started = time.perf_counter() - self.metrics.wall_seconds
        evaluator = Evaluate(self.config, self.metrics)
        callbacks: list[BaseCallback] = [evaluator, Checkpoint(self.config, self.save_checkpoint)]
        if self.gp is not None:
            callbacks.insert(0, self.gp)
        if self.config.curriculum.stages:
            callbacks.insert(0, GoalAreaCurriculum(self.config.curriculum, self.curriculum))
        if self.config.demonstrations.episodes and not self.metrics.demo_episodes and not self.model.num_timesteps:
            callback.message(f"{self.config.name}: {self.config.demonstrations.episodes} demonstrations, behaviour cloning")
            self.learn_from_demonstrations()
        with callback.task(self.config.name, self.config.total_timesteps, int(self.model.num_timesteps)) as task:
            callbacks.append(ReportProgress(task, self.metrics))
            if remaining > 0:
                try:
                    self.model.learn(remaining, callback=CallbackList(callbacks), reset_num_timesteps=False,
                                     tb_log_name=self.config.algorithm, log_interval=10)
                except StopRequested:  # Ctrl-C, at a step boundary: keep the steps since the last checkpoint, then stop
                    self.save_checkpoint()
                    raise
        evaluated = [e["sim_steps"] for e in self.metrics.evaluations]
        if not evaluated or evaluated[-1] != self.model.num_timesteps:  # the final policy is always measured
            self._ensure_logger()
            evaluator.init_callback(self.model)
            evaluator.evaluate()
        self.save_checkpoint()
        return self.write_outputs()

    def _ensure_logger(self) -> None:
        """SB3 makes a model's logger in learn(); a run resumed after its last step never calls it."""
        if getattr(self.model, "_logger", None) is None:
            from stable_baselines3.common.utils import configure_logger

            self.model.set_logger(configure_logger(0, str(self.run_dir / "tb"), self.config.algorithm, False))

    def write_outputs(self) -> dict[str, Any]:
        self._count_restarts()
        data = self.metrics.to_dict(self.config, self.model, self.gp)
        atomic_write_json(self.run_dir / "metrics.json", data)
        from binpick.viz.plots import plot_learning_curve

        plot_learning_curve(self.metrics.evaluations, self.run_dir / "curves.png", title=self.config.name,
                            threshold=self.config.eval.success_threshold)
        return data


class RLRun:
    """An RL run as one job (:class:`binpick.core.runs.Job`), whatever its algorithm: A3C trains with worker
    processes (:class:`~binpick.rl.a3c.train.A3CTrainer`), SAC / SB3 SAC+HER / DQN with :class:`Trainer`."""

    TASK = "rl"  # its kind of job (binpick.core.jobs)

    @staticmethod
    def new(config: RLConfig, runs: Path = Path("runs")):
        return trainer_for(config, runs)

    @staticmethod
    def resume(run_dir: Path):
        return trainer_for(resume=run_dir)


def trainer_for(config: RLConfig | None = None, runs_root: Path = Path("runs"), resume: Path | None = None,
                wrap_env=None):
    """A new trainer for ``config``, or the one that continues run folder ``resume`` (A3C or SB3-based);
    ``wrap_env`` is A3C's (binpick.rl.a3c.envs.make_a3c_env)."""
    if resume is not None:
        config = load_run_config(RLConfig, resume)
    trainer = ALGORITHMS[config.algorithm].load("trainer")
    return trainer.new(config, runs_root, wrap_env) if resume is None else trainer.resume(Path(resume), wrap_env)



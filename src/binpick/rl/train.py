"""Train one RL run from an :class:`RLConfig`, top to bottom, resumable after a crash.

Run folder ``runs/<name>/<timestamp>/``: ``config.yaml``, ``tb/`` (TensorBoard), ``checkpoints/``
(``ckpt-<steps>/`` written whole, then named in ``checkpoints/latest`` with an atomic rename, so a
``kill -9`` leaves the previous checkpoint intact), ``metrics.json`` and ``curves.png``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import DQN, SAC, HerReplayBuffer
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
    Task,
    commit_checkpoint,
    latest_checkpoint,
    new_run,
    removed_on_error,
)
from binpick.envs import make
from binpick.rl.gp_her.agents import GoalSAC, GPImagination
from binpick.rl.config import RLConfig
from binpick.rl.common.curriculum import CurriculumProgress, GoalAreaCurriculum
from binpick.rl.gp_her.dynamics import GPDynamics
from binpick.rl.common.evaluate import evaluate_policy
from binpick.rl.common.persistence import (
    copy_algorithm,
    load_algorithm,
    load_replay,
    load_saved_policy,
    save_algorithm,
    save_policy,
    save_replay,
)
from binpick.rl.common.replay import EpisodeReplayBuffer
from binpick.rl.common.wrappers import (
    MinActionScale,
    SemanticState,
    gripper_dims,
    needs_gripper,
)


def next_multiple(steps: int, every: int) -> int:
    """The first multiple of ``every`` after ``steps``: when a periodic job next runs."""
    return (int(steps) // every + 1) * every


def _no_wrap_env(config: RLConfig, wrap_env) -> None:
    """``wrap_env`` reaches only A3C's envs (binpick.rl.a3c.train.make_env); anywhere else it is a mistake."""
    if wrap_env is not None:
        raise ConfigError(f"wrap_env is an A3C option; this run is {config.algorithm}")


def make_env(config: RLConfig, wrap_env=None) -> gym.Env:
    """The env exactly as the run trains on it (semantic state, minimum action scale; A3C's flattened state,
    after A3C's ``wrap_env`` if the run was made with one)."""
    if config.algorithm == "a3c":
        from binpick.rl.a3c.train import make_env as make_a3c_env

        return make_a3c_env(config, wrap_env)
    _no_wrap_env(config, wrap_env)
    env = make(config.env, **config.env_kwargs)
    if config.semantic_state and config.algorithm in ("sac", "sb3_sac_her"):
        env = SemanticState(env, gripper=needs_gripper(config.env), privileged=config.privileged_state,
                            opening=config.gripper_opening)
    if config.min_action_scale:
        env = MinActionScale(env, config.min_action_scale)
    return env


def build_model(config: RLConfig, env: gym.Env, tensorboard: str | None, envs=None) -> BaseAlgorithm:
    """The run's learner on ``env`` (the run's env; its reward and episode length for the replay), or on
    ``envs``, a ``VecEnv`` of several simulators of it (Ray actors): then ``sac.gradient_steps`` are per
    simulator step, as in a local run, so one vector step of N simulators is followed by N times as many."""
    if envs is not None and config.algorithm != "sac":
        raise ConfigError(f"several simulators feed the sac learner (GP + HER) only; this run is {config.algorithm}")
    if config.algorithm == "dqn":
        dqn = config.dqn
        return DQN("CnnPolicy", env, buffer_size=dqn.buffer_size, target_update_interval=dqn.target_update_interval,
                   learning_rate=dqn.learning_rate, batch_size=dqn.batch_size, gamma=dqn.gamma,
                   learning_starts=dqn.learning_starts, train_freq=dqn.train_freq,
                   exploration_fraction=dqn.exploration_fraction, exploration_final_eps=dqn.exploration_final_eps,
                   optimize_memory_usage=False, seed=config.seed, tensorboard_log=tensorboard, device="cpu")
    sac = config.sac
    simulators = envs.num_envs if envs is not None else 1
    common = dict(learning_rate=sac.learning_rate, batch_size=sac.batch_size, gamma=sac.gamma, tau=sac.tau,
                  gradient_steps=sac.gradient_steps * simulators, learning_starts=sac.learning_starts, ent_coef=sac.ent_coef,
                  seed=config.seed,
                  policy_kwargs={"net_arch": list(sac.net_arch)}, tensorboard_log=tensorboard, device="cpu")
    if config.algorithm == "sb3_sac_her":
        return SAC("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer,
                   replay_buffer_kwargs={"n_sampled_goal": config.replay.future_k, "goal_selection_strategy": "future"},
                   **common)
    replay = dict(compute_reward=env.unwrapped.compute_reward, max_episode_steps=env.spec.max_episode_steps,
                  capacity_episodes=config.replay.capacity_episodes, her_additions=config.replay.her_additions,
                  start_fraction=config.replay.start_fraction, her_min_motion=config.replay.her_min_motion,
                  seed=config.seed)
    if config.gp.enabled:
        common["learning_starts"] = config.gp.warmup_episodes * env.spec.max_episode_steps
    return GoalSAC("MultiInputPolicy", env if envs is None else envs, replay_buffer_class=EpisodeReplayBuffer,
                   replay_buffer_kwargs=replay, **common)


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

    def to_dict(self, config: RLConfig, model: SAC, gp: GPImagination | None) -> dict[str, Any]:
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
    def __init__(self, trainer: Trainer) -> None:
        super().__init__()
        self.trainer = trainer
        self._next = trainer.config.checkpoint_every

    def _on_training_start(self) -> None:
        self._next = next_multiple(self.model.num_timesteps, self.trainer.config.checkpoint_every)

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            self._next = next_multiple(self.num_timesteps, self.trainer.config.checkpoint_every)
            self.trainer.save_checkpoint()
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
    def new(cls, config: RLConfig, runs_root: Path = Path("runs")) -> Trainer:
        with removed_on_error(new_run(runs_root, config, cls.TASK)) as run_dir:
            return cls(config, run_dir)

    @classmethod
    def resume(cls, run_dir: Path) -> Trainer:
        run_dir = Path(run_dir)
        config = load_run_config(RLConfig, run_dir)
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
            if self.config.algorithm != "dqn":  # an image replay is GBs: a resumed DQN refills its replay
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
        if self.config.algorithm != "dqn":
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
        callbacks: list[BaseCallback] = [evaluator, Checkpoint(self)]
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


ALGORITHM_FILE = "algorithm.safetensors"
POLICY_FILE = "policy.safetensors"


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
    ``wrap_env`` is A3C's (binpick.rl.a3c.train.make_env)."""
    if resume is not None:
        config = load_run_config(RLConfig, resume)
    if config.algorithm == "a3c":
        from binpick.rl.a3c.train import A3CTrainer as trainer_class
        return (trainer_class.new(config, runs_root, wrap_env) if resume is None
                else trainer_class.resume(Path(resume), wrap_env))
    _no_wrap_env(config, wrap_env)
    return Trainer.new(config, runs_root) if resume is None else Trainer.resume(Path(resume))


def load_policy(run_dir: Path, env_id: str | None = None):
    """The latest checkpoint of a run; asking for another env than it was trained on is an error."""
    run_dir = Path(run_dir)
    if not (run_dir / "config.yaml").is_file():
        raise ConfigError(f"{str(run_dir)!r} is not a run folder (no config.yaml)")
    config = load_run_config(RLConfig, run_dir)
    if env_id is not None:
        from binpick.envs import resolve_env_id

        if resolve_env_id(env_id) != config.env:
            raise ConfigError(f"checkpoint {run_dir} was trained on {config.env}, not {resolve_env_id(env_id)}")
    checkpoint = latest_checkpoint(run_dir / "checkpoints")
    if checkpoint is None:
        raise ConfigError(f"run {run_dir} has no checkpoint yet")
    if config.algorithm == "a3c":
        from binpick.rl.a3c.train import load_a3c_policy

        return load_a3c_policy(checkpoint), config
    if not (checkpoint / POLICY_FILE).is_file():
        raise InputFileError(f"run {run_dir} has no {POLICY_FILE} in its latest checkpoint (older runs saved SB3 zips, "
                             "which binpick no longer loads because they can run code)")
    return load_saved_policy(checkpoint / POLICY_FILE), config


class TrainedPolicy:
    """A trained RL policy as SB3 users know it: ``TrainedPolicy.load(run)`` and
    ``predict(observation, deterministic=True) -> (action, None)``. ``run`` is a run folder (its
    latest checkpoint, any algorithm) or a ``policy.safetensors`` file. Nothing is unpickled."""

    @staticmethod
    def load(path: str | Path, env_id: str | None = None):
        path = Path(path)
        if path.is_file():
            return load_saved_policy(path)
        policy, _ = load_policy(path, env_id)
        return policy

    @staticmethod
    def make_env(run_dir: str | Path) -> gym.Env:
        """The env exactly as the run trained on it (semantic state, minimum action scale): what its
        policy's observations and actions mean."""
        return make_env(load_run_config(RLConfig, run_dir))

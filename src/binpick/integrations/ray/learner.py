"""A central off-policy learner fed by distributed simulators (thesis §6.1, Fig 6.1).

Stable-Baselines3's SAC with HER learns; it never steps an env itself. Ray workers
(:class:`~binpick.integrations.ray.rollouts.DistributedRollouts`) play whole episodes with the latest
policy and stream them in; every finished episode goes into the HER replay buffer and is followed
by as many gradient steps as it had env steps, and every few episodes the workers get the new
policy. A worker that dies costs its in-flight episode only.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from binpick.core.config import check_range
from binpick.cluster import check_ray_address
from binpick.integrations.ray.rollouts import DistributedRollouts, Episode
from binpick.core.files import atomic_write_json


@dataclass(frozen=True)
class DistributedConfig:
    env: str = "binpick/FetchReach-v0"
    workers: int = 2
    total_timesteps: int = 5_000  # env steps played by the workers (lost episodes not counted)
    learning_starts: int = 500
    batch_size: int = 256
    sync_every: int = 2  # episodes between policy broadcasts
    eval_episodes: int = 20
    address: str | None = None  # a Ray cluster ("HOST:6379"); None: a private local one
    seed: int = 0

    def __post_init__(self) -> None:
        check_range("workers", self.workers, 1, 4096, integer=True)
        check_range("total_timesteps", self.total_timesteps, 1, 10**9, integer=True)
        check_range("seed", self.seed, 0, 2**32 - 1, integer=True)
        check_ray_address(self.address)
        check_range("sync_every", self.sync_every, 1, 10**6, integer=True)


def _batched(observation: Any) -> Any:
    if isinstance(observation, dict):
        return {key: np.asarray(value)[None] for key, value in observation.items()}
    return np.asarray(observation)[None]


def add_episode(buffer, episode: Episode) -> None:
    """Whole episode into an SB3 (HER) replay buffer, in step order, as one env of a VecEnv."""
    for t in range(episode.steps):
        done = bool(episode.terminated[t] or episode.truncated[t])
        timeout = bool(episode.truncated[t] and not episode.terminated[t])
        buffer.add(_batched(episode.observations[t]), _batched(episode.next_observations[t]), episode.actions[t][None],
                   np.array([episode.rewards[t]]), np.array([done]), [{"TimeLimit.truncated": timeout}])


def train_distributed(config: DistributedConfig, out: Path | None = None,
                      on_episode: Callable[[Episode, DistributedRollouts, Any], None] | None = None) -> dict[str, Any]:
    """Train SAC + HER from the workers' episodes; returns metrics (and writes model + metrics to ``out``)."""
    import torch
    from stable_baselines3 import SAC, HerReplayBuffer
    from stable_baselines3.common.vec_env import DummyVecEnv

    from binpick.envs import make
    from binpick.rl.evaluate import evaluate_policy

    torch.set_num_threads(1)
    local = make(config.env)  # spaces and compute_reward for HER; the learner never steps it
    model = SAC("MultiInputPolicy", DummyVecEnv([lambda: local]), replay_buffer_class=HerReplayBuffer,
                replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future"},
                learning_starts=0, batch_size=config.batch_size, seed=config.seed, verbose=0, device="cpu")
    model._setup_learn(config.total_timesteps)
    rollouts = DistributedRollouts(config.env, config.workers, config.address, seed=config.seed)
    started = time.perf_counter()
    try:
        rollouts.set_policy(model.policy)
        for episode in rollouts.stream():
            add_episode(model.replay_buffer, episode)
            model.num_timesteps += episode.steps
            if model.num_timesteps >= config.learning_starts:
                model.train(gradient_steps=episode.steps, batch_size=config.batch_size)
            if rollouts.stats.episodes % config.sync_every == 0:
                rollouts.set_policy(model.policy)
            if on_episode is not None:
                on_episode(episode, rollouts, model)
            if model.num_timesteps >= config.total_timesteps:
                break
        elapsed = time.perf_counter() - started
        stats = rollouts.stats
    finally:
        rollouts.close()
    evaluation = evaluate_policy(model, local, episodes=config.eval_episodes, seed=10_000)
    metrics = {"config": asdict(config), "env_steps": stats.steps, "episodes": stats.episodes,
               "lost_episodes": rollouts.pool.deaths, "worker_restarts": rollouts.pool.deaths,
               "steps_per_worker": {str(k): v for k, v in sorted(stats.per_worker_steps.items())},
               "wall_s": round(elapsed, 1), "env_steps_per_s_with_learning": round(stats.steps / elapsed, 1),
               "final_success": evaluation.success_rate, "final_avg_actions": evaluation.mean_length}
    if out is not None:
        from binpick.rl.persistence import save_policy

        save_policy(model, out / "policy.safetensors", algorithm="sac", env=config.env)
        atomic_write_json(out / "metrics.json", metrics)
    local.close()
    return metrics

"""A3C with its workers as Ray actors (thesis §3.1.2 over §6.1's distributed simulators).

Each actor owns a simulator and an :class:`~binpick.rl.a3c.A3CWorker`: given the global weights it
plays up to n steps and returns gradients (Eq 3.5-3.7). The learner applies whichever worker's
gradients arrive first and sends that worker the new weights — asynchronous, as A3C is, but across
processes or machines instead of threads sharing memory. A worker that dies is restarted; its
rollout is lost.
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from binpick.core import tensorfile
from binpick.core.config import check_range
from binpick.core.errors import ConfigError
from binpick.cluster import check_ray_address
from binpick.integrations.ray.rollouts import RestartingActors
from binpick.core.files import atomic_write_json


class A3CActor:
    def __init__(self, env_id: str, env_kwargs: dict, seed: int, a3c: dict) -> None:
        os.environ.setdefault("MUJOCO_GL", "egl")
        import torch

        from binpick.envs import make
        from binpick.rl.a3c import A3CWorker

        torch.set_num_threads(1)
        probe = make(env_id, **env_kwargs)
        shape, actions = probe.observation_space.shape, int(probe.action_space.n)
        probe.close()
        self.worker = A3CWorker(lambda: make(env_id, **env_kwargs), shape, actions, seed=seed, **a3c)

    def pid(self) -> int:
        return os.getpid()

    def gradients(self, weights):
        return self.worker.compute_gradients(weights)


@dataclass(frozen=True)
class DistributedA3CConfig:
    env: str = "binpick/Arm2D-v0"
    workers: int = 2
    total_timesteps: int = 20_000
    lr: float = 1e-4
    n_steps: int = 20
    eval_episodes: int = 20
    address: str | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        check_range("workers", self.workers, 1, 4096, integer=True)
        check_range("total_timesteps", self.total_timesteps, 1, 10**9, integer=True)
        check_range("seed", self.seed, 0, 2**32 - 1, integer=True)
        check_ray_address(self.address)
        from binpick.envs import env_spec, resolve_env_id

        object.__setattr__(self, "env", resolve_env_id(self.env))
        if not env_spec(self.env).discrete_actions:
            raise ConfigError(f"A3C learns from images with discrete actions (Arm2D); {self.env} has continuous ones")


def train_a3c_distributed(config: DistributedA3CConfig, out: Path | None = None, on_update=None) -> dict[str, Any]:
    """Train; returns metrics (and writes the network and metrics.json to ``out``)."""
    import ray
    import torch

    from binpick.envs import make
    from binpick.rl.a3c import ActorCritic, apply_gradients
    from binpick.rl.evaluate import evaluate_policy

    torch.manual_seed(config.seed)
    local = make(config.env)
    model = ActorCritic(local.observation_space.shape, int(local.action_space.n))
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    arguments = [(config.env, {}, config.seed * 1000 + 7919 * i, {"n_steps": config.n_steps}) for i in range(config.workers)]
    pool = RestartingActors(A3CActor, arguments, config.address)
    latest = {"weights": ray.put(model.state_dict())}
    steps, updates, lengths, successes = 0, 0, [], []
    started = time.perf_counter()
    try:
        for _, (gradients, stats) in pool.results(lambda actor: actor.gradients.remote(latest["weights"])):
            apply_gradients(model, optimizer, gradients)
            latest["weights"] = ray.put(model.state_dict())
            steps += stats.steps
            updates += 1
            lengths += stats.finished_lengths
            successes += stats.finished_successes
            if on_update is not None:
                on_update(steps, pool)
            if steps >= config.total_timesteps:
                break
        elapsed = time.perf_counter() - started
    finally:
        pool.close()
    evaluation = evaluate_policy(lambda observation: model.act(observation, deterministic=True), local,
                                 episodes=config.eval_episodes, seed=10_000)
    local.close()
    metrics = {"config": asdict(config), "env_steps": steps, "updates": updates, "episodes": len(lengths),
               "lost_rollouts": pool.deaths, "worker_restarts": pool.deaths, "wall_s": round(elapsed, 1),
               "env_steps_per_s_with_learning": round(steps / elapsed, 1),
               "training_success": round(sum(successes) / max(1, len(successes)), 3),
               "final_success": evaluation.success_rate, "final_avg_actions": evaluation.mean_length}
    if out is not None:
        tensorfile.save(out / "model.safetensors", "binpick-a3c-model-1", tensors=model.state_dict(),
                        meta={"config": asdict(config), "observation_shape": list(local.observation_space.shape)})
        atomic_write_json(out / "metrics.json", metrics)
    return metrics

"""Ray simulator workers (thesis §6.1): episodes stream to the SAC + HER learner, and a worker killed
mid-run is restarted while the run finishes, losing only its in-flight episode."""

from __future__ import annotations

import os
import signal

import pytest

from binpick.integrations.ray.learner import DistributedConfig, train_distributed


@pytest.mark.slow
def test_a_killed_worker_is_restarted_and_the_run_finishes(tmp_path):
    killed, back = [], set()

    def on_episode(episode, rollouts, model):
        assert episode.steps > 0 and len(episode.observations) == episode.steps
        if not killed and model.num_timesteps >= 100:
            pid = rollouts.worker_pids()[0]
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
            back.add(rollouts.worker_pids()[0])  # waits while Ray restarts the worker

    config = DistributedConfig(workers=2, total_timesteps=800, learning_starts=100, batch_size=32, eval_episodes=2)
    metrics = train_distributed(config, tmp_path / "run", on_episode=on_episode)
    assert killed and metrics["env_steps"] >= 800
    assert back - set(killed), "worker 0 did not come back in a new process"
    # its episode in flight is lost, unless the kill came before the worker had started it
    assert metrics["worker_restarts"] <= 1 and metrics["lost_episodes"] <= 1
    assert sum(metrics["steps_per_worker"].values()) == metrics["env_steps"]
    from binpick.rl.persistence import load_saved_policy

    policy = load_saved_policy(tmp_path / "run" / "policy.safetensors")
    assert policy.action_space.shape == (4,) and "desired_goal" in policy.observation_space.spaces


@pytest.mark.slow
def test_a3c_workers_as_ray_actors_send_gradients_to_the_learner(tmp_path):
    from binpick.integrations.ray.a3c import DistributedA3CConfig, train_a3c_distributed

    seen = []
    metrics = train_a3c_distributed(DistributedA3CConfig(workers=2, total_timesteps=120, n_steps=20, eval_episodes=1),
                                    tmp_path / "a3c", on_update=lambda steps, pool: seen.append(steps))
    assert metrics["env_steps"] >= 120 and metrics["updates"] == len(seen) >= 6 and seen == sorted(seen)
    from binpick.core import tensorfile

    weights, meta, _ = tensorfile.load(tmp_path / "a3c" / "model.safetensors", "binpick-a3c-model-1")
    assert meta["config"]["workers"] == 2 and any(v.abs().sum() > 0 for v in weights.values())

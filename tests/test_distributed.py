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


A3C = {"task": "rl", "name": "a3c_ray", "env": "Arm2D", "env_kwargs": {"image_size": 32, "tolerance": 0.2}, "algorithm": "a3c",
       "total_timesteps": 400, "checkpoint_every": 200, "a3c": {"workers": 2, "n_steps": 15},
       "eval": {"every": 100, "episodes": 2}}


@pytest.fixture(scope="module")
def ray_cluster():
    """One private cluster (127.0.0.1) for the A3C runs: each joins it instead of starting its own."""
    import ray

    from binpick.cluster import start_ray

    start_ray(None, 2)
    yield
    ray.shutdown()


@pytest.mark.slow
def test_a3c_from_an_rl_yaml_on_ray_actors_ends_as_a_run_without_the_fault(tmp_path, ray_cluster):
    """The same RL YAML as a local run, its workers as Ray actors: the run folder, checkpoints and
    metrics a local run writes; evaluations at exact multiples of eval.every and the exact step budget,
    with or without a rollout worker killed mid-run."""
    import yaml

    from binpick import jobs
    from binpick.integrations.ray.a3c import learn_on_ray
    from binpick.rl.a3c_train import A3CTrainer
    from binpick.rl.config import RLConfig
    from binpick.core.config import from_dict

    path = tmp_path / "a3c.yaml"
    path.write_text(yaml.safe_dump(A3C))
    plain = jobs.train(path, runs=tmp_path / "plain", address="local")  # what `binpick train a3c.yaml --address local` runs
    steps = [e["sim_steps"] for e in plain["evaluations"]]
    assert plain["sim_steps"] == 400 and steps == [100, 200, 300, 400]
    (run,) = (tmp_path / "plain" / "a3c_ray").iterdir()
    assert (run / "metrics.json").is_file() and (run / "curves.png").is_file() and list((run / "tb").iterdir())
    assert (run / "checkpoints" / "latest").read_text().strip() == "ckpt-000000400"

    killed: list[int] = []

    def kill_one_mid_run(trainer, actors) -> None:
        if not killed and trainer.steps >= 150:
            pid = actors.pids()[1]
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    config = from_dict(RLConfig, {k: v for k, v in A3C.items() if k != "task"}, where="test")
    trainer = A3CTrainer.new(config, tmp_path / "faulty")
    faulty = trainer.run(learn=learn_on_ray("local", on_update=kill_one_mid_run))
    assert killed, "no rollout worker was killed"
    assert faulty["sim_steps"] == plain["sim_steps"] and [e["sim_steps"] for e in faulty["evaluations"]] == steps
    assert faulty["worker_restarts"] == 1 and faulty["lost_rollouts"] >= 1
    assert faulty["episodes"] > 0 and all(0 <= e["success_rate"] <= 1 for e in faulty["evaluations"])

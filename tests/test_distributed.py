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
    pids: list[int] = []

    def kill_one_mid_run(trainer, actors) -> None:
        """Worker 1 SIGKILLed while a rollout of its is in flight (so that rollout is lost)."""
        if not pids:
            pids.extend(actors.pids())  # asked once: a pid call waits behind the worker's rollout
        if not killed and trainer.steps >= 150 and 1 in actors.in_flight.values():
            os.kill(pids[1], signal.SIGKILL)
            killed.append(pids[1])

    config = from_dict(RLConfig, {k: v for k, v in A3C.items() if k != "task"}, where="test")
    trainer = A3CTrainer.new(config, tmp_path / "faulty")
    faulty = trainer.run(learn=learn_on_ray("local", on_update=kill_one_mid_run))
    assert killed, "no rollout worker was killed"
    assert faulty["sim_steps"] == plain["sim_steps"] and [e["sim_steps"] for e in faulty["evaluations"]] == steps
    assert faulty["worker_restarts"] == 1 and faulty["lost_rollouts"] >= 1
    assert faulty["episodes"] > 0 and all(0 <= e["success_rate"] <= 1 for e in faulty["evaluations"])


@pytest.mark.slow
def test_a_killed_driver_resumes_on_ray_with_the_steps_and_evaluations_of_an_uninterrupted_run(tmp_path):
    """`binpick train A3C.yaml --address local` killed (driver and its private cluster, SIGKILL) after its
    first checkpoint; `binpick train --resume RUN --address local` ends at the exact budget with every
    evaluation once, at the steps an uninterrupted run has."""
    import json
    import subprocess
    import sys
    import time

    import yaml

    cli = [sys.executable, "-c", "from binpick.cli import main; main()"]
    path = tmp_path / "a3c.yaml"
    path.write_text(yaml.safe_dump({**A3C, "total_timesteps": 600, "checkpoint_every": 200, "eval": {"every": 200, "episodes": 1}}))
    driver = subprocess.Popen([*cli, "train", str(path), "--address", "local", "--runs", str(tmp_path / "runs")],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.monotonic() + 240
    latest = None
    while time.monotonic() < deadline and driver.poll() is None:
        found = list((tmp_path / "runs" / "a3c_ray").glob("*/checkpoints/latest"))
        if found:
            latest = found[0]
            break
        time.sleep(0.1)
    assert latest is not None, driver.stderr.read().decode()[-2000:] if driver.poll() is not None else "no checkpoint in time"
    os.killpg(driver.pid, signal.SIGKILL)  # the driver and the Ray processes it started
    driver.wait(timeout=30)
    run = latest.parents[1]
    assert not (run / "metrics.json").exists()  # it did not finish
    resumed = subprocess.run([*cli, "train", "--resume", str(run), "--address", "local"], capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["sim_steps"] == 600 and [e["sim_steps"] for e in metrics["evaluations"]] == [200, 400, 600]

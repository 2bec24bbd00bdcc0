"""RL on Ray actors (thesis §6.1): the sac learner (GP + HER) fed by simulator actors and A3C's rollout
workers, each from the same RL YAML and into the same run folder as a local run; a simulator or worker
killed mid-run is restarted and the run ends with the steps and evaluations of a run without the fault."""

from __future__ import annotations

import os
import signal

import pytest

from binpick.core.errors import WorkerError

GP_HER = {"task": "rl", "name": "gp_her_ray", "env": "FetchReach", "env_kwargs": {"terminate_on_success": False},
          "algorithm": "sac", "total_timesteps": 300,
          "checkpoint_every": 100, "replay": {"capacity_episodes": 200, "her_additions": 2},
          "gp": {"enabled": True, "warmup_episodes": 2, "refit_every": 100, "imagined_per_real": 2, "batch_episodes": 20,
                 "max_points": 100, "iterations": 5},
          "sac": {"batch_size": 32, "net_arch": [16, 16], "gradient_steps": 1}, "eval": {"every": 100, "episodes": 2}}


@pytest.mark.slow
def test_gp_her_from_an_rl_yaml_on_ray_simulators_ends_as_a_run_without_the_fault(tmp_path, ray_cluster):
    """`binpick train GP_HER.yaml --address local --workers 2`: the learner here, two simulators as actors;
    with one simulator SIGKILLed mid-episode the run has the same steps and evaluations, one restart, and
    the lost episode is not in the replay."""
    import json

    import yaml

    from binpick.core import jobs
    from binpick.core.config import from_dict
    from binpick.integrations.ray.envs import RayVecEnv
    from binpick.rl.config import RLConfig
    from binpick.rl.train import Trainer

    path = tmp_path / "gp_her.yaml"
    path.write_text(yaml.safe_dump(GP_HER))
    plain = jobs.train(path, runs=tmp_path / "plain", address="local", workers=2)
    steps = [e["sim_steps"] for e in plain["evaluations"]]
    assert plain["sim_steps"] == 300 and steps == [100, 200, 300] and plain["worker_restarts"] == 0
    assert plain["gp_fits"] >= 1 and plain["imagined_episodes"] > 0 and plain["gradient_steps"] > 0
    assert plain["sim_episodes"] == 6  # 3 whole 50-step episodes on each of 2 simulators
    (run,) = (tmp_path / "plain" / "gp_her_ray").iterdir()
    assert json.loads((run / "metrics.json").read_text())["sim_steps"] == 300 and (run / "curves.png").is_file()
    assert (run / "checkpoints" / "latest").read_text().strip() == "ckpt-000000300" and list((run / "tb").iterdir())

    class KillOneMidEpisode(RayVecEnv):
        vector_steps, killed = 0, []

        def step_wait(self):
            self.vector_steps += 1
            if self.vector_steps == 60:  # step 10 of simulator 0's second episode
                pid = self.pids()[0]
                os.kill(pid, signal.SIGKILL)
                self.killed.append(pid)
            return super().step_wait()

    config = from_dict(RLConfig, {k: v for k, v in GP_HER.items() if k != "task"}, where="test")
    trainer = Trainer.new(config, tmp_path / "faulty")
    envs = KillOneMidEpisode(config, 2, None, trainer.env)
    faulty = trainer.run(envs=envs)
    assert envs.killed, "no simulator was killed"
    assert faulty["sim_steps"] == 300 and [e["sim_steps"] for e in faulty["evaluations"]] == steps
    assert faulty["worker_restarts"] == 1
    assert faulty["sim_episodes"] == 5  # simulator 0's second episode was lost (its 10 steps are not in the replay)
    assert trainer.model.replay_buffer.real_transitions == 5 * 50


def test_a_simulator_that_cannot_start_fails_in_one_line(ray_cluster):
    """An actor whose __init__ raises is not restarted for ever: the error names its cause at once."""
    from types import SimpleNamespace

    from binpick.envs import make
    from binpick.integrations.ray.envs import RayVecEnv

    broken = SimpleNamespace(algorithm="sac", env="binpick/NoSuchEnv-v0", env_kwargs={}, semantic_state=False,
                             min_action_scale=0.0)
    with pytest.raises(WorkerError, match="could not start on Ray: .*NoSuchEnv") as raised:
        RayVecEnv(broken, 1, None, make("FetchReach"))
    assert "\n" not in str(raised.value)


def test_an_a3c_worker_that_cannot_start_fails_in_one_line(ray_cluster):
    from binpick.integrations.ray.actors import RestartingActors

    class Broken:
        def __init__(self) -> None:
            raise RuntimeError("no simulator here")

        def play(self) -> int:
            return 1

    pool = RestartingActors(Broken, [()])
    try:
        pool.start(0, pool.actors[0].play.remote())
        with pytest.raises(WorkerError, match="worker 0 could not start on Ray: .*no simulator here"):
            pool.next_result(timeout=60)
    finally:
        pool.close()


A3C = {"task": "rl", "name": "a3c_ray", "env": "Arm2D", "env_kwargs": {"image_size": 32, "tolerance": 0.2}, "algorithm": "a3c",
       "total_timesteps": 400, "checkpoint_every": 200, "a3c": {"workers": 2, "n_steps": 15},
       "eval": {"every": 100, "episodes": 2}}


@pytest.mark.slow
def test_a3c_from_an_rl_yaml_on_ray_actors_ends_as_a_run_without_the_fault(tmp_path, ray_cluster):
    """The same RL YAML as a local run, its workers as Ray actors: the run folder, checkpoints and
    metrics a local run writes; evaluations at exact multiples of eval.every and the exact step budget,
    with or without a rollout worker killed mid-run."""
    import yaml

    from binpick.core import jobs
    from binpick.integrations.ray.a3c import learn_on_ray
    from binpick.rl.a3c.train import A3CTrainer
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
    import time

    import cli_zygote
    import yaml

    path = tmp_path / "a3c.yaml"
    path.write_text(yaml.safe_dump({**A3C, "total_timesteps": 600, "checkpoint_every": 200, "eval": {"every": 200, "episodes": 1}}))
    driver = cli_zygote.popen(["train", str(path), "--address", "local", "--runs", str(tmp_path / "runs")],
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
    resumed = cli_zygote.run(["train", "--resume", str(run), "--address", "local"], capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["sim_steps"] == 600 and [e["sim_steps"] for e in metrics["evaluations"]] == [200, 400, 600]

"""RL runs end to end on tiny settings: run folder, kill -9 and resume, eval, one-line errors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import cli_zygote
from conftest import binpick_here

from binpick.core.config import from_dict
from binpick.core.errors import ConfigError
from binpick.rl.config import RLConfig

TINY = """
name: tiny
env: FetchReach
total_timesteps: {steps}
min_action_scale: 0.4
checkpoint_every: 100
replay: {{capacity_episodes: 300, her_additions: 1, start_fraction: 0.01}}
gp: {{enabled: true, warmup_episodes: 3, refit_every: 100, imagined_per_real: 2, batch_episodes: 8, iterations: 5, max_points: 200}}
sac: {{batch_size: 32, net_arch: [16, 16]}}
eval: {{every: 200, episodes: 2}}
"""


def cli(*args: str) -> subprocess.CompletedProcess:
    return binpick_here(list(args))


def test_killed_run_resumes_from_its_last_checkpoint(tmp_path):
    config = tmp_path / "tiny.yaml"
    config.write_text(TINY.format(steps=900))
    process = cli_zygote.popen(["rl", "train",
                                str(config), "--runs", str(tmp_path / "runs")],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 240
    pointer = None
    while time.time() < deadline and process.poll() is None:
        found = list((tmp_path / "runs").glob("tiny/*/checkpoints/latest"))
        if found and found[0].read_text() >= "ckpt-000000300":
            pointer = found[0]
            break
        time.sleep(0.2)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    assert pointer is not None, "no checkpoint appeared before the deadline"
    run = pointer.parents[1]
    killed_at = int(pointer.read_text().split("-")[1])
    assert killed_at < 900
    result = cli("rl", "train", "--resume", str(run))
    assert result.returncode == 0, result.stderr
    assert f"resuming {run} at {killed_at} simulator steps" in result.stdout.replace("\n", "")
    metrics = json.loads((run / "metrics.json").read_text())
    steps = [e["sim_steps"] for e in metrics["evaluations"]]
    assert metrics["sim_steps"] == 900 and steps == sorted(set(steps)) and steps[-1] == 900
    assert all(s % 200 == 0 or s == 900 for s in steps), steps


@pytest.mark.parametrize(
    "data,fragment",
    [
        ({"algo": "sac"}, "has no key 'algo'"),
        ({"algorithm": "ppo"}, "algorithm must be one of 'sac', 'sb3_sac_her'"),
        ({"replay": {"her_additions": -1}}, "alpha_HER"),
        ({"replay": {"capacity_episodes": 10}, "sac": {"batch_size": 64}}, "(M=10) must be >= sac.batch_size (64)"),
        ({"gp": {"iterations": "many"}}, "gp.iterations must be an integer"),
        ({"env": "Nope"}, "unknown env id 'Nope'"),
        ({"sac": {"ent_coef": "autox"}}, "sac.ent_coef must be a number, 'auto' or 'auto_<value>'"),
        ({"demonstrations": {"bc_alpha": -1}}, "demonstrations.bc_alpha"),
        ({"actor_noise": {"goal": -0.1}}, "actor_noise.goal"),
        ({"actor_noise": {"achieved": [0.01, 0.01]}}, "actor_noise.achieved must have 3 entries"),
        ({"actor_noise": {"gripper": 0.01}}, "actor_noise.gripper: binpick/FetchReach-v0's semantic state has no gripper"),
        ({"algorithm": "sb3_sac_her", "actor_noise": {"goal": 0.01}}, "actor_noise perturbs the semantic state"),
    ],
)
def test_bad_configs_name_the_key(data, fragment):
    with pytest.raises(Exception) as error:
        from_dict(RLConfig, data, "cfg.yaml")
    assert isinstance(error.value, (ConfigError, KeyError)) and fragment in str(error.value)


def test_cli_config_errors_are_one_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [x\n")
    result = cli("rl", "train", str(bad))
    assert result.returncode == 2 and "invalid YAML at line 2" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert "does not exist" in cli("rl", "train", str(tmp_path / "none.yaml")).stderr
    assert "not a run folder" in cli("rl", "eval", str(tmp_path)).stderr


def test_shipped_configs_load():
    from binpick.rl.config import RLConfig
    from binpick.core.config import load_config

    for path in Path(__file__).parents[1].glob("configs/rl/rl_*.yaml"):
        load_config(RLConfig, path)


def test_dqn_on_arm2d_images_trains_and_evaluates(tmp_path):
    config = tmp_path / "dqn.yaml"
    config.write_text("""
name: tiny_dqn
env: Arm2D
env_kwargs: {max_episode_steps: 60}
algorithm: dqn
total_timesteps: 300
checkpoint_every: 200
dqn: {buffer_size: 500, learning_starts: 100, target_update_interval: 50, batch_size: 16}
eval: {every: 300, episodes: 2}
""")
    result = cli("rl", "train", str(config), "--runs", str(tmp_path / "runs"))
    assert result.returncode == 0, result.stderr
    (run,) = (tmp_path / "runs" / "tiny_dqn").iterdir()
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["sim_steps"] == 300 and metrics["gradient_steps"] > 0
    assert cli("rl", "eval", str(run), "--episodes", "1").returncode == 0


def test_algorithm_and_env_must_fit_together():
    with pytest.raises(ConfigError, match="a3c learns with discrete actions"):
        from_dict(RLConfig, {"algorithm": "a3c", "env": "FetchReach"})
    with pytest.raises(ConfigError, match="Arm2D takes a3c or dqn"):
        from_dict(RLConfig, {"algorithm": "sac", "env": "Arm2D"})


def test_run_stops_after_enough_successful_evaluations(tmp_path):
    config = tmp_path / "stop.yaml"
    text = TINY.format(steps=900).replace("eval: {every: 200, episodes: 2}",
                                          "eval: {every: 200, episodes: 2, success_threshold: 0.0, stop_after_successes: 2}")
    config.write_text(text)
    result = cli("rl", "train", str(config), "--runs", str(tmp_path / "runs"))
    assert result.returncode == 0, result.stderr
    (run,) = (tmp_path / "runs" / "tiny").iterdir()
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["sim_steps"] == 400 and [e["sim_steps"] for e in metrics["evaluations"]] == [200, 400]
    result = cli("rl", "train", "--resume", str(run))  # finished early: resuming must not train on to 900
    assert result.returncode == 0, result.stderr
    assert json.loads((run / "metrics.json").read_text())["sim_steps"] == 400


def test_dqn_rejects_images_too_small_for_its_cnn():
    with pytest.raises(ConfigError, match="image_size >= 36"):
        from_dict(RLConfig, {"algorithm": "dqn", "env": "Arm2D", "env_kwargs": {"image_size": 32}})


def test_actor_noise_reaches_the_actor_and_never_the_critic():
    """``actor_noise``: in every update the actor reads s̄ plus noise of the configured size, the same
    noise in both slots that hold the achieved goal, while the critic reads the true s̄ of the same batch."""
    import numpy as np
    import torch

    from binpick.rl.train import build_model
    from binpick.rl.envs import make_env

    config = from_dict(RLConfig, {"env": "FetchReach", "total_timesteps": 400, "gp": {"enabled": False},
                                  "replay": {"capacity_episodes": 300, "start_fraction": 0.01},
                                  "sac": {"batch_size": 32, "net_arch": [16, 16], "learning_starts": 0},
                                  "actor_noise": {"achieved": 0.01, "goal": 0.05}}, "cfg.yaml")
    env = make_env(config)
    model = build_model(config, env, None)
    model.perturb_actor_inputs((0.0, 0.01, 0.05), gripper=0)
    seen: dict[str, list] = {"actor": [], "critic": []}
    for name, module in (("actor", model.actor), ("critic", model.critic)):
        module.features_extractor.register_forward_pre_hook(
            lambda _, inputs, name=name: seen[name].append({k: v.clone() for k, v in inputs[0].items()}))
    model.learn(400)
    # one update calls the actor on the batch s and then on s', the critic on s twice: pair the s calls
    actor = [b for b in seen["actor"] if len(b["observation"]) == 32][0::2]  # (rollouts call it on one s̄)
    critic = seen["critic"][0::2]
    assert len(actor) == len(critic) > 100, (len(actor), len(critic))
    for noisy, true in zip(actor, critic):
        torch.testing.assert_close(true["observation"], true["achieved_goal"])  # the env's own z, in both slots
        torch.testing.assert_close(noisy["observation"], noisy["achieved_goal"])  # one perceived z: the same noise
    gap = torch.cat([a["achieved_goal"] - c["achieved_goal"] for a, c in zip(actor, critic)])
    goal_gap = torch.cat([a["desired_goal"] - c["desired_goal"] for a, c in zip(actor, critic)])
    assert 0.009 < float(gap.std()) < 0.011 and 0.045 < float(goal_gap.std()) < 0.055, (gap.std(), goal_gap.std())

    batch = {"observation": torch.zeros(20_000, 3), "achieved_goal": torch.zeros(20_000, 3), "desired_goal": torch.zeros(20_000, 3)}
    view = model.actor_view(batch)
    assert np.isclose(float(view["achieved_goal"].std()), 0.01, rtol=0.05)
    assert np.isclose(float(view["desired_goal"].std()), 0.05, rtol=0.05)
    torch.testing.assert_close(view["observation"], view["achieved_goal"])
    model.actor_noise = None
    assert model.actor_view(batch) is batch


def test_actor_noise_leaves_privileged_state_and_moves_the_gripper_alone():
    import torch

    from binpick.rl.gp_her.agents import GoalSAC

    model = GoalSAC.__new__(GoalSAC)  # actor_view needs nothing else of the model
    model.perturb_actor_inputs(([0.02, 0.01, 0.0], 0.0, 0.0), gripper=3)  # per axis: x, y, z
    batch = {"observation": torch.zeros(5000, 9), "achieved_goal": torch.zeros(5000, 3), "desired_goal": torch.zeros(5000, 3)}
    view = model.actor_view(batch)
    spread = view["observation"][:, :3].std(0)
    assert 0.018 < float(spread[0]) < 0.022 and 0.009 < float(spread[1]) < 0.011 and float(spread[2]) == 0.0
    assert torch.count_nonzero(view["observation"][:, 3:]) == 0 and torch.count_nonzero(view["achieved_goal"]) == 0
    assert torch.count_nonzero(batch["observation"]) == 0, "the replay's own batch is left as it was"


def test_every_algorithm_a_config_may_name_is_declared_once_with_parts_that_import():
    from binpick.rl import config
    from binpick.rl.algorithms import ALGORITHMS

    assert set(ALGORITHMS) == set(config.ALGORITHMS)
    for algorithm in ALGORITHMS.values():
        parts = ["trainer", "env", "policy"] + (["learner"] if algorithm.learner else [])
        assert all(callable(algorithm.load(part)) for part in parts), algorithm.name
    assert [name for name, a in ALGORITHMS.items() if a.simulators_on_ray] == ["sac"]
    assert [name for name, a in ALGORITHMS.items() if not a.keeps_replay] == ["dqn"]

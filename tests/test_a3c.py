"""A3C (thesis §3.1.2) and the goal-area curriculum (§3.2)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import binpick_here
from gymnasium import spaces

from binpick.rl.a3c.networks import A3CWorker, ActorCritic, SharedAdam, apply_gradients
from binpick.rl.config.common import CurriculumConfig, CurriculumStage


class OneRightAction(gym.Env):
    """Blank 16x16 image; action 0 reaches the goal (reward 0, terminal), others cost -1."""

    observation_space = spaces.Box(0, 255, (16, 16, 3), np.uint8)
    action_space = spaces.Discrete(6)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros((16, 16, 3), np.uint8), {"is_success": False}

    def step(self, action):
        success = int(action) == 0
        return np.zeros((16, 16, 3), np.uint8), 0.0 if success else -1.0, success, False, {"is_success": success}


def test_worker_gradients_teach_the_global_network_the_rewarded_action():
    torch.manual_seed(0)
    model = ActorCritic((16, 16, 3), 6)
    model.share_memory()
    optimizer = SharedAdam(model.parameters(), lr=3e-3)
    worker = A3CWorker(lambda: gym.wrappers.TimeLimit(OneRightAction(), 20), (16, 16, 3), 6, seed=0, reward_scale=0.1)
    blank = torch.zeros(1, 16, 16, 3, dtype=torch.uint8)
    before = torch.softmax(model(blank)[0], -1)[0, 0].item()
    for _ in range(150):
        gradients, stats = worker.compute_gradients(model.state_dict())
        assert all(torch.isfinite(g).all() for g in gradients)
        apply_gradients(model, optimizer, gradients)
    after = torch.softmax(model(blank)[0], -1)[0, 0].item()
    assert before < 0.3 and after > 0.9, (before, after)


def test_rollouts_stop_at_episode_end_and_report_lengths():
    worker = A3CWorker(lambda: gym.wrappers.TimeLimit(OneRightAction(), 5), (16, 16, 3), 6, seed=1, n_steps=50)
    _, stats = worker.compute_gradients(ActorCritic((16, 16, 3), 6).state_dict())
    assert stats.steps <= 5 and stats.finished_lengths == [stats.steps]


def test_curriculum_ramps_and_holds():
    schedule = CurriculumConfig([CurriculumStage(0.0, 0, 100), CurriculumStage(0.5, 100, 50), CurriculumStage(1.0, 100)])
    areas = [schedule.goal_area(step) for step in (0, 99, 150, 200, 249, 300, 350, 10_000)]
    assert areas == [0.0, 0.0, 0.25, 0.5, 0.5, 0.75, 1.0, 1.0]
    assert schedule.total_steps == 350 and CurriculumConfig().goal_area(5) is None


A3C_RUN = """
name: tiny_a3c
env: Arm2D
env_kwargs: {{image_size: 32, tolerance: 0.2}}
algorithm: a3c
total_timesteps: {steps}
checkpoint_every: 200
a3c: {{workers: 2, n_steps: 10}}
curriculum: {{stages: [{{area: 0.0, hold_steps: 200}}, {{area: 1.0, ramp_steps: 200}}]}}
eval: {{every: 200, episodes: 2}}
"""


def test_a3c_run_with_curriculum_resumes_and_evaluates(tmp_path):
    config = tmp_path / "a3c.yaml"
    config.write_text(A3C_RUN.format(steps=400))
    result = binpick_here(["rl", "train", str(config), "--runs", str(tmp_path / "runs")])
    assert result.returncode == 0, result.stderr
    (run,) = (tmp_path / "runs" / "tiny_a3c").iterdir()
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["sim_steps"] >= 400 and metrics["algorithm"] == "a3c"
    areas = [e["goal_area"] for e in metrics["evaluations"]]
    assert areas[0] < 0.5 and areas[-1] == 1.0, areas
    assert (run / "curves.png").exists()
    # continue the finished run for longer: the step count carries on from the checkpoint
    saved = (run / "config.yaml").read_text().replace("total_timesteps: 400", "total_timesteps: 600")
    (run / "config.yaml").write_text(saved)
    resumed = binpick_here(["rl", "train", "--resume", str(run)])
    assert resumed.returncode == 0, resumed.stderr
    assert f"at {metrics['sim_steps']} simulator steps" in resumed.stdout.replace("\n", "")
    assert json.loads((run / "metrics.json").read_text())["sim_steps"] >= 600
    evaluation = binpick_here(["rl", "eval", str(run), "--episodes", "2"])
    assert evaluation.returncode == 0 and "actions per episode" in evaluation.stdout, evaluation.stderr
    _check_init_from(run, tmp_path)


def _check_init_from(source, tmp_path):
    """A curriculum run that starts from a trained run (thesis §3.2) carries weights and steps over."""
    import pytest
    import yaml

    from binpick.core.config import from_dict
    from binpick.core.errors import ConfigError
    from binpick.rl.a3c.policy import read_a3c_checkpoint
    from binpick.core.runs import latest_checkpoint
    from binpick.rl.config import RLConfig
    from binpick.rl.train import trainer_for

    settings = yaml.safe_load(A3C_RUN.format(steps=800)) | {"init_from": str(source)}
    trainer = trainer_for(from_dict(RLConfig, settings), tmp_path / "continued")
    saved, _ = read_a3c_checkpoint(latest_checkpoint(source / "checkpoints"))
    assert trainer.steps_done >= 600 and trainer.steps_done == json.loads((source / "metrics.json").read_text())["sim_steps"]
    assert all(torch.equal(trainer.model.state_dict()[k], v) for k, v in saved["model"].items())
    assert trainer.goal_area(trainer.steps_done) == 1.0  # the schedule counts the source run's steps
    other_size = settings | {"env_kwargs": {"image_size": 48, "tolerance": 0.2}}
    with pytest.raises(ConfigError, match="shape"):
        trainer_for(from_dict(RLConfig, other_size), tmp_path / "bad")
    with pytest.raises(ConfigError, match="not a run folder"):
        trainer_for(from_dict(RLConfig, settings | {"init_from": str(tmp_path)}), tmp_path / "bad")
    with pytest.raises(ConfigError, match="init_from continues an A3C run"):
        from_dict(RLConfig, settings | {"algorithm": "dqn"})


def test_sb3_curriculum_callback_widens_the_training_envs_goal_area(tmp_path):
    from binpick.core.config import from_dict, to_dict
    from binpick.rl.config import RLConfig
    from binpick.rl.train import Trainer, trainer_for

    config = from_dict(RLConfig, {
        "name": "curriculum_dqn", "env": "Arm2D", "env_kwargs": {"image_size": 40, "max_episode_steps": 30},
        "algorithm": "dqn", "total_timesteps": 300, "checkpoint_every": 1000,
        "dqn": {"buffer_size": 300, "learning_starts": 100, "batch_size": 8, "target_update_interval": 50},
        "curriculum": {"stages": [{"area": 0.0, "hold_steps": 100}, {"area": 1.0, "ramp_steps": 100}]},
        "eval": {"every": 1000, "episodes": 1},
    })
    trainer = trainer_for(config, tmp_path)
    seen = []
    original = trainer.env.unwrapped.set_goal_area
    trainer.env.unwrapped.set_goal_area = lambda area: (seen.append(area), original(area))
    trainer.run()
    assert seen[0] == 0.0 and seen[-1] == 1.0 and seen == sorted(seen)
    assert trainer.env.unwrapped.goal_area == 1.0
    # the thesis's rule: widen once the training episodes have re-converged; the state resumes
    converged = from_dict(RLConfig, to_dict(config) | {"name": "converged_dqn", "curriculum": {
        "advance": "converged", "window": 2, "tolerance": 1.0,
        "stages": [{"area": 0.0, "hold_steps": 100}, {"area": 1.0, "ramp_steps": 100}]}})
    trainer = trainer_for(converged, tmp_path)
    trainer.run()
    (start,) = trainer.curriculum.advanced_at
    assert 100 <= start < 300 and trainer.curriculum.goal_area(start + 100) == 1.0
    assert Trainer.resume(trainer.run_dir).curriculum.advanced_at == [start]


def test_curriculum_widens_only_once_the_agent_has_re_converged():
    """Thesis §3.2: hold an area until the recent average has settled, then ramp to the next."""
    import pytest

    from binpick.core.errors import ConfigError
    from binpick.rl.common.curriculum import CurriculumProgress

    schedule = CurriculumConfig([CurriculumStage(0.0, 0, 100), CurriculumStage(0.5, 100, 50), CurriculumStage(1.0, 100)],
                                advance="converged", window=5, tolerance=0.1)
    progress = CurriculumProgress(schedule)
    assert progress.goal_area(0) == 0.0
    assert not progress.record(50, [10] * 10, 0.0)  # settled, but the minimum hold is not over
    assert not progress.record(120, [40] * 5, 0.0) and progress.goal_area(10_000) == 0.0  # still changing
    assert progress.record(150, [40] * 5, 0.0) and progress.stage == 1  # two windows of 40: re-converged
    assert progress.goal_area(200) == 0.25 and progress.goal_area(250) == 0.5  # the ramp from 0 to 0.5
    assert not progress.record(260, [20] * 10, 0.25)  # episodes of the ramp do not count
    assert not progress.record(300, [60] * 5 + [20] * 5, 0.5)  # at 0.5 but not settled (60 -> 20)
    saved = progress.state_dict()
    resumed = CurriculumProgress(schedule)
    resumed.load_state_dict(saved)
    assert resumed.record(310, [20] * 5, 0.5) and resumed.stage == 2 and resumed.advanced_at == [150, 310]
    assert resumed.goal_area(360) == 0.75 and resumed.goal_area(10**6) == 1.0
    assert not resumed.record(10**6, [5] * 20, 1.0)  # the last stage holds for the rest of the run
    from binpick.core.errors import InputFileError

    with pytest.raises(InputFileError, match="curriculum state is damaged"):
        CurriculumProgress(schedule).load_state_dict({"stage": "two"})
    fixed = CurriculumProgress(CurriculumConfig([CurriculumStage(0.0, 0, 100), CurriculumStage(1.0, 100)]))
    assert fixed.goal_area(150) == 0.5 and not fixed.record(150, [1] * 1000, 0.5)  # steps mode ignores episodes
    with pytest.raises(ConfigError, match="curriculum.advance"):
        CurriculumConfig([CurriculumStage(0.0)], advance="sometimes")
    with pytest.raises(ConfigError, match="needs curriculum.stages"):
        CurriculumConfig(advance="converged")


def test_keypoints_read_where_a_feature_fires_anywhere_in_the_picture():
    """SpatialSoftmax gives a channel's peak position in [-1, 1] wherever the peak is: what the
    curriculum needs (a goal learnt in one place is found in every place)."""
    from binpick.rl.a3c.networks import SpatialSoftmax

    maps = torch.zeros(2, 1, 32, 32)
    maps[0, 0, 4, 27] = 50.0  # row 4, column 27
    maps[1, 0, 30, 1] = 50.0
    xy = SpatialSoftmax()(maps)
    expected = torch.tensor([[27 / 31 * 2 - 1, 4 / 31 * 2 - 1], [1 / 31 * 2 - 1, 30 / 31 * 2 - 1]])
    assert torch.allclose(xy, expected, atol=1e-3)
    model = ActorCritic((64, 64, 3), 6, encoder="keypoints")
    logits, values = model(torch.zeros(3, 64, 64, 3, dtype=torch.uint8))
    assert logits.shape == (3, 6) and values.shape == (3,)
    assert model.hidden[0].in_features == 64  # 32 maps x (x, y): nothing tied to a place in the picture


def test_a3c_encoder_is_saved_with_the_weights_and_a_mismatch_is_one_line(tmp_path):
    import pytest
    import yaml

    from binpick.core.config import from_dict
    from binpick.core.errors import ConfigError
    from binpick.rl.a3c.policy import load_a3c_policy
    from binpick.rl.config import RLConfig
    from binpick.rl.train import trainer_for
    from binpick.core.runs import latest_checkpoint

    settings = yaml.safe_load(A3C_RUN.format(steps=40)) | {"a3c": {"workers": 1, "n_steps": 5, "encoder": "keypoints"}}
    trainer = trainer_for(from_dict(RLConfig, settings), tmp_path / "runs")
    trainer.save_checkpoint()
    checkpoint = latest_checkpoint(trainer.run_dir / "checkpoints")
    policy = load_a3c_policy(checkpoint)
    assert policy.model.encoder == "keypoints"
    assert all(torch.equal(policy.model.state_dict()[k], v) for k, v in trainer.model.state_dict().items())
    flattened = settings | {"a3c": {"workers": 1, "n_steps": 5}, "init_from": str(trainer.run_dir)}
    with pytest.raises(ConfigError, match="a3c.encoder 'keypoints'"):
        trainer_for(from_dict(RLConfig, flattened), tmp_path / "other")
    with pytest.raises(ConfigError, match="a3c.encoder"):
        from_dict(RLConfig, settings | {"a3c": {"encoder": "pixels"}})
    # the auxiliary state head is saved with the weights; a run without it cannot start from them
    auxiliary = settings | {"a3c": {"workers": 1, "n_steps": 5, "encoder": "keypoints", "state_weight": 0.5}}
    trainer = trainer_for(from_dict(RLConfig, auxiliary), tmp_path / "aux")
    trainer.save_checkpoint()
    assert trainer.state_size == 7 and load_a3c_policy(latest_checkpoint(trainer.run_dir / "checkpoints")).model.state_size == 7
    with pytest.raises(ConfigError, match="auxiliary state head"):
        trainer_for(from_dict(RLConfig, settings | {"init_from": str(trainer.run_dir)}), tmp_path / "other2")
    # a3c.state_key names the info entry the head regresses: Arm2D's continuous state is 10 long
    continuous = auxiliary | {"a3c": auxiliary["a3c"] | {"state_key": "state_continuous"}}
    assert trainer_for(from_dict(RLConfig, continuous), tmp_path / "continuous").state_size == 10
    with pytest.raises(ConfigError, match=r"info\['nowhere'\]"):
        trainer_for(from_dict(RLConfig, auxiliary | {"a3c": auxiliary["a3c"] | {"state_key": "nowhere"}}), tmp_path / "bad")
    with pytest.raises(ConfigError, match="a3c.state_key"):
        from_dict(RLConfig, settings | {"a3c": {"state_key": ""}})


def test_auxiliary_state_loss_teaches_the_features_where_arm_and_goal_are(tmp_path):
    """a3c.state_weight: the trunk's features also regress info['state'] (joint angles, end point, goal),
    so they carry the goal even while the reward alone would not ask for it."""
    from binpick.envs import make

    def worker(weight):
        return A3CWorker(lambda: make("Arm2D", image_size=32, goal_area=1.0), (32, 32, 3), 6, seed=3, n_steps=20,
                         state_weight=weight, state_size=7)

    plain = worker(0.0)
    assert plain.model.state is None and plain.compute_gradients(plain.model.state_dict())[1].state_loss == 0.0
    continuous = A3CWorker(lambda: make("Arm2D", image_size=32, goal_area=1.0), (32, 32, 3), 6, seed=3, n_steps=5,
                           state_weight=1.0, state_size=10, state_key="state_continuous")  # regresses that entry
    assert continuous.semantic.shape == (10,) and continuous.compute_gradients(continuous.model.state_dict())[1].state_loss > 0
    env = make("Arm2D", image_size=32, goal_area=1.0)
    pictures, states = zip(*((image, info["state"]) for image, info in (env.reset(seed=s) for s in range(200))))
    pictures, states = torch.from_numpy(np.stack(pictures)), torch.as_tensor(np.stack(states), dtype=torch.float32)

    def end_point_error(model):  # mean distance of the predicted end point from the true one, held-out pictures
        with torch.no_grad():  # (the goal changes once an episode: too few of them here to learn it)
            return float((model.state(model.features(pictures))[:, 3:5] - states[:, 3:5]).norm(dim=1).mean())

    torch.manual_seed(0)
    aux = worker(1.0)
    model = ActorCritic((32, 32, 3), 6, state_size=7)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    before = end_point_error(model)
    for _ in range(300):
        apply_gradients(model, optimizer, aux.compute_gradients(model.state_dict())[0])
    assert end_point_error(model) < 0.85 * before, (before, end_point_error(model))  # 0.554 -> 0.408 measured


class SignPicksTheAction(gym.Env):
    """A two-number state; action 0 is right when its first number is positive, action 1 otherwise."""

    observation_space = spaces.Box(-1.0, 1.0, (2,), np.float64)
    action_space = spaces.Discrete(6)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.sign = 1.0 if self.np_random.random() < 0.5 else -1.0
        return np.array([self.sign, 0.5]), {"is_success": False}

    def step(self, action):
        success = int(action) == (0 if self.sign > 0 else 1)
        return np.array([self.sign, 0.5]), 0.0 if success else -1.0, success, False, {"is_success": success}


def test_state_encoder_learns_an_action_that_depends_on_the_state_vector():
    """a3c.encoder: state (perception taken away): the same worker and losses on a vector."""
    torch.manual_seed(0)
    model = ActorCritic((2,), 6, encoder="state")
    model.share_memory()
    optimizer = SharedAdam(model.parameters(), lr=3e-3)
    worker = A3CWorker(lambda: gym.wrappers.TimeLimit(SignPicksTheAction(), 20), (2,), 6, seed=0, reward_scale=0.1,
                       encoder="state")
    states = torch.tensor([[1.0, 0.5], [-1.0, 0.5]], dtype=torch.float64)
    for _ in range(300):
        apply_gradients(model, optimizer, worker.compute_gradients(model.state_dict())[0])
    right = torch.softmax(model(states)[0], -1)[[0, 1], [0, 1]]
    assert (right > 0.8).all(), right
    with pytest.raises(ValueError, match="flat vector"):
        ActorCritic((16, 16, 3), 6, encoder="state")


def test_state_encoder_runs_on_arm2d_state_and_mismatched_configs_are_one_line(tmp_path):
    import yaml

    from binpick.core.config import from_dict
    from binpick.core.errors import ConfigError
    from binpick.rl.a3c.policy import load_a3c_policy
    from binpick.rl.config import RLConfig
    from binpick.rl.train import trainer_for
    from binpick.core.runs import latest_checkpoint

    settings = yaml.safe_load(A3C_RUN.format(steps=40))
    state_run = settings | {"env_kwargs": {"goal_conditioned": True, "image": None, "tolerance": 0.2},
                            "a3c": {"workers": 1, "n_steps": 5, "encoder": "state"}}
    trainer = trainer_for(from_dict(RLConfig, state_run), tmp_path / "runs")
    metrics = trainer.run()
    assert trainer.observation_shape == (12,) and metrics["sim_steps"] >= 40  # cos, sin, end point, achieved, desired
    policy = load_a3c_policy(latest_checkpoint(trainer.run_dir / "checkpoints"))
    assert policy.model.encoder == "state" and 0 <= policy(np.zeros(12)) < 6
    from binpick.rl.envs import make_env  # what `binpick rl eval` plays the run on: the same flattened state

    env = make_env(trainer.config)
    assert env.observation_space.shape == (12,) and 0 <= policy(env.reset(seed=0)[0]) < 6
    from binpick import Policy  # the same actor through the one loader every trained policy has

    loaded = Policy.load(trainer.run_dir)
    action, state = loaded.predict(env.reset(seed=0)[0], deterministic=True)
    assert state is None and loaded.action_space.contains(int(action)) and loaded.observation_space.shape == (12,)
    with pytest.raises(ConfigError, match="a3c.encoder 'state' learns from Arm2D's state vector"):
        from_dict(RLConfig, settings | {"a3c": {"encoder": "state"}})
    with pytest.raises(ConfigError, match="image encoders need"):
        from_dict(RLConfig, state_run | {"a3c": {"encoder": "keypoints"}})
    with pytest.raises(ConfigError, match="image: null"):
        trainer_for(from_dict(RLConfig, state_run | {"env_kwargs": {"goal_conditioned": True}}), tmp_path / "r2")


def test_perception_pretraining_reads_the_state_before_rl_and_is_not_redone_on_resume(tmp_path):
    """a3c.pretrain_pictures: the trunk and state head learn info[state_key] from rendered pictures
    before any RL step; the run records it, checkpoints it, and a resumed run keeps the weights it has."""
    import yaml

    from binpick.core.config import from_dict
    from binpick.core.errors import ConfigError
    from binpick.rl.config import RLConfig
    from binpick.rl.train import trainer_for

    settings = yaml.safe_load(A3C_RUN.format(steps=20)) | {
        "a3c": {"workers": 1, "n_steps": 5, "encoder": "keypoints", "state_weight": 1.0, "state_key": "state_continuous",
                "pretrain_pictures": 1000, "pretrain_epochs": 6}}
    torch.manual_seed(0)
    trainer = trainer_for(from_dict(RLConfig, settings), tmp_path / "runs")
    metrics = trainer.run()
    pretrain = metrics["pretrain"]
    assert pretrain["pictures"] == 1000 and pretrain["held_out_error"] < 0.8 * pretrain["untrained_error"], pretrain  # 0.44 vs 0.62
    resumed = trainer_for(resume=trainer.run_dir)
    assert resumed.metrics["pretrain"] == pretrain
    weights = {k: v.clone() for k, v in resumed.model.state_dict().items()}
    resumed.run()  # at its budget already: evaluates nothing new, trains nothing, does not pretrain again
    assert all(torch.equal(weights[k], v) for k, v in resumed.model.state_dict().items())
    for bad, message in [({"state_weight": 0.0}, "needs the auxiliary state head"),
                         ({"encoder": "state"}, "has none"), ({"pretrain_epochs": 0}, "a3c.pretrain_epochs")]:
        with pytest.raises(ConfigError, match=message):
            from_dict(RLConfig, settings | {"a3c": settings["a3c"] | bad})


def test_state_estimate_bottleneck_acts_on_the_read_state_and_is_saved_with_the_weights(tmp_path):
    """a3c.policy_input: state_estimate: the policy and value see the picture only through the state
    the auxiliary head reads off it, so two pictures read as the same state get the same action probabilities."""
    import yaml

    from binpick.envs import make

    from binpick.core.config import from_dict
    from binpick.core.errors import ConfigError
    from binpick.rl.a3c.policy import load_a3c_policy
    from binpick.rl.config import RLConfig
    from binpick.rl.train import trainer_for
    from binpick.core.runs import latest_checkpoint

    torch.manual_seed(0)
    pictures = torch.randint(0, 256, (4, 32, 32, 3), dtype=torch.uint8)
    bottleneck, plain = ActorCritic((32, 32, 3), 6, "keypoints", 10, "state_estimate"), ActorCritic((32, 32, 3), 6, "keypoints", 10)
    with torch.no_grad():
        for model in (bottleneck, plain):
            model.state.weight.zero_()  # every picture now reads as the same state (the head's bias)
        logits, values = bottleneck(pictures)
        assert torch.allclose(logits, logits[:1].expand_as(logits)) and torch.allclose(values, values[:1].expand_as(values))
        logits, _ = plain(pictures)  # without the bottleneck the heads still see the pictures
        assert not torch.allclose(logits, logits[:1].expand_as(logits))
    # a worker's update reaches the controller MLP (the trunk it always reaches through the auxiliary loss)
    worker = A3CWorker(lambda: make("Arm2D", image_size=32, goal_area=1.0), (32, 32, 3), 6, seed=3, n_steps=5,
                       encoder="keypoints", state_weight=1.0, state_size=10, state_key="state_continuous",
                       policy_input="state_estimate")
    model = ActorCritic((32, 32, 3), 6, "keypoints", 10, "state_estimate")
    gradients = dict(zip((name for name, _ in model.named_parameters()), worker.compute_gradients(model.state_dict())[0]))
    assert gradients["controller.0.weight"].abs().sum() > 0 and gradients["trunk.0.weight"].abs().sum() > 0
    with pytest.raises(ValueError, match="needs state_size"):
        ActorCritic((32, 32, 3), 6, "keypoints", 0, "state_estimate")
    # a3c.detach_perception: the policy's and value's losses stop at the state estimate; the trunk learns from
    # the auxiliary loss alone
    for policy_input in ("state_estimate", "features"):
        detached = ActorCritic((32, 32, 3), 6, "keypoints", 10, policy_input, detach_perception=True)
        logits, values = detached(pictures)
        (logits.sum() + values.sum()).backward()
        assert detached.trunk[0].weight.grad is None and detached.policy.weight.grad.abs().sum() > 0
        detached.state(detached.features(pictures)).sum().backward()
        assert detached.trunk[0].weight.grad.abs().sum() > 0
    # saved with the weights; a run without it cannot continue from them; bad configs are one line
    settings = yaml.safe_load(A3C_RUN.format(steps=40)) | {
        "env_kwargs": {"image_size": 32},
        "a3c": {"workers": 1, "n_steps": 5, "encoder": "keypoints", "state_weight": 1.0, "state_key": "state_continuous",
                "policy_input": "state_estimate"}}
    trainer = trainer_for(from_dict(RLConfig, settings), tmp_path / "runs")
    trainer.save_checkpoint()
    policy = load_a3c_policy(latest_checkpoint(trainer.run_dir / "checkpoints"))
    assert policy.model.policy_input == "state_estimate"
    assert all(torch.equal(policy.model.state_dict()[k], v) for k, v in trainer.model.state_dict().items())
    plain_run = settings | {"a3c": settings["a3c"] | {"policy_input": "features"}, "init_from": str(trainer.run_dir)}
    with pytest.raises(ConfigError, match="a3c.policy_input 'state_estimate'"):
        trainer_for(from_dict(RLConfig, plain_run), tmp_path / "other")
    for bad, message in [({"state_weight": 0.0}, "set a3c.state_weight > 0"), ({"policy_input": "state"}, "a3c.policy_input"),
                         ({"detach_perception": "yes"}, "a3c.detach_perception must be true or false")]:
        with pytest.raises(ConfigError, match=message):
            from_dict(RLConfig, settings | {"a3c": settings["a3c"] | bad})


def test_state_noise_perturbs_each_step_reproducibly_and_only_state_vectors():
    """a3c.state_noise: the state learner given a picture reader's error, fresh each step, seeded by
    reset; the env underneath (goal, start) is the same as without it."""
    from binpick.core.config import from_dict
    from binpick.core.errors import ConfigError
    from binpick.rl.a3c.envs import make_a3c_env as make_env
    from binpick.rl.config import RLConfig

    settings = {"name": "noisy", "env": "binpick/Arm2D-v0", "env_kwargs": {"goal_conditioned": True, "image": None},
                "algorithm": "a3c", "total_timesteps": 10, "a3c": {"encoder": "state", "state_noise": 0.05}}
    noisy, clean = make_env(from_dict(RLConfig, settings)), make_env(from_dict(RLConfig, settings | {"a3c": {"encoder": "state"}}))
    errors = []
    for seed in range(50):
        first, second, truth = noisy.reset(seed=seed)[0], noisy.reset(seed=seed)[0], clean.reset(seed=seed)[0]
        assert np.array_equal(first, second)  # same seed, same noise
        errors.append(first - truth)
        stepped, truth = noisy.step(0)[0], clean.step(0)[0]
        assert not np.allclose(stepped - truth, errors[-1])  # fresh noise each step
    assert 0.04 < np.std(errors) < 0.06 and abs(np.mean(errors)) < 0.01
    with pytest.raises(ConfigError, match="a3c.state_noise"):
        from_dict(RLConfig, settings | {"env_kwargs": {}, "a3c": {"encoder": "keypoints", "state_noise": 0.05}})


def test_pretraining_pictures_can_end_like_successful_episodes():
    """a3c.pretrain_near_goal: that fraction of the pictures has the goal next to the tip, where random poses
    seldom put it; the rest stay random poses with goals anywhere."""
    from binpick.envs import make
    from binpick.rl.a3c.pretrain import render_states

    def distances(near_goal):
        _, states = render_states(lambda: make("Arm2D", image_size=16), "state_continuous", 200, 0, near_goal)
        return (states[:, 6:8] - states[:, 8:10]).norm(dim=1)

    anywhere, near = distances(0.0), distances(1.0)
    # offsets of 1.5 radii a coordinate: 64% of the near pictures within 0.15, 98% within 0.3 (measured 0.62 / 2%)
    assert (anywhere < 0.15).float().mean() < 0.1 and (near < 0.3).float().mean() > 0.9
    assert 0.2 < (distances(0.5) < 0.15).float().mean() < 0.45


@pytest.mark.parametrize("spawned", ["0", "1"], ids=["forkserver", "spawn"])
def test_workers_stop_when_the_trainer_is_killed(tmp_path, spawned):
    """A SIGKILLed trainer cannot stop its daemon workers; they must notice and exit, not keep two cores busy
    training weights nobody will save (workers forked from the forkserver, and spawned ones)."""
    import signal
    import time

    config = tmp_path / "run.yaml"
    config.write_text(A3C_RUN.format(steps=10_000_000).replace("checkpoint_every: 200", "checkpoint_every: 1000000"))
    from pathlib import Path

    command = [str(Path(sys.executable).parent / "binpick"), "rl", "train", str(config), "--runs", str(tmp_path / "runs")]
    trainer = subprocess.Popen(command, env={**os.environ, "BINPICK_SPAWN_WORKERS": spawned},
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(workers) < 2:  # the two workers
            time.sleep(1)
            workers = _worker_pids(trainer.pid)
        assert len(workers) >= 2, workers
        time.sleep(5)  # the workers are training
        assert all(_running(pid) for pid in workers), workers
        os.kill(trainer.pid, signal.SIGKILL)
        trainer.wait()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and any(_running(pid) for pid in workers):
            time.sleep(1)
        alive = [pid for pid in workers if _running(pid)]
        assert not alive, f"workers {alive} outlived their trainer"
    finally:
        if trainer.poll() is None:
            trainer.kill()
        for pid in workers:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _children(pid: int) -> list[int]:
    try:
        return [int(child) for child in open(f"/proc/{pid}/task/{pid}/children").read().split()]
    except OSError:
        return []


def _command(pid: int) -> str:
    try:
        return open(f"/proc/{pid}/cmdline").read()
    except OSError:
        return ""


def _worker_pids(trainer: int) -> list[int]:
    """The trainer's worker processes: its spawned children, or the children of its forkserver (the
    resource tracker and the forkserver itself are not workers)."""
    pids = []
    for child in _children(trainer):
        command = _command(child)
        if "multiprocessing.forkserver" in command:
            pids += _children(child)
        elif "spawn_main" in command and "resource_tracker" not in command:
            pids.append(child)
    return pids


def _running(pid: int) -> bool:
    return os.path.exists(f"/proc/{pid}") and "Z" not in _process_state(pid)


def _process_state(pid: int) -> str:
    try:
        return open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "Z"


def test_reading_errors_add_a_row_of_the_table_seeded_and_untied_from_the_pose():
    """ReadingErrors: each step adds one row of a perception's measured errors, drawn at random, so
    the same pose gets different errors; the same seed draws the same rows; a table of the wrong width is one line."""
    from gymnasium.wrappers import FlattenObservation

    from binpick.envs import make
    from binpick.core.errors import ConfigError
    from binpick.rl.common.wrappers import ReadingErrors

    table = np.random.default_rng(0).normal(0.0, 0.05, (40, 12))
    base = FlattenObservation(make("binpick/Arm2D-v0", goal_conditioned=True, image=None))
    env = ReadingErrors(FlattenObservation(make("binpick/Arm2D-v0", goal_conditioned=True, image=None)), table)
    drawn = []
    for seed in range(30):
        first, truth = env.reset(seed=seed)[0], base.reset(seed=seed)[0]
        assert np.array_equal(first, env.reset(seed=seed)[0])
        difference = first - truth
        assert np.isclose(np.abs(table - difference).max(1), 0.0, atol=1e-12).any()  # one of the table's rows
        drawn.append(int(np.argmin(np.abs(table - difference).max(1))))
    assert len(set(drawn)) > 10
    # the same pose, reached twice, is read with different errors
    env.reset(seed=0)
    there, back = env.step(0)[0], (env.step(1), env.step(0))[1][0]
    assert np.allclose(there[:2], back[:2], atol=0.2) and not np.allclose(there, back)
    with pytest.raises(ConfigError, match=r"\(N, 12\)"):
        ReadingErrors(FlattenObservation(make("binpick/Arm2D-v0", goal_conditioned=True, image=None)), table[:, :5])


def test_hidden_layers_deepen_the_heads_network_and_are_saved_with_the_weights(tmp_path):
    """a3c.hidden_layers: the layers between what the network reads and its heads. One (the default)
    keeps older checkpoints' layout; two gives the pixel learner's heads the state learner's depth. A run with
    another depth cannot continue from the weights; a bad value is one line."""
    import yaml

    from binpick.core.config import from_dict
    from binpick.core.errors import ConfigError
    from binpick.rl.a3c.policy import load_a3c_policy
    from binpick.rl.config import RLConfig
    from binpick.rl.train import trainer_for
    from binpick.core.runs import latest_checkpoint

    def linears(module):
        return [m for m in module if isinstance(m, torch.nn.Linear)]

    one, two = ActorCritic((32, 32, 3), 6, "keypoints", 10, "state_estimate"), ActorCritic(
        (32, 32, 3), 6, "keypoints", 10, "state_estimate", hidden_layers=2)
    assert (len(linears(one.hidden)), len(linears(one.controller))) == (1, 1)
    assert (len(linears(two.hidden)), len(linears(two.controller))) == (2, 2)
    assert set(one.state_dict()) < set(two.state_dict()) and "hidden.0.weight" in one.state_dict()
    # parameters in the order older checkpoints' optimiser states list them (matched by position, not name)
    for model in (one, two):
        modules = [name.split(".")[0] for name, _ in model.named_parameters()]
        assert list(dict.fromkeys(modules)) == ["trunk", "hidden", "policy", "value", "state", "controller"]
    logits, values = two(torch.randint(0, 256, (3, 32, 32, 3), dtype=torch.uint8))
    assert logits.shape == (3, 6) and values.shape == (3,)
    none = ActorCritic((8,), 6, "state", hidden_layers=0)  # the state learner with one layer: its trunk's
    assert len(none.hidden) == 0 and none.policy.in_features == 256
    assert ActorCritic((32, 32, 3), 6, "keypoints", 10, "state_estimate", hidden_layers=0).policy.in_features == 10
    with pytest.raises(ValueError, match="hidden_layers"):
        ActorCritic((8,), 6, "state", hidden_layers=-1)
    settings = yaml.safe_load(A3C_RUN.format(steps=40)) | {
        "env_kwargs": {"image_size": 32}, "a3c": {"workers": 1, "n_steps": 5, "encoder": "keypoints", "hidden_layers": 2}}
    trainer = trainer_for(from_dict(RLConfig, settings), tmp_path / "runs")
    trainer.save_checkpoint()
    policy = load_a3c_policy(latest_checkpoint(trainer.run_dir / "checkpoints"))
    assert policy.model.hidden_layers == 2
    assert all(torch.equal(policy.model.state_dict()[k], v) for k, v in trainer.model.state_dict().items())
    shallow = settings | {"a3c": settings["a3c"] | {"hidden_layers": 1}, "init_from": str(trainer.run_dir)}
    with pytest.raises(ConfigError, match="a3c.hidden_layers 2"):
        trainer_for(from_dict(RLConfig, shallow), tmp_path / "other")
    with pytest.raises(ConfigError, match="a3c.hidden_layers"):
        from_dict(RLConfig, settings | {"a3c": settings["a3c"] | {"hidden_layers": -1}})


class _BreaksOnStep:
    """A wrap_env whose env fails on its first step: only A3C's workers step it (module level: it pickles)."""

    def __call__(self, env):
        import gymnasium as gym

        class Broken(gym.Wrapper):
            def step(self, action):
                raise RuntimeError("this env breaks on purpose")

        return Broken(env)


def test_a_run_whose_workers_fail_is_an_error_not_a_finished_run(tmp_path):
    """Workers that die (here: an env that raises) used to end the loop as if the budget were spent: the trainer
    evaluated and wrote metrics.json for a run that never trained. Now it is one clear error naming the run."""
    import yaml

    from binpick.core.config import from_dict
    from binpick.core.errors import WorkerError
    from binpick.rl.a3c.train import A3CTrainer
    from binpick.rl.config import RLConfig

    settings = yaml.safe_load(A3C_RUN.format(steps=200)) | {"a3c": {"workers": 1, "n_steps": 5}}
    trainer = A3CTrainer.new(from_dict(RLConfig, settings), tmp_path / "runs", _BreaksOnStep())
    with pytest.raises(WorkerError, match="resumes from its last checkpoint"):
        trainer.run()
    assert not (trainer.run_dir / "metrics.json").exists()

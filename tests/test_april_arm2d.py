"""APRiL on Arm2D: a state policy's observation rebuilt from keypoints read off the image."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.wrappers import FlattenObservation

from binpick.april.arm2d import (PixelsAsArm2DState, collect, keypoint_errors, load_keypoints, save_keypoints,
                                 state_from_keypoints, train_keypoints, true_keypoints)
from binpick.envs import make
from binpick.core.errors import InputFileError


def test_the_state_rebuilt_from_true_keypoints_is_the_envs_own():
    env = make("binpick/Arm2D-v0", goal_conditioned=True, image=None, goal_area=1.0)
    for seed in range(20):
        observation, _ = env.reset(seed=seed)
        for action in np.random.default_rng(seed).integers(0, 6, 5):
            observation, *_ = env.step(int(action))
        rebuilt = state_from_keypoints(true_keypoints(env.unwrapped))
        for key in ("observation", "achieved_goal", "desired_goal"):
            np.testing.assert_allclose(rebuilt[key], observation[key], atol=1e-9)


def test_the_pixel_wrapper_gives_a_state_policy_the_vector_it_was_trained_on():
    state_env = FlattenObservation(make("binpick/Arm2D-v0", goal_conditioned=True, image=None, goal_area=1.0))
    pixel_env = make("binpick/Arm2D-v0", goal_conditioned=True, image="rgb", goal_area=1.0)
    wrapped = PixelsAsArm2DState(pixel_env, lambda image: true_keypoints(pixel_env.unwrapped))
    assert wrapped.observation_space == state_env.observation_space
    a, _ = state_env.reset(seed=3)
    b, _ = wrapped.reset(seed=3)
    np.testing.assert_allclose(a, b, atol=1e-9)
    for action in (0, 3, 5, 5, 1):
        a, *_ = state_env.step(action)
        b, *_ = wrapped.step(action)
        np.testing.assert_allclose(a, b, atol=1e-9)


def test_keypoints_are_learnt_from_images_saved_and_loaded(tmp_path):
    images, points = collect(384, seed=100)
    model, history = train_keypoints(images, points, epochs=4, batch_size=32)
    assert history[-1]["end_point"] < 0.75 * history[0]["end_point"]  # it learns where the arm ends
    held_images, held_points = collect(64, seed=9_000)
    errors = keypoint_errors(model, held_images, held_points)
    assert set(errors) >= {"end_point_median", "goal_p95"}
    path = save_keypoints(model, tmp_path / "k.safetensors", train_images=384)
    np.testing.assert_allclose(load_keypoints(path).keypoints(held_images[:4]), model.keypoints(held_images[:4]))
    (tmp_path / "bad.safetensors").write_bytes(b"not a weights file")
    with pytest.raises(InputFileError):
        load_keypoints(tmp_path / "bad.safetensors")


def test_a3c_trains_a_state_learner_on_the_state_read_off_pixels(tmp_path):
    """ReadStateOffPixels: the frozen keypoint network turns Arm2D's pictures into the state vector,
    pickles into A3C's spawned workers, and a run made with it resumes with it; a picture size the weights do
    not read is one line."""
    import pickle

    import torch

    from binpick.april.arm2d import Arm2DKeypoints, ReadStateOffPixels
    from binpick.core.config import from_dict
    from binpick.core.errors import ConfigError
    from binpick.rl.a3c.train import A3CTrainer
    from binpick.rl.a3c.envs import make_a3c_env as make_env
    from binpick.rl.config import RLConfig

    torch.manual_seed(0)
    weights = save_keypoints(Arm2DKeypoints(32, 8), tmp_path / "reader.safetensors")
    reading = ReadStateOffPixels(str(weights))
    assert pickle.loads(pickle.dumps(reading)) == reading
    settings = {"name": "read", "env": "binpick/Arm2D-v0", "algorithm": "a3c", "total_timesteps": 120,
                "checkpoint_every": 60, "env_kwargs": {"goal_conditioned": True, "image": "rgb", "image_size": 32},
                "a3c": {"encoder": "state", "workers": 1, "n_steps": 10}, "eval": {"every": 60, "episodes": 1}}
    config = from_dict(RLConfig, settings)
    env = make_env(config, reading)
    observation, _ = env.reset(seed=4)
    picture = env.unwrapped._observation()["image"]
    expected = FlattenObservation(make("binpick/Arm2D-v0", goal_conditioned=True, image=None)).observation(
        state_from_keypoints(load_keypoints(weights).keypoints(picture)[0]))
    np.testing.assert_allclose(observation, expected, atol=1e-6)
    trainer = A3CTrainer.new(config, tmp_path / "runs", reading)
    metrics = trainer.run()
    assert metrics["sim_steps"] >= 120 and metrics["evaluations"]
    with pytest.raises(ConfigError, match="a3c.encoder 'state' needs vector observations"):
        A3CTrainer.resume(trainer.run_dir)  # the pictures are not a state without the reader
    assert A3CTrainer.resume(trainer.run_dir, reading).steps == metrics["sim_steps"]
    with pytest.raises(ConfigError, match="32 px"):
        make_env(from_dict(RLConfig, settings | {"env_kwargs": {"goal_conditioned": True, "image": "rgb", "image_size": 16}}),
                 reading)

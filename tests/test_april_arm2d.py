"""APRiL on Arm2D: a state policy's observation rebuilt from keypoints read off the image."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.wrappers import FlattenObservation

from binpick.april.arm2d import (PixelsAsArm2DState, collect, keypoint_errors, load_keypoints, save_keypoints,
                                 state_from_keypoints, train_keypoints, true_keypoints)
from binpick.envs import make
from binpick.errors import InputFileError


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

"""Reacher (thesis §4.5.1): actions are joint-angle changes Δα in [-0.1, 0.1]; u is the end point."""

from __future__ import annotations

import numpy as np


def test_action_changes_joint_angles_by_delta_alpha(make_env):
    env = make_env("binpick/Reacher-v0")
    env.reset(seed=0)
    data = env.unwrapped.data
    before = data.qpos[:2].copy()
    env.step(np.array([0.05, -0.03], dtype=np.float32))
    np.testing.assert_allclose(data.qpos[:2] - before, [0.05, -0.03], atol=1e-6)
    before = data.qpos[:2].copy()
    env.unwrapped.step(np.array([1.0, -1.0]))  # out of range: clipped to ±0.1
    np.testing.assert_allclose(data.qpos[:2] - before, [0.1, -0.1], atol=1e-9)


def test_achieved_goal_is_the_fingertip_and_desired_goal_the_target(make_env):
    env = make_env("binpick/Reacher-v0")
    observation, _ = env.reset(seed=4)
    data = env.unwrapped.data
    np.testing.assert_allclose(observation["achieved_goal"], data.body("fingertip").xpos[:2])
    np.testing.assert_allclose(observation["desired_goal"], data.body("target").xpos[:2])
    assert np.linalg.norm(observation["desired_goal"]) < 0.2
    np.testing.assert_allclose(env.action_space.low, [-0.1, -0.1])
    np.testing.assert_allclose(env.action_space.high, [0.1, 0.1])

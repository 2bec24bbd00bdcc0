"""Every env: Gymnasium's checker, determinism, image observations and HER-ready rewards."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import binpick

def _image_kwargs(env_id: str, mode: str = "rgb", size: int = 32) -> dict:
    if env_id.endswith("Arm2D-v0"):
        return {"goal_conditioned": True, "image": mode, "image_size": size}
    return {"image": mode, "image_size": size}


def _obs_equal(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    return np.array_equal(a, b)


@pytest.mark.parametrize("env_id", binpick.ENV_IDS)
@pytest.mark.parametrize("with_image", [False, True], ids=["state", "image"])
def test_passes_gymnasium_env_checker(env_id, with_image, make_env):
    if with_image:
        kwargs = _image_kwargs(env_id, "grey", 24)
    else:
        kwargs = {"goal_conditioned": True, "image": None} if env_id.endswith("Arm2D-v0") else {}
    env = make_env(env_id, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # infinite Box bounds are expected for positions
        check_env(env.unwrapped)


@pytest.mark.parametrize("env_id", binpick.ENV_IDS)
def test_registered_and_made_with_plain_gymnasium(env_id):
    env = gym.make(env_id)
    try:
        assert env.spec.id == env_id
        assert env.spec.max_episode_steps == binpick.envs.ENVS[env_id].max_episode_steps
    finally:
        env.close()


@pytest.mark.parametrize("env_id", binpick.ENV_IDS)
def test_same_seed_gives_same_images_and_states(env_id, make_env):
    def rollout():
        env = make_env(env_id, **_image_kwargs(env_id, "rgb", 32))
        env.action_space.seed(5)
        observations = [env.reset(seed=11)[0]]
        for _ in range(6):
            observation, *_ = env.step(env.action_space.sample())
            observations.append(observation)
        return observations

    first, second = rollout(), rollout()
    assert all(_obs_equal(a, b) for a, b in zip(first, second))
    other_env = make_env(env_id, **_image_kwargs(env_id, "rgb", 32))
    other = other_env.reset(seed=12)[0]
    assert not _obs_equal(other, first[0]), "a new seed must give a new episode"
    assert not np.array_equal(other["image"], first[0]["image"])


@pytest.mark.parametrize("env_id", binpick.ENV_IDS)
@pytest.mark.parametrize("mode,channels", [("rgb", 3), ("grey", 1)])
def test_image_observation_shape_dtype_and_content(env_id, mode, channels, make_env):
    env = make_env(env_id, **_image_kwargs(env_id, mode, 40))
    observation, _ = env.reset(seed=0)
    image = observation["image"]
    assert image.shape == (40, 40, channels) and image.dtype == np.uint8
    assert env.observation_space["image"].contains(image)
    assert image.std() > 5, "the picture must show something, not a blank frame"
    for _ in range(3):
        observation, *_ = env.step(env.action_space.sample())
        assert observation["image"].shape == (40, 40, channels)


def test_arm2d_default_observation_is_a_64px_rgb_image(make_env):
    env = make_env("binpick/Arm2D-v0")
    observation, info = env.reset(seed=0)
    assert observation.shape == (64, 64, 3) and observation.dtype == np.uint8
    assert set(info) >= {"state", "is_success", "distance"} and info["state"].shape == (7,)
    assert make_env("binpick/Arm2D-v0", image_size=96).reset(seed=0)[0].shape == (96, 96, 3)


@pytest.mark.parametrize("env_id", binpick.ENV_IDS)
def test_compute_reward_matches_step_rewards(env_id, make_env):
    env = make_env(env_id, **({"goal_conditioned": True, "goal_area": 1.0} if env_id.endswith("Arm2D-v0") else {}))
    env.action_space.seed(0)
    env.reset(seed=3)
    achieved, desired, rewards, infos = [], [], [], []
    for _ in range(40):
        observation, reward, terminated, truncated, info = env.step(env.action_space.sample())
        achieved.append(observation["achieved_goal"])
        desired.append(observation["desired_goal"])
        rewards.append(reward)
        infos.append(info)
        assert env.unwrapped.compute_reward(achieved[-1], desired[-1], info) == reward
        if terminated or truncated:
            env.reset()
    batch = env.unwrapped.compute_reward(np.array(achieved), np.array(desired), infos)
    assert batch.shape == (len(rewards),)
    np.testing.assert_array_equal(batch, rewards)
    # HER relabelling: a goal that was achieved earns the success reward
    relabelled = env.unwrapped.compute_reward(np.array(achieved), np.array(achieved), infos)
    assert np.all(relabelled == 0)


@pytest.mark.parametrize("env_id", binpick.ENV_IDS)
def test_episode_ends_at_success(env_id, make_env):
    env = make_env(env_id, **({"goal_conditioned": True} if env_id.endswith("Arm2D-v0") else {}))
    env.reset(seed=0)
    unwrapped = env.unwrapped
    # put the goal where the end effector already is: the next step must succeed and terminate
    if env_id.endswith("Arm2D-v0"):
        unwrapped.goal = unwrapped.joint_positions()[-1].copy()
        action = 0
        unwrapped.angles[0] -= np.pi / 8  # action 0 brings it back onto the goal
    elif env_id.endswith("Reacher-v0"):
        qpos = unwrapped.data.qpos.copy()
        qpos[2:] = unwrapped.data.body("fingertip").xpos[:2]
        unwrapped.set_state(qpos, np.zeros_like(unwrapped.data.qvel))
        action = np.zeros(2, dtype=np.float32)
    else:
        achieved = unwrapped._get_obs()["achieved_goal"]
        unwrapped.goal = achieved.copy()
        action = np.zeros(4, dtype=np.float32)
    _, reward, terminated, truncated, info = env.step(action)
    assert info["is_success"] and reward == 0 and terminated and not truncated


@pytest.mark.parametrize("env_id,limit", [("binpick/Arm2D-v0", 1000), ("binpick/Reacher-v0", 50),
                                          ("binpick/FetchReach-v0", 50), ("binpick/FetchPickAndPlace-v0", 100)])
def test_episode_limit_T(env_id, limit, make_env):
    env = make_env(env_id, max_episode_steps=7)
    env.reset(seed=0)
    assert binpick.envs.ENVS[env_id].max_episode_steps == limit
    steps, done = 0, False
    unwrapped = env.unwrapped
    while not done:
        # keep the goal unreachable so only the time limit can end the episode
        if hasattr(unwrapped, "goal") and not env_id.endswith("Reacher-v0"):
            unwrapped.goal = np.full_like(unwrapped.goal, 50.0)
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        steps += 1
        done = terminated or truncated
    assert steps == 7 and truncated


@pytest.mark.parametrize("env_id,kwargs", [(i, {}) for i in binpick.ENV_IDS] + [("binpick/Arm2D-v0", {"goal_conditioned": True})])
def test_every_env_passes_stable_baselines3_check_env(env_id, kwargs, make_env):
    """SB3's checker on the unwrapped env: a goal env only where there is a goal dict (Arm2D's pixel
    task has no compute_reward), float rewards (Gymnasium-Robotics returns float32)."""
    import warnings

    from stable_baselines3.common.env_checker import check_env

    env = make_env(env_id, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env.unwrapped, warn=False)
    goal_env = binpick.envs.env_spec(env_id).goal_conditioned or kwargs.get("goal_conditioned", False)
    assert hasattr(env.unwrapped, "compute_reward") == goal_env

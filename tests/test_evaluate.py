"""The evaluation helper counts actions until success, capped at T, over seeded episodes."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

import binpick
from binpick.rl.common.evaluate import evaluate_policy, random_policy


class Countdown(gym.Env):
    """Succeeds after exactly ``seed % 7 + 1`` actions of 1; action 0 never succeeds."""

    observation_space = spaces.Discrete(100)
    action_space = spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.remaining = seed % 7 + 1
        return 0, {"is_success": False}

    def step(self, action):
        self.remaining -= int(action)
        success = self.remaining <= 0
        return 0, float(success), success, False, {"is_success": success}


def test_lengths_are_actions_until_success():
    env = gym.wrappers.TimeLimit(Countdown(), max_episode_steps=20)
    result = evaluate_policy(lambda _obs: 1, env, episodes=10, seed=0)
    expected = [s % 7 + 1 for s in range(10)]
    assert result.lengths == expected
    assert result.mean_length == pytest.approx(np.mean(expected))
    assert result.std_length == pytest.approx(np.std(expected))
    assert result.success_rate == 1.0


def test_failures_count_as_T():
    env = gym.wrappers.TimeLimit(Countdown(), max_episode_steps=20)
    result = evaluate_policy(lambda _obs: 0, env, episodes=3)
    assert result.lengths == [20, 20, 20] and result.success_rate == 0.0


def test_stops_at_first_success_even_when_env_does_not_terminate(make_env):
    env = make_env("binpick/FetchReach-v0", terminate_on_success=False)

    class Controller:  # SB3-style predict(): a P-controller towards the goal
        def predict(self, observation, deterministic=True):
            action = np.zeros(4, dtype=np.float32)
            action[:3] = np.clip(10 * (observation["desired_goal"] - observation["achieved_goal"]), -1, 1)
            return action, None

    result = evaluate_policy(Controller(), env, episodes=5)
    assert result.success_rate == 1.0
    assert 1 <= result.mean_length <= 10, result.lengths


def test_random_policy_is_repeatable_and_worse_than_the_controller(make_env):
    env = make_env("binpick/FetchReach-v0")
    first = evaluate_policy(random_policy(env, 3), env, episodes=5)
    second = evaluate_policy(random_policy(env, 3), env, episodes=5)
    assert first.lengths == second.lengths
    assert first.mean_length > 10
    assert set(first.to_dict()) >= {"mean_length", "std_length", "success_rate", "episodes", "env_id"}


def test_episodes_must_be_positive():
    env = binpick.make("binpick/Arm2D-v0")
    with pytest.raises(binpick.core.errors.ConfigError, match="episodes"):
        evaluate_policy(random_policy(env), env, episodes=0)


def test_epsilon_greedy_breaks_a_greedy_policy_that_never_succeeds():
    env = gym.wrappers.TimeLimit(Countdown(), max_episode_steps=200)
    stuck = evaluate_policy(lambda _obs: 0, env, episodes=20)  # greedy: loops without progress until T
    explored = evaluate_policy(lambda _obs: 0, env, episodes=20, epsilon=0.5)
    again = evaluate_policy(lambda _obs: 0, env, episodes=20, epsilon=0.5)
    assert stuck.success_rate == 0.0 and explored.success_rate == 1.0 and explored.mean_length < 50
    assert explored.lengths == again.lengths  # seeded


def test_sampling_a_stochastic_policy_is_seeded_and_leaves_torch_alone():
    import torch

    class Softmax:  # greedy: the action that never succeeds; sampled: 1 a third of the time
        def predict(self, observation, deterministic=True):
            if deterministic:
                return 0, None
            return int(torch.rand(()) < 1 / 3), None

    env = gym.wrappers.TimeLimit(Countdown(), max_episode_steps=200)
    greedy = evaluate_policy(Softmax(), env, episodes=20)
    torch.manual_seed(123)
    before = torch.rand(())
    torch.manual_seed(123)
    sampled = evaluate_policy(Softmax(), env, episodes=20, seed=5, deterministic=False)
    assert torch.rand(()) == before  # the caller's generator is as it was
    again = evaluate_policy(Softmax(), env, episodes=20, seed=5, deterministic=False)
    assert greedy.success_rate == 0.0 and sampled.success_rate == 1.0 and sampled.lengths == again.lengths

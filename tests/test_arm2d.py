"""Arm2D (thesis §3.1.3): action semantics, start states and the curriculum's goal area (§3.2)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from binpick.envs.arm2d import PLAY_HALF_WIDTH


def _goals(env, episodes: int, seed: int = 0) -> np.ndarray:
    return np.array([env.reset(seed=seed + i)[1]["state"][5:7] for i in range(episodes)])


@pytest.mark.parametrize("action,joint,sign", [(0, 0, 1), (1, 0, -1), (2, 1, 1), (3, 1, -1), (4, 2, 1), (5, 2, -1)])
def test_each_action_turns_one_joint_by_pi_over_8(action, joint, sign, make_env):
    env = make_env("binpick/Arm2D-v0")
    env.reset(seed=1)
    before = env.unwrapped.angles.copy()
    env.step(action)
    change = (env.unwrapped.angles - before + math.pi) % (2 * math.pi) - math.pi
    expected = np.zeros(3)
    expected[joint] = sign * math.pi / 8
    np.testing.assert_allclose(change, expected, atol=1e-12)


def test_end_point_is_forward_kinematics(make_env):
    env = make_env("binpick/Arm2D-v0")
    env.reset(seed=0)
    unwrapped = env.unwrapped
    unwrapped.angles = np.array([math.pi / 2, 0.0, 0.0])
    np.testing.assert_allclose(unwrapped.end_point, [0.0, unwrapped.reach], atol=1e-12)
    unwrapped.angles = np.array([0.0, math.pi / 2, -math.pi / 2])
    l1, l2, l3 = unwrapped.link_lengths
    np.testing.assert_allclose(unwrapped.end_point, [l1 + l3, l2], atol=1e-12)


def test_continuous_state_has_each_angle_as_cos_and_sin_and_no_jump_at_pi(make_env):
    """info["state_continuous"] (A3C's auxiliary target): the semantic state without the ±π wrap."""
    env = make_env("binpick/Arm2D-v0")
    _, info = env.reset(seed=4)
    angles, rest = info["state"][:3], info["state"][3:]
    np.testing.assert_allclose(info["state_continuous"], np.r_[np.cos(angles), np.sin(angles), rest], atol=1e-12)
    arm = env.unwrapped
    arm.angles = np.array([math.pi - 1e-3, 0.0, 0.0])
    before_state, before_continuous = arm.state.copy(), arm.state_continuous.copy()
    env.step(0)  # joint 0 turns past π and wraps to about -7π/8
    env.step(1)  # and back
    arm.angles = np.array([-math.pi + 1e-3, 0.0, 0.0])  # 2e-3 rad from where it was, on the other side of the wrap
    assert abs(arm.state[0] - before_state[0]) > 6.0
    assert np.abs(arm.state_continuous - before_continuous).max() < 3e-3


def test_random_start_configurations_and_never_start_on_goal(make_env):
    env = make_env("binpick/Arm2D-v0")
    starts = np.array([env.reset(seed=s)[1]["state"][:3] for s in range(50)])
    assert starts.std(axis=0).min() > 1.0, "start angles should spread over the circle"
    assert all(not env.reset(seed=s)[1]["is_success"] for s in range(50))


def test_fixed_goal_when_goal_area_is_zero(make_env):
    env = make_env("binpick/Arm2D-v0", fixed_goal=(0.3, -0.2))
    np.testing.assert_allclose(_goals(env, 20), np.tile([0.3, -0.2], (20, 1)))


def test_goal_area_changes_where_goals_are_sampled(make_env):
    env = make_env("binpick/Arm2D-v0", goal_area=0.25)
    unwrapped = env.unwrapped
    low, high = unwrapped.goal_region()
    np.testing.assert_allclose(np.prod(high - low), 0.25 * (2 * PLAY_HALF_WIDTH) ** 2)
    quarter = _goals(env, 200)
    assert np.all(quarter >= low - 1e-12) and np.all(quarter <= high + 1e-12)
    assert np.all(np.linalg.norm(quarter, axis=1) <= 0.95 * unwrapped.reach + 1e-12), "goals must be reachable"

    unwrapped.set_goal_area(1.0)  # widened while "training": the very next resets use it
    whole = _goals(env, 200)
    outside = np.any((whole < low) | (whole > high), axis=1)
    assert outside.mean() > 0.4
    assert whole.std(axis=0).min() > quarter.std(axis=0).max()


def test_goal_area_zero_point_grows_monotonically(make_env):
    env = make_env("binpick/Arm2D-v0")
    sizes = []
    for area in (0.0, 0.1, 0.5, 1.0):
        env.unwrapped.set_goal_area(area)
        low, high = env.unwrapped.goal_region()
        sizes.append(np.prod(high - low))
        assert np.all(low <= env.unwrapped.fixed_goal) and np.all(env.unwrapped.fixed_goal <= high)
    assert sizes == sorted(sizes) and sizes[0] == 0


def test_image_shows_goal_in_red_and_moves_with_the_arm(make_env):
    env = make_env("binpick/Arm2D-v0")
    first, _ = env.reset(seed=2)
    red = (first[..., 0] > 150) & (first[..., 1] < 100) & (first[..., 2] < 100)
    assert red.sum() > 3
    second, *_ = env.step(0)
    assert not np.array_equal(first, second)


def test_place_goal_moves_only_the_goal_and_redraws_it():
    """Pictures with the goal next to the tip, for perception pretraining."""
    from binpick.envs import make

    env = make("Arm2D", image_size=32, goal_area=1.0)
    image, info = env.reset(seed=4)
    arm = env.unwrapped
    angles = arm.angles.copy()
    moved, moved_info = arm.place_goal(arm.end_point + [0.03, 0.0])
    assert np.array_equal(arm.angles, angles) and moved_info["is_success"] and abs(moved_info["distance"] - 0.03) < 1e-9
    assert np.allclose(moved_info["state_continuous"][8:], arm.end_point + [0.03, 0.0]) and not np.array_equal(moved, image)
    with pytest.raises(ValueError, match="two finite numbers"):
        arm.place_goal([0.0, np.nan])

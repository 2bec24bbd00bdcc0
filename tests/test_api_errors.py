"""Bad input through the Python API raises one clear BinpickError naming the parameter and range."""

from __future__ import annotations

import pytest

import binpick
from binpick.envs.arm2d import Arm2DEnv
from binpick.core.errors import BinpickError, ConfigError, UnknownEnvError


def test_unknown_env_id_lists_valid_ids():
    with pytest.raises(UnknownEnvError) as error:
        binpick.make("binpick/Nope-v0")
    message = str(error.value)
    assert all(env_id in message for env_id in binpick.ENV_IDS)


def test_short_names_resolve():
    assert binpick.envs.resolve_env_id("fetchreachobstacle") == "binpick/FetchReachObstacle-v0"
    assert binpick.envs.resolve_env_id("Arm2D-v0") == "binpick/Arm2D-v0"


@pytest.mark.parametrize(
    "kwargs,fragment",
    [
        ({"goal_area": -0.1}, "goal_area must be in [0.0, 1.0]"),
        ({"image_size": 2000}, "image_size must be in [16, 1024]"),
        ({"image_size": 32.5}, "image_size must be an integer"),
        ({"tolerance": 0.0}, "tolerance must be in (0.0, 0.5]"),
        ({"fixed_goal": (0.99, 0.99)}, "out of the arm's reach"),
        ({"fixed_goal": (2.0, 0.0)}, "fixed_goal[0] must be in [-1.0, 1.0]"),
        ({"image": "colour"}, "image must be one of 'rgb', 'grey'"),
        ({"link_lengths": (0.4, 0.3)}, "link_lengths must have 3 entries"),
        ({"image": None}, "image must be one of 'rgb', 'grey', got None"),
    ],
)
def test_arm2d_rejects_bad_parameters(kwargs, fragment):
    with pytest.raises(ConfigError) as error:
        Arm2DEnv(**kwargs)
    assert fragment in str(error.value)


def test_goal_area_is_checked_when_changed_during_training():
    env = Arm2DEnv()
    with pytest.raises(ConfigError, match=r"goal_area must be in \[0.0, 1.0\], got 1.5"):
        env.unwrapped.set_goal_area(1.5)
    assert env.goal_area == 0.0


@pytest.mark.parametrize(
    "env_id,kwargs,fragment",
    [
        ("binpick/Reacher-v0", {"tolerance": 0.5}, "tolerance must be in (0.0, 0.2]"),
        ("binpick/FetchReach-v0", {"image": "depth"}, "image must be one of None, 'rgb', 'grey'"),
        ("binpick/FetchReachObstacle-v0", {"obstacle_half_size": 0.5}, "obstacle_half_size must be in [0.01, 0.1]"),
        ("binpick/FetchPickAndPlace-v0", {"width": 4}, "width must be in [16, 1024]"),
        ("binpick/Arm2D-v0", {"max_episode_steps": 0}, "max_episode_steps must be in [1, 100000]"),
        ("binpick/Arm2D-v0", {"colour": 1}, "has no parameter colour"),
    ],
)
def test_make_rejects_bad_parameters(env_id, kwargs, fragment):
    with pytest.raises(BinpickError) as error:
        binpick.make(env_id, **kwargs)
    assert fragment in str(error.value)


def test_an_empty_setting_for_a_text_field_says_how_to_write_an_empty_string():
    from binpick.core.config import apply_overrides, from_dict
    from binpick.detection.pickability_training import PickabilityConfig

    data = apply_overrides({"val": "d.json", "init": "runs/x"}, {"init": None})  # --set init=
    with pytest.raises(ConfigError, match=r"init must be a string, got nothing .*init: ''"):
        from_dict(PickabilityConfig, data, where="cfg")

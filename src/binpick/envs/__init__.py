"""binpick's simulated worlds as registered Gymnasium ids (``binpick/<Name>-v0``).

Importing :mod:`binpick` registers them, so ``gymnasium.make("binpick/FetchReach-v0")`` works after
``import binpick``. :func:`make` adds one-line errors for unknown ids and parameters.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass

import gymnasium as gym
from gymnasium.envs.registration import register, registry

from binpick.core.config import check_range
from binpick.core.errors import ConfigError, UnknownEnvError


@dataclass(frozen=True)
class EnvSpec:
    """What ``binpick envs list`` shows about each env, how it is registered, and what it can do:
    the capabilities other code asks about (never the id's spelling)."""

    env_id: str
    entry_point: str
    max_episode_steps: int
    thesis: str
    summary: str
    discrete_actions: bool = False  # A3C and DQN; SAC needs continuous actions
    goal_conditioned: bool = True  # dict observations + compute_reward (HER, GP imagination, APRiL)
    moves_object: bool = False  # the goal is an object moved by contact: no GP model, demonstrations, gripper in s̄
    goal_area: bool = False  # set_goal_area(): the goal area can grow while training (§3.2 curriculum)
    frame_size: tuple[str, ...] = ("width", "height")  # the parameters that size render()'s frame


ENVS: dict[str, EnvSpec] = {
    spec.env_id: spec
    for spec in (
        EnvSpec("binpick/Arm2D-v0", "binpick.envs.arm2d:Arm2DEnv", 1000, "§3.1.3, Fig 3.2",
                "planar 3-joint arm from 64x64 RGB, 6 discrete ±π/8 actions, growable goal area",
                discrete_actions=True, goal_conditioned=False, goal_area=True, frame_size=("render_size",)),
        EnvSpec("binpick/Reacher-v0", "binpick.envs.reacher:GoalReacherEnv", 50, "§4.5.1, Fig 4.5",
                "MuJoCo Reacher, goal-conditioned, actions Δα ∈ [-0.1, 0.1]"),
        EnvSpec("binpick/FetchReach-v0", "binpick.envs.fetch:FetchReachEnv", 50, "§3.3, §4.5.2",
                "Fetch arm moves its gripper to a target, actions Δz"),
        EnvSpec("binpick/FetchReachObstacle-v0", "binpick.envs.fetch:FetchReachObstacleEnv", 50, "§4.5.2, Fig 4.9",
                "FetchReach with a random solid box that blocks the arm and hides the goal"),
        EnvSpec("binpick/FetchPickAndPlace-v0", "binpick.envs.fetch:FetchPickAndPlaceEnv", 100, "§4.5.3",
                "Fetch grasps a cube and carries it to a target, actions (Δz, a_g)", moves_object=True),
    )
}
ENV_IDS: tuple[str, ...] = tuple(ENVS)

for _spec in ENVS.values():
    if _spec.env_id not in registry:
        register(id=_spec.env_id, entry_point=_spec.entry_point, max_episode_steps=_spec.max_episode_steps)
# The client side of the ROS bridge: any served binpick env, driven over ROS (binpick.integrations.ros1.client).
# Not among ENV_IDS: it needs a running server, and the served env keeps its own time limit.
if "binpick/Ros-v0" not in registry:
    register(id="binpick/Ros-v0", entry_point="binpick.integrations.ros1.client:RosEnv")


def env_spec(name: str) -> EnvSpec:
    """The :class:`EnvSpec` of a full id or a short name (one-line error for an unknown one)."""
    return ENVS[resolve_env_id(name)]


def resolve_env_id(name: str) -> str:
    """Accept a full id or a short name (``FetchReach``, ``fetchreach-v0``); raise a one-line error."""
    if name in ENVS:
        return name
    wanted = name.lower().removeprefix("binpick/")
    for env_id in ENVS:
        short = env_id.removeprefix("binpick/").lower()
        if wanted in (short, short.rsplit("-v", 1)[0]):
            return env_id
    raise UnknownEnvError(f"unknown env id {name!r}; valid ids: {', '.join(ENV_IDS)}")


def make(env_id: str, **kwargs) -> gym.Env:
    """``gymnasium.make`` for binpick ids, with clear errors for unknown ids and parameters."""
    env_id = resolve_env_id(env_id)
    entry = registry[env_id].entry_point
    module_name, class_name = entry.split(":")
    env_class = getattr(__import__(module_name, fromlist=[class_name]), class_name)
    allowed = _parameters(env_class) | {"max_episode_steps"}
    unknown = sorted(set(kwargs) - allowed)
    if unknown:
        raise ConfigError(
            f"{env_id} has no parameter {', '.join(unknown)}; its parameters are: {', '.join(sorted(allowed))}"
        )
    if "max_episode_steps" in kwargs:
        check_range("max_episode_steps", kwargs["max_episode_steps"], 1, 100_000, integer=True)
    return gym.make(env_id, **kwargs)


def _parameters(env_class: type) -> set[str]:
    names: set[str] = set()
    for klass in env_class.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        params = inspect.signature(init).parameters
        names |= {n for n, p in params.items() if n != "self" and p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}
        if not any(p.kind == p.VAR_KEYWORD for p in params.values()):
            break
    return names


__all__ = ["ENVS", "ENV_IDS", "EnvSpec", "env_spec", "make", "resolve_env_id"]

"""The thesis's headline metric: average episode length (actions until success, capped at T) ± std,
beside the success rate, over N seeded episodes.

A policy is any callable ``obs -> action`` or an object with an SB3-style
``predict(obs, deterministic=True) -> (action, state)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from binpick.core.config import check_range


class SupportsPredict(Protocol):
    def predict(self, observation: Any, deterministic: bool = True) -> tuple[Any, Any]: ...


Policy = Callable[[Any], Any] | SupportsPredict
EpisodeCallback = Callable[[int, int, bool], None]


@dataclass
class EvalResult:
    """Per-episode lengths and successes, with the summary numbers the thesis reports."""

    env_id: str
    lengths: list[int] = field(default_factory=list)
    successes: list[bool] = field(default_factory=list)
    max_episode_steps: int | None = None

    @property
    def episodes(self) -> int:
        return len(self.lengths)

    @property
    def mean_length(self) -> float:
        return float(np.mean(self.lengths)) if self.lengths else float("nan")

    @property
    def std_length(self) -> float:
        return float(np.std(self.lengths)) if self.lengths else float("nan")

    @property
    def success_rate(self) -> float:
        return float(np.mean(self.successes)) if self.successes else float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {
            "env_id": self.env_id,
            "episodes": self.episodes,
            "max_episode_steps": self.max_episode_steps,
            "mean_length": self.mean_length,
            "std_length": self.std_length,
            "success_rate": self.success_rate,
        }

    def summary(self) -> str:
        return (
            f"{self.env_id}: {self.mean_length:.2f} ± {self.std_length:.2f} actions per episode, "
            f"success {100 * self.success_rate:.1f}% over {self.episodes} episodes"
        )


def random_policy(env: gym.Env, seed: int = 0) -> Callable[[Any], Any]:
    """Uniformly random actions from the env's action space, seeded for repeatable baselines."""
    space = env.action_space
    space.seed(seed)
    return lambda _observation: space.sample()


def evaluate_policy(
    model: Policy,
    env: gym.Env,
    episodes: int = 100,
    seed: int = 0,
    on_episode: EpisodeCallback | None = None,
    epsilon: float = 0.0,
    deterministic: bool = True,
) -> EvalResult:
    """Run ``episodes`` episodes (episode i reset with ``seed + i``) and measure their lengths.

    Arguments in Stable-Baselines3's order (``evaluate_policy(model, env, ...)``); ``model`` is any
    callable ``obs -> action`` or an object with SB3's ``predict``.

    An episode ends at the first step whose ``info["is_success"]`` is true (its length is the number
    of actions taken), or when the env terminates or truncates (length T if never successful).

    ``epsilon`` > 0 takes a uniformly random action with that probability (seeded from ``seed``): the
    ε-greedy evaluation of Mnih et al. (2015), ε = 0.05, which a value-based policy needs where its
    greedy actions can cycle between two states forever in a deterministic env.

    ``deterministic=False`` asks ``predict`` to sample its policy's distribution, as an actor-critic
    such as A3C acts (Mnih et al. 2016); torch's generator is seeded from ``seed`` for the evaluation and
    restored after it.
    """
    check_range("episodes", episodes, 1, None, integer=True)
    check_range("epsilon", epsilon, 0.0, 1.0)
    act = _as_callable(model, deterministic)
    if deterministic:
        return _run_episodes(act, env, episodes, seed, on_episode, epsilon)
    import torch

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return _run_episodes(act, env, episodes, seed, on_episode, epsilon)


def _run_episodes(act: Callable[[Any], Any], env: gym.Env, episodes: int, seed: int, on_episode: EpisodeCallback | None,
                  epsilon: float) -> EvalResult:
    if epsilon > 0:
        greedy, rng, space = act, np.random.default_rng(seed), env.action_space
        space.seed(seed)
        act = lambda observation: space.sample() if rng.uniform() < epsilon else greedy(observation)  # noqa: E731
    spec = env.spec
    result = EvalResult(env_id=spec.id if spec else type(env.unwrapped).__name__,
                        max_episode_steps=spec.max_episode_steps if spec else None)
    for episode in range(episodes):
        observation, info = env.reset(seed=seed + episode)
        steps, success = 0, bool(info.get("is_success", False))
        while not success:
            observation, _, terminated, truncated, info = env.step(act(observation))
            steps += 1
            success = bool(info.get("is_success", False))
            if terminated or truncated:
                break
        result.lengths.append(steps)
        result.successes.append(success)
        if on_episode is not None:
            on_episode(episode, steps, success)
    return result


def _as_callable(policy: Policy, deterministic: bool = True) -> Callable[[Any], Any]:
    predict = getattr(policy, "predict", None)
    if callable(predict):
        return lambda observation: predict(observation, deterministic=deterministic)[0]
    if callable(policy):
        return policy
    raise TypeError(f"policy must be callable or have a predict() method, got {type(policy).__name__}")

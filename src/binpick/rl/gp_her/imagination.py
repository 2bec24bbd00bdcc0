"""Imagined episodes (thesis §3.3.1, Fig 3.7): roll the current policy through the GP model.

Many episodes advance together, one batched GP query per time step, from start states and goals
taken from real episodes. Rewards come from the env's own ``compute_reward``, so imagined episodes
go into the same replay as real ones (and get HER copies like them). The policy's input must be the
semantic state itself (``observation == achieved_goal``, see :class:`SemanticState`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from binpick.rl.gp_her.dynamics import GPDynamics
from binpick.rl.common.replay import Episode

BatchPolicy = Callable[[dict[str, np.ndarray]], np.ndarray]


def imagine_episodes(
    dynamics: GPDynamics,
    policy: BatchPolicy,
    starts: np.ndarray,
    goals: np.ndarray,
    compute_reward: Callable,
    max_steps: int,
    rng: np.random.Generator,
    stochastic: bool = True,
) -> list[Episode]:
    """Roll ``len(starts)`` episodes of at most ``max_steps`` through the GP; each stops at success."""
    batch = len(starts)
    states = np.zeros((max_steps + 1, batch, starts.shape[1]), np.float64)
    states[0] = starts
    actions: np.ndarray | None = None
    lengths = np.full(batch, max_steps)
    active = np.arange(batch)  # only unfinished episodes are queried: stragglers stay cheap
    for t in range(max_steps):
        observation = {"observation": states[t, active], "achieved_goal": states[t, active], "desired_goal": goals[active]}
        action = np.asarray(policy(observation), np.float64)
        if actions is None:
            actions = np.zeros((batch, max_steps, action.shape[1]), np.float64)
        actions[active, t] = action
        states[t + 1, active] = dynamics.sample_next(states[t, active], action, rng, stochastic=stochastic)
        reached = np.asarray(compute_reward(states[t + 1, active], goals[active], None)) >= 0
        lengths[active[reached]] = t + 1
        active = active[~reached]
        if len(active) == 0:
            break
    episodes = []
    for i in range(batch):
        length = int(lengths[i])
        path = states[: length + 1, i].astype(np.float32)
        episodes.append(Episode(path, path.copy(), goals[i].astype(np.float32), actions[i, :length].astype(np.float32)))
    return episodes

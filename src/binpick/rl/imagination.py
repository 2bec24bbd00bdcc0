"""Imagined episodes (thesis §3.3.1, Fig 3.7): roll the current policy through the GP model.

Many episodes advance together, one batched GP query per time step, from start states and goals
taken from real episodes. Rewards come from the env's own ``compute_reward``, so imagined episodes
go into the same replay as real ones (and get HER copies like them). The policy's input must be the
semantic state itself (``observation == achieved_goal``, see :class:`SemanticState`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from binpick.rl.dynamics import GPDynamics
from binpick.rl.replay import Episode

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
    actions: list[np.ndarray] = []
    lengths = np.full(batch, max_steps)
    active = np.ones(batch, bool)
    for t in range(max_steps):
        observation = {"observation": states[t], "achieved_goal": states[t], "desired_goal": goals}
        action = np.asarray(policy(observation), np.float64)
        actions.append(action)
        states[t + 1] = dynamics.sample_next(states[t], action, rng, stochastic=stochastic)
        reached = np.asarray(compute_reward(states[t + 1], goals, None)) >= 0
        finished = active & reached
        lengths[finished] = t + 1
        active &= ~reached
        if not active.any():
            break
    actions_array = np.stack(actions, axis=1)  # (B, steps, act_dim)
    episodes = []
    for i in range(batch):
        length = int(lengths[i])
        path = states[: length + 1, i].astype(np.float32)
        episodes.append(Episode(path, path.copy(), goals[i].astype(np.float32), actions_array[i, :length].astype(np.float32)))
    return episodes

"""Demonstrations from a scripted policy and behaviour cloning of the actor (thesis §4.5.3).

"We initially collect data using a simple hand-crafted heuristic policy ... This data is used as
demonstration for imitation learning. Therefore the initial RL policy is not random." The
demonstration episodes go into the episode replay (with their HER copies) and the SAC actor is
first fitted to their actions by mean squared error.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC

from binpick.rl.replay import Episode, EpisodeReplayBuffer


def collect_demonstrations(env: gym.Env, expert: Callable[[dict], np.ndarray], episodes: int,
                           seed: int = 0) -> tuple[list[Episode], int]:
    """Roll ``expert`` (which reads the env's raw observation) in the wrapped training env ``env``;
    the episodes are recorded in the observations the policy trains on. Returns them and the steps."""
    recorded, steps = [], 0
    for episode in range(episodes):
        observation, _ = env.reset(seed=seed + episode)
        observations, achieved, actions = [observation["observation"]], [observation["achieved_goal"]], []
        done = False
        while not done:
            action = expert(env.unwrapped._get_obs())
            observation, _, terminated, truncated, _ = env.step(action)
            observations.append(observation["observation"])
            achieved.append(observation["achieved_goal"])
            actions.append(action)
            done = terminated or truncated
        steps += len(actions)
        recorded.append(Episode(np.asarray(observations, np.float32), np.asarray(achieved, np.float32),
                                np.asarray(observation["desired_goal"], np.float32), np.asarray(actions, np.float32)))
    return recorded, steps


def behaviour_clone(model: SAC, episodes: list[Episode], steps: int, batch_size: int = 256, seed: int = 0) -> list[float]:
    """Fit the SAC actor's deterministic action to the demonstrated ones (MSE); returns the losses."""
    observation = np.concatenate([e.observation[:-1] for e in episodes])
    achieved = np.concatenate([e.achieved_goal[:-1] for e in episodes])
    desired = np.concatenate([np.repeat(e.desired_goal[None], e.length, 0) for e in episodes])
    actions = torch.as_tensor(np.concatenate([e.actions for e in episodes]), dtype=torch.float32)
    low, high = model.action_space.low, model.action_space.high
    targets = 2.0 * (actions - torch.as_tensor(low)) / torch.as_tensor(high - low) - 1.0  # SAC acts in [-1, 1]
    rng = np.random.default_rng(seed)
    losses = []
    for _ in range(steps):
        batch = rng.integers(0, len(actions), size=min(batch_size, len(actions)))
        inputs: dict[str, Any] = {"observation": observation[batch], "achieved_goal": achieved[batch],
                                  "desired_goal": desired[batch]}
        tensor, _ = model.policy.obs_to_tensor(inputs)
        loss = torch.nn.functional.mse_loss(model.actor(tensor, deterministic=True), targets[batch])
        model.actor.optimizer.zero_grad()
        loss.backward()
        model.actor.optimizer.step()
        losses.append(float(loss.detach()))
    return losses


def add_demonstrations(buffer: EpisodeReplayBuffer, episodes: list[Episode]) -> None:
    for episode in episodes:
        buffer.add_episode(episode, origin="real")

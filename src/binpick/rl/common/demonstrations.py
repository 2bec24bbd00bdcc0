"""Demonstrations from a scripted policy and behaviour cloning of the actor (thesis §4.5.3).

"We initially collect data using a simple hand-crafted heuristic policy ... This data is used as
demonstration for imitation learning. Therefore the initial RL policy is not random." The
demonstration episodes go into the episode replay (with their HER copies) and the SAC actor is
first fitted to their actions by mean squared error.
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC

from binpick.rl.common.replay import Episode, EpisodeReplayBuffer


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


MIN_LOG_STD = -3.0  # exploration noise learnt by behaviour cloning stays ≥ e^-3 ≈ 0.05 (pre-squash)


class DemonstrationSet:
    """The demonstrated (observation, action) pairs as arrays, actions in SAC's [-1, 1] units.

    Kept on the model (saved with it) so that SAC can keep cloning them while it learns."""

    def __init__(self, episodes: list[Episode], low: np.ndarray, high: np.ndarray) -> None:
        self.observation = np.concatenate([e.observation[:-1] for e in episodes])
        self.achieved_goal = np.concatenate([e.achieved_goal[:-1] for e in episodes])
        self.desired_goal = np.concatenate([np.repeat(e.desired_goal[None], e.length, 0) for e in episodes])
        actions = np.concatenate([e.actions for e in episodes])
        self.actions = (2.0 * (actions - low) / (high - low) - 1.0).astype(np.float32)

    def __len__(self) -> int:
        return len(self.actions)

    def arrays(self) -> dict[str, np.ndarray]:
        """What a checkpoint stores (``from_arrays`` rebuilds the set)."""
        return {key: getattr(self, key) for key in ("observation", "achieved_goal", "desired_goal", "actions")}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> DemonstrationSet:
        demonstrations = cls.__new__(cls)
        for key in ("observation", "achieved_goal", "desired_goal", "actions"):
            setattr(demonstrations, key, np.asarray(arrays[key], np.float32))
        return demonstrations

    def sample(self, rng: np.random.Generator, batch_size: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
        batch = rng.integers(0, len(self), size=min(batch_size, len(self)))
        return ({"observation": self.observation[batch], "achieved_goal": self.achieved_goal[batch],
                 "desired_goal": self.desired_goal[batch]}, self.actions[batch])


def behaviour_clone(model: SAC, demonstrations: DemonstrationSet, steps: int, batch_size: int = 256, seed: int = 0,
                    likelihood_weight: float = 0.0) -> list[float]:
    """Fit the SAC actor's deterministic action to the demonstrated ones (MSE) and, with
    ``likelihood_weight`` > 0, its Gaussian's spread by maximum likelihood: an untouched actor explores
    with σ ≈ 1, i.e. almost at random, and would throw the cloned behaviour away. Returns the MSE per step."""
    rng = np.random.default_rng(seed)
    losses = []
    for _ in range(steps):
        inputs, targets = demonstrations.sample(rng, batch_size)
        loss, mse = cloning_loss(model, inputs, targets, likelihood_weight)
        model.actor.optimizer.zero_grad()
        loss.backward()
        model.actor.optimizer.step()
        losses.append(float(mse.detach()))
    return losses


def cloning_loss(model: SAC, inputs: dict[str, np.ndarray], targets: np.ndarray, likelihood_weight: float = 0.0,
                 q_filter: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Behaviour cloning of demonstrated actions: MSE of the deterministic action plus, weighted, the
    Gaussian negative log-likelihood before the squash (which fits σ too). With ``q_filter`` (Nair et
    al., 2018) a sample counts only where the critic rates the demonstrated action above the actor's
    own, so the policy may outgrow the heuristic. Returns (loss, mean squared error)."""
    tensor, _ = model.policy.obs_to_tensor(inputs)
    target = torch.as_tensor(targets)
    view = getattr(model, "actor_view", None)  # GoalSAC with actor_noise: the actor clones from noisy s̄ too
    mean, log_std, _ = model.actor.get_action_dist_params(view(tensor) if view else tensor)
    squared = ((torch.tanh(mean) - target) ** 2).mean(dim=1)
    per_sample = squared
    if likelihood_weight:
        log_std = log_std.clamp(min=MIN_LOG_STD)
        gaussian = torch.atanh(target.clamp(-0.97, 0.97))
        per_sample = per_sample + likelihood_weight * (0.5 * ((gaussian - mean) / log_std.exp()) ** 2 + log_std).mean(dim=1)
    if q_filter:
        with torch.no_grad():
            q_demo = torch.min(torch.cat(model.critic(tensor, target), dim=1), dim=1).values
            q_actor = torch.min(torch.cat(model.critic(tensor, torch.tanh(mean)), dim=1), dim=1).values
            per_sample = per_sample * (q_demo > q_actor).float()
    return per_sample.mean(), squared.mean()


def add_demonstrations(buffer: EpisodeReplayBuffer, episodes: list[Episode]) -> None:
    for episode in episodes:
        buffer.add_episode(episode, origin="real")

"""Teach an A3C network to read the semantic state off its pictures before RL starts.

A3C from pixels learns its perception from the reward and the auxiliary state loss while it acts, at
the small learning rate the policy needs; on Arm2D its features still read the arm's state poorly
after a few hundred thousand steps (auxiliary loss ~0.1 a component), while the same learner on the
state itself has converged. Perception does not need the reward: as APRiL (thesis ch. 4) trains its
perception on simulator states apart from the policy, this fits the trunk and the auxiliary state head
to ``info[state_key]`` on pictures of random poses with goals anywhere, at a rate fit for supervised
learning, then hands the network to A3C, which keeps acting and learning from the pictures alone.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch

from binpick.core.errors import ConfigError
from binpick.rl.a3c.networks import ActorCritic
from binpick.core.runs import Task


@dataclass(frozen=True)
class PretrainResult:
    pictures: int
    epochs: int
    held_out_error: float  # root mean square error per state component on held-out pictures, after
    untrained_error: float  # ... and before


def render_states(make_env: Callable[[], gym.Env], state_key: str, count: int, seed: int,
                  near_goal: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """``count`` pictures of random poses with goals anywhere in the play area, and their ``info[state_key]``.

    A ``near_goal`` fraction of them has the goal moved next to the end point (offsets of 1.5 success radii
    a coordinate, normally distributed), the pictures every successful episode ends in: random poses put the
    tip within 0.15 of the goal in ~2% of pictures, and a network never shown them reads the goal there
    twice as badly as elsewhere."""
    env = make_env()
    rng = np.random.default_rng(seed)
    if near_goal and not hasattr(env.unwrapped, "place_goal"):
        env.close()
        raise ConfigError("a3c.pretrain_near_goal moves the goal next to the tip: the env needs place_goal (Arm2D has it)")
    try:
        env.unwrapped.set_goal_area(1.0)  # every goal the curriculum will ever show
        images, states = [], []
        for index in range(count):
            image, info = env.reset(seed=seed + index)
            if rng.random() < near_goal:
                arm = env.unwrapped
                image, info = arm.place_goal(arm.end_point + rng.normal(0.0, 1.5 * arm.tolerance, 2))
            if state_key not in info:
                raise ConfigError(f"a3c.pretrain needs info[{state_key!r}] (a3c.state_key); the env does not give it")
            images.append(image)
            states.append(np.asarray(info[state_key], dtype=np.float32))
    finally:
        env.close()
    return torch.from_numpy(np.stack(images)), torch.from_numpy(np.stack(states))


def pretrain_perception(model: ActorCritic, make_env: Callable[[], gym.Env], state_key: str, pictures: int,
                        epochs: int, learning_rate: float, seed: int, task: Task | None = None,
                        batch_size: int = 64, near_goal: float = 0.0) -> PretrainResult:
    """Fit ``model``'s trunk, 256-unit layer and state head to the state on rendered pictures (its own Adam,
    so A3C's shared optimiser starts fresh); a tenth as many more pictures, held out, give the error."""
    if model.state is None:
        raise ConfigError("a3c.pretrain_pictures needs the auxiliary state head: set a3c.state_weight > 0")
    held_out = max(pictures // 10, 1)
    images, states = render_states(make_env, state_key, pictures + held_out, seed, near_goal)
    train_images, train_states = images[:pictures], states[:pictures]
    test_images, test_states = images[pictures:], states[pictures:]
    parameters = [*model.trunk.parameters(), *model.hidden.parameters(), *model.state.parameters()]
    optimizer = torch.optim.Adam(parameters, lr=learning_rate)
    generator = torch.Generator().manual_seed(seed)

    def held_out_error() -> float:
        with torch.no_grad():
            return float((model.state(model.features(test_images)) - test_states).pow(2).mean().sqrt())

    untrained = held_out_error()
    for epoch in range(epochs):
        for batch in torch.randperm(pictures, generator=generator).split(batch_size):
            loss = (model.state(model.features(train_images[batch])) - train_states[batch]).pow(2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        error = held_out_error()
        if task is not None:
            task.update(epoch + 1, status=f"held-out state error {error:.3f}")
    model.zero_grad(set_to_none=True)
    return PretrainResult(pictures, epochs, error, untrained)

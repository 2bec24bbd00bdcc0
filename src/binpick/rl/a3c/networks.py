"""Asynchronous advantage actor-critic (thesis §3.1.2, Eq 3.4-3.7) for pixel observations (or, with
``encoder="state"``, for the env's semantic state vector: the same learner with perception taken away).

n worker processes each own an env and a local copy of the network. A worker repeatedly copies the
global weights, plays up to ``n_steps`` actions, and computes gradients of

    L = L_π + c_v L_V,   L_V = (R_t - V(s_t))²,   L_π = -log π(a_t|s_t) A_t - β H(π(·|s_t))   (3.5, 3.6)

with n-step returns R_t = r_t + γ R_{t+1}, bootstrapped from V(s_{t+n}) unless the episode ended
(Eq 3.7), and A_t = R_t - V(s_t) (Eq 3.4). The gradients are applied to the shared global network
by a shared Adam, without locks (as A3C does). :class:`A3CWorker` only turns weights into
gradients, so the same class can run in a Ray actor on another machine.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn


ENCODERS = ("flatten", "keypoints", "state")
POLICY_INPUTS = ("features", "state_estimate")


class SpatialSoftmax(nn.Module):
    """Each channel's expected (x, y) under its softmax over the image, in [-1, 1] (Levine et al. 2016):
    a feature that fires on the goal gives the goal's coordinates wherever it is, where a flattened
    map gives a separate weight to every place (trained on goals in a quarter of the play
    area, a flattened trunk located goals elsewhere over 10x worse than inside; this one about as well:
    the `a3c_encoder_probe` note (docs/notes.md))."""

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        batch, channels, height, width = maps.shape
        weights = torch.softmax(maps.flatten(2), -1).view(batch, channels, height, width)
        xs = torch.linspace(-1.0, 1.0, width, device=maps.device)
        ys = torch.linspace(-1.0, 1.0, height, device=maps.device)
        return torch.cat([(weights.sum(2) * xs).sum(-1), (weights.sum(3) * ys).sum(-1)], 1)


class ActorCritic(nn.Module):
    """Shared convolutional trunk with a policy head (logits) and a value head (thesis §3.1.2).

    ``encoder="flatten"`` (the thesis-style default) flattens the last feature map; ``"keypoints"``
    keeps half-resolution maps and reads each channel's expected position (:class:`SpatialSoftmax`), so what is
    learnt about a goal in one place holds in every place: the curriculum's widening needs it. ``"state"``
    takes a flat float vector (B, D) instead of images: it measures what the learner does when
    perception is perfect.

    ``policy_input="state_estimate"`` puts a semantic bottleneck between perception and control (APRiL's
    idea, thesis ch. 4, inside A3C): the policy and value heads read an MLP on the state the auxiliary head
    reads off the picture, the very network the state learner uses on the true state, instead of the
    256 features that also had to encode that state linearly. Trained end to end; needs ``state_size``.
    ``detach_perception`` stops the policy's and value's gradients at what they read, so only the auxiliary
    state loss trains the perception (APRiL's split: perception learns the state, the policy acts on it).

    ``hidden_layers`` is the number of 256-unit ReLU layers in ``hidden`` (after the trunk) and in ``controller``
    (0: the heads read the trunk's output, or the state estimate, directly). The state encoder's trunk is itself
    one such layer, so the state learner has 1 + ``hidden_layers`` layers on the state, where a picture trunk that
    ends at positions (keypoints) leaves ``hidden_layers`` above them. Why: with one, the pixel learner
    and the bottleneck learnt Arm2D's single goal at the pace of the state learner with one (``hidden_layers=0``),
    half that of the state learner with two."""

    def __init__(self, observation_shape: tuple[int, ...], actions: int, encoder: str = "flatten",
                 state_size: int = 0, policy_input: str = "features", detach_perception: bool = False,
                 hidden_layers: int = 1) -> None:
        super().__init__()
        if not isinstance(hidden_layers, int) or hidden_layers < 0:
            raise ValueError(f"hidden_layers must be an integer >= 0, got {hidden_layers!r}")
        self.hidden_layers = hidden_layers
        self.detach_perception = bool(detach_perception)
        if encoder not in ENCODERS:
            raise ValueError(f"encoder must be one of {ENCODERS}, got {encoder!r}")
        if policy_input not in POLICY_INPUTS:
            raise ValueError(f"policy_input must be one of {POLICY_INPUTS}, got {policy_input!r}")
        if policy_input == "state_estimate" and not state_size:
            raise ValueError("policy_input 'state_estimate' reads the auxiliary state head: it needs state_size > 0")
        self.policy_input = policy_input
        self.encoder = encoder
        if encoder == "state":
            if len(observation_shape) != 1:
                raise ValueError(f"encoder 'state' needs a flat vector observation, got shape {tuple(observation_shape)}")
            self.trunk = nn.Sequential(nn.Linear(int(observation_shape[0]), 256), nn.ReLU())
        elif len(observation_shape) != 3:
            raise ValueError(f"encoder {encoder!r} needs (H, W, C) images, got shape {tuple(observation_shape)}")
        elif encoder == "flatten":
            channels = observation_shape[2]
            self.trunk = nn.Sequential(
                nn.Conv2d(channels, 16, 5, stride=2, padding=2), nn.ReLU(),
                nn.Conv2d(16, 32, 5, stride=2, padding=2), nn.ReLU(),
                nn.Conv2d(32, 32, 3, stride=2, padding=1), nn.ReLU(),
                nn.Flatten(),
            )
        else:
            channels = observation_shape[2]
            self.trunk = nn.Sequential(
                nn.Conv2d(channels, 16, 5, stride=2, padding=2), nn.ReLU(),
                nn.Conv2d(16, 32, 3, stride=1, padding=1), nn.ReLU(),
                nn.Conv2d(32, 32, 3, stride=1, padding=1),
                SpatialSoftmax(),
            )
        with torch.no_grad():
            features = self.trunk(self._prepare(torch.zeros(1, *observation_shape, dtype=torch.uint8))).shape[1]
        # modules in the order older checkpoints' optimiser states list their parameters
        self.hidden = _mlp(features, hidden_layers)
        width = 256 if hidden_layers else features  # of the features; 0 layers: the trunk's own output
        self.state_size = int(state_size)
        head_width = (256 if hidden_layers else self.state_size) if policy_input == "state_estimate" else width
        self.policy = nn.Linear(head_width, actions)
        self.value = nn.Linear(head_width, 1)
        # optional auxiliary head: the semantic state (info[state_key]) read from the same features
        self.state = nn.Linear(width, self.state_size) if self.state_size else None
        self.controller = _mlp(self.state_size, hidden_layers) if policy_input == "state_estimate" else None

    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """uint8 (B, H, W, C) images -> (logits (B, A), values (B,))."""
        return self.heads(self.features(images))

    def heads(self, hidden: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, F) features -> (logits, values), through the state estimate when there is a bottleneck."""
        control = hidden if self.controller is None else self.state(hidden)
        if self.detach_perception:
            control = control.detach()
        if self.controller is not None:
            control = self.controller(control)
        return self.policy(control), self.value(control).squeeze(-1)

    def features(self, images: torch.Tensor) -> torch.Tensor:
        """uint8 (B, H, W, C) images (or (B, D) state vectors) -> the (B, F) features the heads read
        (F = 256, or the trunk's output with ``hidden_layers=0``)."""
        return self.hidden(self.trunk(self._prepare(images)))

    def _prepare(self, observations: torch.Tensor) -> torch.Tensor:
        if self.encoder == "state":
            return observations.float()
        return observations.permute(0, 3, 1, 2).float() / 255.0

    @torch.no_grad()
    def act(self, image: np.ndarray, deterministic: bool = False) -> int:
        logits, _ = self(torch.from_numpy(np.array(image[None])))
        if deterministic:
            return int(logits.argmax(-1))
        return int(torch.distributions.Categorical(logits=logits).sample())


def _mlp(inputs: int, layers: int, width: int = 256) -> nn.Sequential:
    """``layers`` ReLU layers of ``width`` units."""
    modules: list[nn.Module] = []
    for index in range(layers):
        modules += [nn.Linear(inputs if index == 0 else width, width), nn.ReLU()]
    return nn.Sequential(*modules)


class SharedAdam(torch.optim.Adam):
    """Adam whose moment estimates live in shared memory, so every worker process updates them."""

    def __init__(self, params, lr: float = 1e-4, betas=(0.9, 0.999), eps: float = 1e-8) -> None:
        super().__init__(params, lr=lr, betas=betas, eps=eps)
        for group in self.param_groups:
            for p in group["params"]:
                state = self.state[p]
                state["step"] = torch.zeros(1)
                state["exp_avg"] = torch.zeros_like(p.data)
                state["exp_avg_sq"] = torch.zeros_like(p.data)
                state["step"].share_memory_()
                state["exp_avg"].share_memory_()
                state["exp_avg_sq"].share_memory_()


@dataclass
class RolloutStats:
    steps: int = 0
    finished_lengths: list[int] = field(default_factory=list)
    finished_successes: list[bool] = field(default_factory=list)
    policy_loss: float = 0.0
    value_loss: float = 0.0
    entropy: float = 0.0
    state_loss: float = 0.0


class A3CWorker:
    """One environment and a local network; turns global weights into gradients from one rollout."""

    def __init__(self, make_env: Callable[[], gym.Env], observation_shape, actions: int, seed: int,
                 n_steps: int = 20, gamma: float = 0.99, entropy_beta: float = 0.01, value_coef: float = 0.5,
                 max_grad_norm: float = 40.0, reward_scale: float = 0.01, encoder: str = "flatten",
                 state_weight: float = 0.0, state_size: int = 0, state_key: str = "state",
                 policy_input: str = "features", detach_perception: bool = False, hidden_layers: int = 1) -> None:
        self.env = make_env()
        self.model = ActorCritic(observation_shape, actions, encoder, state_size if state_weight > 0 else 0, policy_input,
                                 detach_perception, hidden_layers)
        self.state_weight, self.state_key = state_weight, state_key
        self.n_steps, self.gamma = n_steps, gamma
        self.entropy_beta, self.value_coef, self.max_grad_norm = entropy_beta, value_coef, max_grad_norm
        # binpick's -1-per-step reward gives returns near -1/(1-γ); scaling by (1-γ) keeps the critic's
        # targets in [-1, 0] so the value loss cannot swamp the policy gradient (same optimal policy).
        self.reward_scale = reward_scale
        self.seed = seed
        self._episode = 0
        self._episode_steps = 0
        self.observation, info = self.env.reset(seed=seed)
        self.semantic = info.get(self.state_key)
        torch.manual_seed(seed)

    def reset_env(self) -> None:
        self._episode += 1
        self._episode_steps = 0
        self.observation, info = self.env.reset(seed=self.seed + 100_003 * self._episode)
        self.semantic = info.get(self.state_key)

    def compute_gradients(self, weights: dict[str, torch.Tensor], max_steps: int | None = None) -> tuple[list[torch.Tensor], RolloutStats]:
        """Play up to n_steps (fewer with ``max_steps``: a learner that stops at an exact step count)
        with ``weights`` and return the A3C gradients (Eq 3.5-3.7)."""
        self.model.load_state_dict(weights)
        stats = RolloutStats()
        images, actions, rewards, semantic = [], [], [], []
        done = False
        for _ in range(self.n_steps if max_steps is None else max(1, min(self.n_steps, max_steps))):
            images.append(self.observation)
            semantic.append(self.semantic)
            action = self.model.act(self.observation)
            self.observation, reward, terminated, truncated, info = self.env.step(action)
            self.semantic = info.get(self.state_key)
            actions.append(action)
            rewards.append(reward * self.reward_scale)
            self._episode_steps += 1
            stats.steps += 1
            if terminated or truncated:
                stats.finished_lengths.append(self._episode_steps)
                stats.finished_successes.append(bool(info.get("is_success", terminated)))
                done = terminated  # a time limit is not the end of the task: bootstrap through it
                bootstrap_image = self.observation
                self.reset_env()
                break
        else:
            bootstrap_image = self.observation
        hidden = self.model.features(torch.from_numpy(np.stack(images)))
        logits, values = self.model.heads(hidden)
        with torch.no_grad():
            running = 0.0 if done else float(self.model(torch.from_numpy(np.array(bootstrap_image[None])))[1])
        returns = torch.zeros(len(rewards))
        for t in reversed(range(len(rewards))):
            running = rewards[t] + self.gamma * running
            returns[t] = running
        distribution = torch.distributions.Categorical(logits=logits)
        advantages = returns - values
        value_loss = advantages.pow(2).mean()
        entropy = distribution.entropy().mean()
        policy_loss = -(distribution.log_prob(torch.as_tensor(actions)) * advantages.detach()).mean() - self.entropy_beta * entropy
        loss = policy_loss + self.value_coef * value_loss
        if self.state_weight > 0:  # auxiliary: the features must also say where the arm and goal are
            if any(value is None for value in semantic):
                raise ValueError(f"a3c.state_weight needs an env that returns its semantic state in info[{self.state_key!r}]")
            target = torch.as_tensor(np.stack(semantic), dtype=torch.float32)
            stats.state_loss = float((state_loss := (self.model.state(hidden) - target).pow(2).mean()).detach())
            loss = loss + self.state_weight * state_loss
        self.model.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(self.model.parameters(), self.max_grad_norm)
        stats.policy_loss, stats.value_loss = float(policy_loss.detach()), float(value_loss.detach())
        stats.entropy = float(entropy.detach())
        return [p.grad.detach().clone() for p in self.model.parameters()], stats


def apply_gradients(global_model: nn.Module, optimizer: torch.optim.Optimizer, gradients: list[torch.Tensor]) -> None:
    """Hogwild update of the shared network with one worker's gradients."""
    for parameter, gradient in zip(global_model.parameters(), gradients):
        parameter.grad = gradient
    optimizer.step()


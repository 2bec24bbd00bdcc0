"""Goal-conditioned SAC on binpick's episode replay, with GP imagination (thesis §3.3).

:class:`GoalSAC` is Stable-Baselines3's SAC whose replay is :class:`EpisodeReplayBuffer` (episode
HER) and whose gradient steps wait until the buffer is 10% full, as in the thesis. The
:class:`GPImagination` callback fits the GP dynamics model on real episodes and adds imagined
episodes from the current policy to the same buffer.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from stable_baselines3 import SAC
from stable_baselines3.common.utils import polyak_update
from stable_baselines3.common.callbacks import BaseCallback

from binpick.core.config import check_range
from binpick.rl.config.gp_her import GPConfig
from binpick.rl.gp_her.dynamics import GPDynamics
from binpick.rl.gp_her.imagination import imagine_episodes
from binpick.rl.common.demonstrations import DemonstrationSet, cloning_loss
from binpick.rl.common.replay import Episode, EpisodeReplayBuffer


class GoalSAC(SAC):
    """SAC that trains only once its :class:`EpisodeReplayBuffer` is ``start_fraction`` full.

    With ``demonstrations`` and ``bc_alpha`` > 0 (pick and place, thesis §4.5.3) the actor keeps a
    behaviour-cloning term (optionally Q-filtered) while it learns: plain SAC forgets a cloned policy
    within a few thousand steps, because its first actor updates follow a critic that knows nothing yet.
    """

    demonstrations: DemonstrationSet | None = None
    bc_alpha: float = 0.0  # weight of the RL term against the cloning term (TD3+BC's α)
    bc_likelihood_weight: float = 0.0  # keep fitting σ to the demonstrations (see behaviour_clone)
    bc_q_filter: bool = False  # clone only where the critic prefers the demonstrated action
    actor_noise: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None  # per-axis std of (gripper, achieved, goal)
    noisy_gripper: int = 0  # how many numbers of s̄'s observation describe the hand (0, 3, or 4 with the opening)

    def keep_cloning(self, demonstrations: DemonstrationSet, alpha: float, likelihood_weight: float = 0.0,
                     q_filter: bool = False) -> None:
        """Go on cloning ``demonstrations`` while SAC learns (thesis §4.5.3): the actor loss becomes
        ``alpha`` · SAC's term + the cloning term (see :meth:`_train_with_demonstrations`)."""
        self.demonstrations, self.bc_alpha = demonstrations, check_range("demonstrations.bc_alpha", alpha, 0.0, None)
        self.bc_likelihood_weight, self.bc_q_filter = likelihood_weight, bool(q_filter)

    def perturb_actor_inputs(self, noise, gripper: int) -> None:
        """Train the actor on s̄ plus Gaussian noise of std ``noise`` = (gripper, achieved, goal), each a
        number or one per axis, in metres (see :class:`binpick.rl.config.gp_her.ActorNoiseConfig`); the critic
        keeps reading the true s̄. ``gripper``: how many numbers before the achieved goal describe the
        hand (:func:`binpick.rl.common.wrappers.gripper_dims`: 3, its position, noised; a 4th, the fingers'
        opening, is left as it is)."""
        self.actor_noise = tuple(torch.as_tensor(v, dtype=torch.float32) for v in noise)
        self.noisy_gripper = int(gripper)

    def actor_view(self, observation: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """What the actor reads in an update: s̄ as is, or with ``actor_noise``. The achieved goal's
        noise is the same in ``observation`` and ``achieved_goal`` (one perceived object, two slots)."""
        if not self.actor_noise:
            return observation
        gripper_std, achieved_std, goal_std = self.actor_noise
        achieved = observation["achieved_goal"]
        achieved_noise = torch.randn_like(achieved) * achieved_std
        state = observation["observation"].clone()
        start = self.noisy_gripper
        if start:
            state[:, :3] += torch.randn_like(state[:, :3]) * gripper_std
        state[:, start:start + achieved.shape[1]] += achieved_noise  # privileged values after it stay true
        desired = observation["desired_goal"]
        return {**observation, "observation": state, "achieved_goal": achieved + achieved_noise,
                "desired_goal": desired + torch.randn_like(desired) * goal_std}

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        buffer = self.replay_buffer
        if isinstance(buffer, EpisodeReplayBuffer) and not buffer.ready:
            return
        if (self.demonstrations is None or not self.bc_alpha) and not self.actor_noise:
            super().train(gradient_steps, batch_size)
            return
        self._train_with_demonstrations(gradient_steps, batch_size)

    def pretrain_critic(self, gradient_steps: int, batch_size: int) -> None:
        """Critic updates alone, the cloned actor held fixed: the first actor updates of RL then follow
        a critic that already values the demonstrated behaviour instead of a random one."""
        self._train_with_demonstrations(gradient_steps, batch_size, update_actor=False)

    def _train_with_demonstrations(self, gradient_steps: int, batch_size: int, update_actor: bool = True) -> None:
        """SB3's SAC update (critic, entropy weight, actor) with the actor loss of TD3+BC:
        α · (ent · log π − Q) / mean|Q| + cloning, so the two terms keep comparable scales
        (|Q| is at least 1: rewards are −1 per step, a smaller mean only means an untrained critic).
        Without demonstrations the actor loss is the RL term alone. With ``actor_noise`` the actor
        reads noisy s̄ (its own loss and the next actions of the critic's target); the critic, true s̄."""
        cloning = self.demonstrations is not None and bool(self.bc_alpha)
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers.append(self.ent_coef_optimizer)
        if update_actor:  # before learn() there is no logger, and the learning rate is the initial one
            self._update_learning_rate(optimizers)
        rng = getattr(self, "_demo_rng", None) or np.random.default_rng(self._n_updates)
        self._demo_rng = rng
        logs: dict[str, list[float]] = {"actor_loss": [], "critic_loss": [], "ent_coef": [], "bc_loss": []}
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            if update_actor:  # the critic-only warm-up needs no actions of the actor's own here
                actions_pi, log_prob = self.actor.action_log_prob(self.actor_view(data.observations))
                log_prob = log_prob.reshape(-1, 1)
            if self.ent_coef_optimizer is not None and self.log_ent_coef is not None and update_actor:
                ent_coef = torch.exp(self.log_ent_coef.detach())
                ent_coef_loss = -(self.log_ent_coef * (log_prob + self.target_entropy).detach()).mean()
                self.ent_coef_optimizer.zero_grad()
                ent_coef_loss.backward()
                self.ent_coef_optimizer.step()
            elif self.log_ent_coef is not None:
                ent_coef = torch.exp(self.log_ent_coef.detach())
            else:
                ent_coef = self.ent_coef_tensor
            with torch.no_grad():
                next_actions, next_log_prob = self.actor.action_log_prob(self.actor_view(data.next_observations))
                next_q = torch.min(torch.cat(self.critic_target(data.next_observations, next_actions), dim=1),
                                   dim=1, keepdim=True).values
                next_q = next_q - ent_coef * next_log_prob.reshape(-1, 1)
                target_q = data.rewards + (1 - data.dones) * self.gamma * next_q
            critic_loss = 0.5 * sum(F.mse_loss(q, target_q) for q in self.critic(data.observations, data.actions))
            self.critic.optimizer.zero_grad()
            critic_loss.backward()
            self.critic.optimizer.step()
            polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
            logs["critic_loss"].append(critic_loss.item())
            if not update_actor:
                continue
            q_pi = torch.min(torch.cat(self.critic(data.observations, actions_pi), dim=1), dim=1, keepdim=True).values
            rl_loss = (ent_coef * log_prob - q_pi).mean() / q_pi.abs().mean().detach().clamp(min=1.0)
            if cloning:
                bc_loss, _ = cloning_loss(self, *self.demonstrations.sample(rng, batch_size), self.bc_likelihood_weight,
                                          self.bc_q_filter)
                actor_loss = self.bc_alpha * rl_loss + bc_loss
            else:
                bc_loss, actor_loss = torch.zeros(()), rl_loss
            self.actor.optimizer.zero_grad()
            actor_loss.backward()
            self.actor.optimizer.step()
            for key, value in (("actor_loss", actor_loss), ("ent_coef", ent_coef), ("bc_loss", bc_loss)):
                logs[key].append(value.item())
        if not update_actor:
            return
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        for key, values in logs.items():
            self.logger.record(f"train/{key}", float(np.mean(values)))

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_demo_rng"]

    def batch_policy(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """Exploring actions for a batch, in the [-1, 1] units the replay stores."""
        actions, _ = self.predict(observation, deterministic=False)
        return self.policy.scale_action(actions)


class GPImagination(BaseCallback):
    """Fit the GP after ``warmup_episodes`` real episodes, refit after every ``refit_every`` new real
    transitions (counted in steps: a good policy's episodes are short), and add ``imagined_per_real``
    imagined episodes for each real episode, generated in batches."""

    def __init__(self, warmup_episodes: int = 15, refit_every: int = 500, imagined_per_real: float = 20.0,
                 batch_episodes: int = 500, dynamics: GPDynamics | None = None, seed: int = 0,
                 fill_until_ready: bool = True, verbose: int = 0) -> None:
        super().__init__(verbose)
        # the same rules a YAML config's gp section is checked with, written once (GPConfig)
        settings = GPConfig(enabled=True, warmup_episodes=warmup_episodes, refit_every=refit_every,
                            imagined_per_real=imagined_per_real, batch_episodes=batch_episodes)
        self.warmup_episodes, self.refit_every = settings.warmup_episodes, settings.refit_every
        self.imagined_per_real, self.batch_episodes = settings.imagined_per_real, settings.batch_episodes
        self.dynamics = dynamics or GPDynamics(seed=seed)
        self.fill_until_ready = fill_until_ready
        self.rng = np.random.default_rng(seed)
        self.fits = 0
        self.imagined_steps = 0
        self._fitted_at = 0  # real transitions when the GP was last fitted
        self._real_seen = 0  # real episodes already paid for with imagined ones
        self._debt = 0.0  # imagined episodes owed, generated once a batch is due

    @property
    def buffer(self) -> EpisodeReplayBuffer:
        return self.model.replay_buffer  # type: ignore[return-value]

    def _on_step(self) -> bool:
        real = self.buffer.added["real"]
        if real < self.warmup_episodes:
            return True
        if not self.dynamics.fitted or self.buffer.real_transitions - self._fitted_at >= self.refit_every:
            self._fit()
        self._debt += self.imagined_per_real * (real - self._real_seen)  # the first time: all warm-up episodes
        self._real_seen = real
        # whole batches keep GP queries efficient
        while self._debt >= self.batch_episodes or (self._debt >= 1 and not self.buffer.ready):
            count = int(min(self._debt, self.batch_episodes))
            self.imagine(count)
            self._debt -= count
        # thesis §3.3.2: training starts once Ω is 10% full of simulator, GP or HER episodes, so the
        # GP fills what the simulator has not
        while self.fill_until_ready and not self.buffer.ready:
            self.imagine(self.batch_episodes)
        return True

    def _fit(self) -> None:
        episodes = self.buffer.stored_episodes("real")
        states = np.concatenate([e.achieved_goal[:-1] for e in episodes])
        actions = np.concatenate([e.actions for e in episodes])
        next_states = np.concatenate([e.achieved_goal[1:] for e in episodes])
        report = self.dynamics.fit(states, actions, next_states)
        self.fits += 1
        self._fitted_at = self.buffer.real_transitions
        self.logger.record("gp/fit_seconds", report.seconds)
        self.logger.record("gp/negative_mll", report.negative_mll)
        self.logger.record("gp/points", report.points)

    def imagine(self, count: int) -> list[Episode]:
        """Add ``count`` imagined episodes from real start states and goals (re-paired at random)."""
        real = self.buffer.stored_episodes("real")
        starts = np.stack([real[i].achieved_goal[0] for i in self.rng.integers(0, len(real), count)])
        goals = np.stack([real[i].desired_goal for i in self.rng.integers(0, len(real), count)])
        episodes = imagine_episodes(self.dynamics, self.model.batch_policy, starts.astype(np.float64),
                                    goals.astype(np.float64), self.buffer.compute_reward, self.buffer.T, self.rng)
        for episode in episodes:
            self.buffer.add_episode(episode, origin="imagined")
            self.imagined_steps += episode.length
        self.logger.record("gp/imagined_episodes", self.buffer.added["imagined"])
        return episodes

    def state(self) -> dict[str, Any]:
        """What a checkpoint keeps so a resumed run continues the same schedule."""
        return {"fits": self.fits, "imagined_steps": self.imagined_steps, "fitted_at": self._fitted_at,
                "real_seen": self._real_seen, "debt": self._debt}

    def restore(self, state: dict[str, Any]) -> None:
        self.fits, self.imagined_steps = state["fits"], state["imagined_steps"]
        self._fitted_at, self._real_seen, self._debt = state["fitted_at"], state["real_seen"], state["debt"]

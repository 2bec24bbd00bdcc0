"""Episode replay Ω of thesis §3.1.1 with the episode-level HER of §3.3.2.

Whole episodes are stored (capacity M *episodes*; the oldest is forgotten first). When an episode
ends unsuccessfully, α_HER relabelled copies are added whose goals are achieved states drawn
without replacement; each copy ends where it first reaches its new goal. Rewards and terminal flags
are recomputed with the env's ``compute_reward`` when sampled, so real, relabelled and imagined
(GP) episodes are all treated alike. Training should start once the buffer is ``start_fraction``
(thesis: 10%) full, see :attr:`EpisodeReplayBuffer.ready`.

The class plugs into Stable-Baselines3 as ``replay_buffer_class`` (SB3 calls :meth:`add` each step
and :meth:`sample` each gradient step).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import BaseBuffer, DictReplayBuffer
from stable_baselines3.common.type_aliases import DictReplayBufferSamples

from binpick.core.config import check_range
from binpick.core.errors import ConfigError
from binpick.rl.config.common import ReplayConfig

RewardFn = Callable[[np.ndarray, np.ndarray, Any], np.ndarray]
KEYS = ("observation", "achieved_goal", "desired_goal")
LOST = "episode_lost"  # info key of a step whose simulator died: the episode it ended is dropped


@dataclass
class Episode:
    """One episode: observations o_0..o_L, achieved goals z_0..z_L, actions a_0..a_{L-1}, goal g."""

    observation: np.ndarray  # (L+1, obs_dim)
    achieved_goal: np.ndarray  # (L+1, goal_dim)
    desired_goal: np.ndarray  # (goal_dim,)
    actions: np.ndarray  # (L, act_dim)

    @property
    def length(self) -> int:
        return len(self.actions)


class EpisodeReplayBuffer(DictReplayBuffer):
    """Whole-episode replay with episode HER; capacity and 10%-full start counted in episodes."""

    ORIGINS = ("real", "her", "imagined")

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Dict,
        action_space: spaces.Box,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        *,
        compute_reward: RewardFn,
        max_episode_steps: int,
        capacity_episodes: int = 10_000,
        her_additions: int = 1,
        start_fraction: float = 0.1,
        her_min_motion: float = 0.0,
        seed: int | None = None,
    ) -> None:
        # Deliberately not DictReplayBuffer.__init__: it would allocate per-transition arrays.
        BaseBuffer.__init__(self, buffer_size, observation_space, action_space, device=device, n_envs=n_envs)
        missing = [k for k in KEYS if k not in observation_space.spaces]
        if missing:
            raise ConfigError(f"episode replay needs dict observations with {', '.join(KEYS)}; missing {', '.join(missing)}")
        self.compute_reward = compute_reward
        self.T = check_range("max_episode_steps", max_episode_steps, 1, 100_000, integer=True)
        # the same rules a YAML config's replay section is checked with, written once (ReplayConfig)
        settings = ReplayConfig(capacity_episodes=capacity_episodes, her_additions=her_additions,
                                start_fraction=start_fraction, her_min_motion=her_min_motion)
        self.M, self.her_additions, self.start_fraction = settings.capacity_episodes, settings.her_additions, settings.start_fraction
        # thesis §4.5.3: HER copies only for episodes in which the achieved goal (the object) moved
        self.her_min_motion = settings.her_min_motion
        self.rng = np.random.default_rng(seed)
        obs_dim = observation_space["observation"].shape[0]
        goal_dim = observation_space["achieved_goal"].shape[0]
        act_dim = action_space.shape[0]
        # np.zeros maps pages lazily: memory grows with what is stored, not with M.
        self._obs = np.zeros((self.M, self.T + 1, obs_dim), np.float32)
        self._ag = np.zeros((self.M, self.T + 1, goal_dim), np.float32)
        self._dg = np.zeros((self.M, goal_dim), np.float32)
        self._actions = np.zeros((self.M, self.T, act_dim), np.float32)
        self._lengths = np.zeros(self.M, np.int64)
        self._origin = np.zeros(self.M, np.int8)
        self._next = 0  # slot the next episode goes into
        self._stored = 0
        self._cumulative: np.ndarray | None = None
        self.added = dict.fromkeys(self.ORIGINS, 0)  # episodes ever added, by origin
        self.added_when_ready: dict[str, int] | None = None  # the same counts when training could start
        self.real_transitions = 0
        self._open: list[dict[str, list]] = [self._empty_episode() for _ in range(n_envs)]

    # ------------------------------------------------------------------ state
    @property
    def episodes(self) -> int:
        """Episodes held now (at most M)."""
        return self._stored

    @property
    def ready(self) -> bool:
        """True once the buffer is ``start_fraction`` full: the thesis starts training then."""
        return self._stored >= max(1, int(np.ceil(self.start_fraction * self.M)))

    def size(self) -> int:
        """Transitions held now (what SB3 calls the buffer's size)."""
        return int(self._lengths[: self._stored].sum()) if self._stored < self.M else int(self._lengths.sum())

    def stored_episodes(self, origin: str | None = None) -> list[Episode]:
        """Copies of the stored episodes, optionally of one origin (for models fitted on real data)."""
        slots = np.arange(self._stored)
        if origin is not None:
            slots = slots[self._origin[: self._stored] == self.ORIGINS.index(origin)]
        result = []
        for slot in slots:
            length = int(self._lengths[slot])
            result.append(Episode(self._obs[slot, : length + 1].copy(), self._ag[slot, : length + 1].copy(),
                                  self._dg[slot].copy(), self._actions[slot, :length].copy()))
        return result

    # ------------------------------------------------------------------ adding
    def add(self, obs, next_obs, action, reward, done, infos) -> None:  # type: ignore[override]
        """SB3's per-step hook: grow each env's open episode; store it (plus HER copies) when it ends."""
        for env in range(self.n_envs):
            if infos[env].get(LOST):  # its simulator's process died: the episode is dropped, no step invented
                self._open[env] = self._empty_episode()
                continue
            episode = self._open[env]
            if not episode["actions"]:
                episode["observation"].append(np.array(obs["observation"][env], np.float32))
                episode["achieved_goal"].append(np.array(obs["achieved_goal"][env], np.float32))
                episode["desired_goal"] = np.array(obs["desired_goal"][env], np.float32)
            episode["actions"].append(np.array(action[env], np.float32))
            episode["observation"].append(np.array(next_obs["observation"][env], np.float32))
            episode["achieved_goal"].append(np.array(next_obs["achieved_goal"][env], np.float32))
            if done[env] or len(episode["actions"]) >= self.T:
                self.real_transitions += len(episode["actions"])
                self.add_episode(
                    Episode(np.stack(episode["observation"]), np.stack(episode["achieved_goal"]),
                            episode["desired_goal"], np.stack(episode["actions"])),
                    origin="real",
                )
                self._open[env] = self._empty_episode()

    def for_envs(self, n_envs: int) -> None:
        """Take steps from ``n_envs`` simulators from now on (episodes still open are dropped)."""
        self.n_envs = int(n_envs)
        self._open = [self._empty_episode() for _ in range(self.n_envs)]

    def add_episode(self, episode: Episode, origin: str = "real", relabel: bool = True) -> int:
        """Store an episode and, if it failed and ``relabel``, its α_HER hindsight copies.

        Returns the number of episodes stored (1 + HER copies).
        """
        self._store(episode, origin)
        stored = 1
        if relabel and self.her_additions > 0 and not self.succeeded(episode) and self.moved(episode):
            for copy in self.relabel(episode):
                self._store(copy, "her")
                stored += 1
        return stored

    def moved(self, episode: Episode) -> bool:
        """Did the achieved goal move more than ``her_min_motion`` from where the episode began?"""
        if self.her_min_motion <= 0:
            return True
        travel = np.linalg.norm(episode.achieved_goal - episode.achieved_goal[0], axis=-1)
        return bool(travel.max() > self.her_min_motion)

    def succeeded(self, episode: Episode) -> bool:
        rewards = self.compute_reward(episode.achieved_goal[1:], np.broadcast_to(episode.desired_goal, episode.achieved_goal[1:].shape), None)
        return bool(np.any(np.asarray(rewards) >= 0))

    def relabel(self, episode: Episode) -> list[Episode]:
        """α_HER copies with goals = achieved states z_i (i ≥ 1) drawn without replacement; each copy
        is cut at the first step that reaches its new goal, as a real episode would end there."""
        achieved = episode.achieved_goal[1:]
        count = min(self.her_additions, len(achieved))
        copies = []
        for index in self.rng.choice(len(achieved), size=count, replace=False):
            goal = achieved[index]
            rewards = np.asarray(self.compute_reward(achieved, np.broadcast_to(goal, achieved.shape), None))
            end = int(np.argmax(rewards >= 0)) + 1  # first success; exists, since z_index == goal
            copies.append(Episode(episode.observation[: end + 1], episode.achieved_goal[: end + 1], goal.copy(),
                                  episode.actions[:end]))
        return copies

    def _store(self, episode: Episode, origin: str) -> None:
        length = episode.length
        if not 1 <= length <= self.T:
            raise ValueError(f"episode length must be in [1, {self.T}], got {length}")
        slot = self._next
        self._obs[slot, : length + 1] = episode.observation
        self._ag[slot, : length + 1] = episode.achieved_goal
        self._dg[slot] = episode.desired_goal
        self._actions[slot, :length] = episode.actions
        self._lengths[slot] = length
        self._origin[slot] = self.ORIGINS.index(origin)
        self._next = (slot + 1) % self.M
        self._stored = min(self._stored + 1, self.M)
        self._cumulative = None
        self.added[origin] += 1
        if self.added_when_ready is None and self.ready:
            self.added_when_ready = dict(self.added)

    # ------------------------------------------------------------------ sampling
    def sample_arrays(self, batch_size: int) -> dict[str, np.ndarray]:
        """Uniform over stored transitions: obs, next obs (dicts), actions, rewards, dones."""
        if self._stored == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        if self._cumulative is None:
            self._cumulative = np.cumsum(self._lengths[: self._stored])
        picks = self.rng.integers(0, self._cumulative[-1], size=batch_size)
        slots = np.searchsorted(self._cumulative, picks, side="right")
        steps = picks - (self._cumulative[slots] - self._lengths[slots])
        goal = self._dg[slots]
        next_achieved = self._ag[slots, steps + 1]
        rewards = np.asarray(self.compute_reward(next_achieved, goal, None), np.float32)
        return {
            "obs": {"observation": self._obs[slots, steps], "achieved_goal": self._ag[slots, steps], "desired_goal": goal},
            "next_obs": {"observation": self._obs[slots, steps + 1], "achieved_goal": next_achieved, "desired_goal": goal},
            "actions": self._actions[slots, steps],
            "rewards": rewards,
            "dones": (rewards >= 0).astype(np.float32),  # success ends an episode; time limits do not
        }

    def sample(self, batch_size: int, env=None) -> DictReplayBufferSamples:  # type: ignore[override]
        batch = self.sample_arrays(batch_size)
        obs = self._normalize_obs(batch["obs"], env)
        next_obs = self._normalize_obs(batch["next_obs"], env)
        return DictReplayBufferSamples(
            observations={k: self.to_torch(v) for k, v in obs.items()},
            actions=self.to_torch(batch["actions"]),
            next_observations={k: self.to_torch(v) for k, v in next_obs.items()},
            dones=self.to_torch(batch["dones"]).reshape(-1, 1),
            rewards=self.to_torch(self._normalize_reward(batch["rewards"].reshape(-1, 1), env)),
        )

    # ------------------------------------------------------------------ saving (no pickle)
    _ARRAYS = ("_obs", "_ag", "_dg", "_actions", "_lengths", "_origin")
    _SETTINGS = ("M", "T", "her_additions", "start_fraction", "her_min_motion")

    def state_arrays(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """The used slots as arrays and the counters, random state and settings as JSON data: an
        M = 10^6 buffer is GBs when full but small at first, so only what is stored is written."""
        used = self._stored
        arrays = {key.lstrip("_"): getattr(self, key)[:used] for key in self._ARRAYS}
        counters = {"next": self._next, "stored": self._stored, "added": dict(self.added),
                    "added_when_ready": self.added_when_ready, "real_transitions": self.real_transitions,
                    "rng": self.rng.bit_generator.state, "settings": {k: getattr(self, k) for k in self._SETTINGS}}
        return arrays, counters

    def load_state_arrays(self, arrays: dict[str, np.ndarray], counters: dict[str, Any]) -> None:
        """Refill a buffer built with the same settings from :meth:`state_arrays`. Episodes that were
        still open are dropped: a resumed run starts new ones."""
        settings = counters["settings"]
        differ = [k for k in self._SETTINGS if settings.get(k) != getattr(self, k)]
        if differ:
            raise ValueError(f"{differ[0]} was {settings.get(differ[0])!r}, this buffer has {getattr(self, differ[0])!r}")
        used = int(counters["stored"])
        if not 0 <= used <= self.M or not 0 <= int(counters["next"]) < self.M:
            raise ValueError(f"{used} stored episodes do not fit M = {self.M}")
        for key in self._ARRAYS:
            values = arrays[key.lstrip("_")]
            target = getattr(self, key)
            if values.shape != (used, *target.shape[1:]):
                raise ValueError(f"{key.lstrip('_')} has shape {values.shape}, expected {(used, *target.shape[1:])}")
            target[:used] = values
        if np.any(self._lengths[:used] < 1) or np.any(self._lengths[:used] > self.T):
            raise ValueError("episode lengths out of range")
        self._next, self._stored = int(counters["next"]), used
        self.added = {origin: int(counters["added"][origin]) for origin in self.ORIGINS}
        ready = counters["added_when_ready"]
        self.added_when_ready = None if ready is None else {origin: int(ready[origin]) for origin in self.ORIGINS}
        self.real_transitions = int(counters["real_transitions"])
        self.rng.bit_generator.state = counters["rng"]
        self._cumulative = None
        self._open = [self._empty_episode() for _ in range(self.n_envs)]

    @staticmethod
    def _empty_episode() -> dict[str, list]:
        return {"observation": [], "achieved_goal": [], "actions": [], "desired_goal": None}

"""Simulators spread over processes and machines with Ray (thesis §6.1, in place of ROS multimaster).

Each :class:`SimulatorWorker` is a Ray actor that owns one simulator and plays whole episodes with
the latest policy it was sent. :class:`DistributedRollouts` keeps one episode in flight per worker
and hands finished episodes to the learner as they arrive, so a slow worker never blocks a fast one.
A worker that dies (a crash, a killed process, a lost machine) is restarted by Ray; the episode it
was playing is lost and counted, the fresh worker gets the current policy again, and the stream
goes on.

Locally ``ray.init()`` starts a private cluster on this machine; ``address="ray://..."`` or
``"HOST:6379"`` joins a cluster started with ``ray start --head`` (see the README).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from binpick.cluster import start_ray


@dataclass
class Episode:
    """One episode played by one worker: everything a replay buffer needs, in step order."""

    worker: int
    pid: int
    observations: list[Any]  # s_0 ... s_{T-1}
    next_observations: list[Any]  # s_1 ... s_T
    actions: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    success: bool
    policy_version: int = -1

    @property
    def steps(self) -> int:
        return len(self.actions)


class SimulatorWorker:
    """One simulator in its own process. Plain class: :class:`DistributedRollouts` makes it an actor."""

    def __init__(self, env_id: str, env_kwargs: dict, seed: int, index: int) -> None:
        os.environ.setdefault("MUJOCO_GL", "egl")
        import torch

        from binpick.envs import make

        torch.set_num_threads(1)  # one core per simulator
        self.env, self.index, self.seed = make(env_id, **env_kwargs), index, seed
        self.policy, self.version, self.played = None, -1, 0

    def set_policy(self, policy: Any, version: int) -> None:
        """An SB3 policy (anything with ``predict``), or None for random actions."""
        self.policy, self.version = policy, version

    def pid(self) -> int:
        return os.getpid()

    def play(self, deterministic: bool = False) -> Episode:
        observation, _ = self.env.reset(seed=self.seed * 1_000_003 + self.played)
        self.played += 1
        observations, next_observations, actions, rewards, terminated, truncated = [], [], [], [], [], []
        success = False
        while True:
            if self.policy is None:
                action = self.env.action_space.sample()
            else:
                action, _ = self.policy.predict(observation, deterministic=deterministic)
            next_observation, reward, term, trunc, info = self.env.step(action)
            observations.append(observation)
            next_observations.append(next_observation)
            actions.append(np.asarray(action))
            rewards.append(float(reward))
            terminated.append(bool(term))
            truncated.append(bool(trunc))
            success = bool(info.get("is_success", success))
            observation = next_observation
            if term or trunc:
                break
        return Episode(self.index, os.getpid(), observations, next_observations, np.array(actions), np.array(rewards),
                       np.array(terminated), np.array(truncated), success, self.version)


@dataclass
class StreamStats:
    episodes: int = 0
    steps: int = 0
    per_worker_steps: dict[int, int] = field(default_factory=dict)


class RestartingActors:
    """Ray actors of one class that Ray restarts when their process dies, kept busy with one task
    each. :meth:`results` yields ``(worker index, result)`` as tasks finish; a task lost with its
    worker is counted once per death, and ``on_restart(index)`` runs before the worker's next task
    (to resend state the fresh process lacks)."""

    def __init__(self, actor_class: type, arguments: list[tuple], address: str | None = None) -> None:
        from binpick.core.errors import ConfigError

        if not arguments:
            raise ConfigError("workers must be at least 1, got 0")
        self.owns_ray = start_ray(address, len(arguments))  # a private local cluster stays on 127.0.0.1
        import ray

        remote = ray.remote(num_cpus=1, max_restarts=-1, max_task_retries=0)(actor_class)
        self.actors = [remote.remote(*args) for args in arguments]
        self.in_flight: dict[Any, int] = {}
        self.recovering: set[int] = set()  # workers whose process died and is being restarted
        self.deaths = 0  # worker processes that died: each lost its task in flight and was restarted

    def pids(self, timeout: float = 60.0) -> list[int]:
        """Process ids of the workers (waits for restarting ones)."""
        import ray
        from ray.exceptions import ActorUnavailableError, RayActorError

        deadline = time.monotonic() + timeout
        while True:
            try:
                return ray.get([actor.pid.remote() for actor in self.actors])
            except (RayActorError, ActorUnavailableError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)

    def start(self, index: int, ref: Any) -> None:
        """A task (its object ref) now runs on worker ``index``."""
        self.in_flight[ref] = index

    def idle(self) -> list[int]:
        """Workers with no task running."""
        busy = set(self.in_flight.values())
        return [index for index in range(len(self.actors)) if index not in busy]

    def next_result(self, timeout: float | None = None) -> tuple[int, Any, bool]:
        """The next task to end: ``(worker index, result, True)``, or ``(index, None, False)`` when the
        worker died with it (Ray restarts the worker; a death is counted once however many tasks it
        loses while restarting). No task ending within ``timeout`` seconds is a :class:`TimeoutError`."""
        import ray
        from ray.exceptions import ActorUnavailableError, RayActorError

        ready, _ = ray.wait(list(self.in_flight), num_returns=1, timeout=timeout)
        if not ready:
            raise TimeoutError(f"no worker finished a task within {timeout:.0f} s")
        index = self.in_flight.pop(ready[0])
        try:
            result = ray.get(ready[0])
        except (RayActorError, ActorUnavailableError):
            if index not in self.recovering:
                self.deaths += 1
                self.recovering.add(index)
            time.sleep(0.2)
            return index, None, False
        self.recovering.discard(index)
        return index, result, True

    def results(self, submit, on_restart=None) -> Iterator[tuple[int, Any]]:
        """``submit(actor)`` starts a task on an actor and returns its object ref; every worker is kept
        busy and the results are yielded as they come; a lost task is started again."""
        for index in self.idle():
            self.start(index, submit(self.actors[index]))
        while True:
            index, result, ok = self.next_result()
            if not ok and on_restart is not None:
                on_restart(index)
            self.start(index, submit(self.actors[index]))
            if ok:
                yield index, result

    def close(self) -> None:
        import ray

        for actor in self.actors:
            ray.kill(actor, no_restart=True)
        self.actors, self.in_flight = [], {}
        if self.owns_ray:  # we started the local cluster: stop it too
            ray.shutdown()


class DistributedRollouts:
    """``workers`` simulators of ``env_id``; iterate :meth:`stream` for episodes."""

    def __init__(self, env_id: str, workers: int = 2, address: str | None = None, env_kwargs: dict | None = None,
                 seed: int = 0) -> None:
        self.pool = RestartingActors(SimulatorWorker, [(env_id, env_kwargs or {}, seed + i, i) for i in range(workers)], address)
        self.policy_ref, self.version = None, -1
        self.stats = StreamStats()

    def set_policy(self, policy: Any) -> None:
        """Send the learner's current policy to every worker (it applies before the worker's next episode)."""
        import ray

        self.version += 1
        self.policy_ref = ray.put(policy)
        for actor in self.pool.actors:
            actor.set_policy.remote(self.policy_ref, self.version)

    def worker_pids(self) -> list[int]:
        return self.pool.pids()

    def _resend_policy(self, index: int) -> None:
        if self.policy_ref is not None:  # the fresh process needs the current policy again
            self.pool.actors[index].set_policy.remote(self.policy_ref, self.version)

    def stream(self, max_episodes: int | None = None) -> Iterator[Episode]:
        """Episodes as they finish, from whichever worker; a dead worker's episode is skipped."""
        delivered = 0
        for index, episode in self.pool.results(lambda actor: actor.play.remote(), self._resend_policy):
            self.stats.episodes += 1
            self.stats.steps += episode.steps
            self.stats.per_worker_steps[index] = self.stats.per_worker_steps.get(index, 0) + episode.steps
            delivered += 1
            yield episode
            if max_episodes is not None and delivered >= max_episodes:
                return

    def close(self) -> None:
        self.pool.close()

"""An RL run's simulators as Ray actors behind Stable-Baselines3's ``VecEnv`` (thesis §6.1's distributed
simulators feeding one learner), so the SB3-based learners (SAC with GP imagination and episode HER) keep
their own ``learn()`` loop, callbacks, checkpoints and run folder.

Each :class:`EnvActor` owns the env exactly as a local run trains on it
(:func:`binpick.rl.envs.make_env` under SB3's ``Monitor``) and resets itself when an episode ends, as
``DummyVecEnv`` does, so one vector step is one round trip to every actor, in parallel. An actor whose
process dies (a crash, a killed process, a lost machine) is restarted by Ray: the episode it was playing
ends there as truncated with ``episode_lost`` in its info (the replay drops it; no step is invented), the
fresh process gets the calls made through :meth:`RayVecEnv.env_method` again (the curriculum's goal area)
and starts a new episode. The vector step still counts, so a run's step count and evaluations are those
of a run without the fault.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from copy import deepcopy
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices
from stable_baselines3.common.vec_env.util import dict_to_obs, obs_space_info

from binpick.core.errors import WorkerError
from binpick.integrations.ray.actors import RestartingActors, raise_if_it_never_started
from binpick.rl.common.replay import LOST  # info key: the episode ended because its simulator's process died

FAILING_S = 120.0  # an actor that cannot be started again for this long fails the run
WAIT_S = 600.0  # a vector step (or a call) that no simulator answers for this long fails the run
RESUME = "the run keeps its last checkpoint (binpick train --resume RUN --address ...)"


class EnvActor:
    """One simulator of an RL run, in its own process (a plain class: :class:`RayVecEnv` makes it an actor)."""

    def __init__(self, config) -> None:
        os.environ.setdefault("MUJOCO_GL", "egl")
        import torch
        from stable_baselines3.common.monitor import Monitor

        from binpick.rl.envs import make_env

        torch.set_num_threads(1)  # one core per simulator
        self.env = Monitor(make_env(config))  # episode lengths in the info, as SB3 wraps a local env
        self.started = False  # a process Ray started again after a death has no episode until reset

    def pid(self) -> int:
        return os.getpid()

    def reset(self, seed: int | None, options: dict | None = None) -> tuple[Any, dict]:
        self.started = True
        return self.env.reset(seed=seed, options=options)

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, dict, dict | None] | None:
        """One step; at the end of an episode the next one starts here (``DummyVecEnv``'s semantics). None
        from a fresh process (Ray restarted it between two steps): the episode was lost with the old one.
        The last item: the next episode's reset info, or None."""
        if not self.started:
            return None
        observation, reward, terminated, truncated, info = self.env.step(action)
        done = bool(terminated or truncated)
        info["TimeLimit.truncated"] = bool(truncated and not terminated)
        reset_info = None
        if done:
            info["terminal_observation"] = observation
            observation, reset_info = self.env.reset()
        return observation, float(reward), done, info, reset_info

    def call(self, name: str, args: tuple, kwargs: dict) -> Any:
        return self.env.get_wrapper_attr(name)(*args, **kwargs)

    def get(self, name: str) -> Any:
        return self.env.get_wrapper_attr(name)

    def is_wrapped(self, wrapper_class: type) -> bool:
        from stable_baselines3.common.env_util import is_wrapped

        return is_wrapped(self.env, wrapper_class)


class RayVecEnv(VecEnv):
    """``workers`` simulators of ``config``'s env as Ray actors (``address`` None: a private cluster on
    127.0.0.1; else a cluster address); ``spaces_from``: a local env of the same config, for the spaces."""

    def __init__(self, config, workers: int, address: str | None, spaces_from) -> None:
        self.pool = RestartingActors(EnvActor, [(config,)] * workers, address)
        try:  # (SB3 asks every env for its render mode here: the actors have started once this returns)
            super().__init__(workers, spaces_from.observation_space, spaces_from.action_space)
        except BaseException:
            self.pool.close()
            raise
        self.keys, shapes, dtypes = obs_space_info(self.observation_space)
        self.buf_obs = {k: np.zeros((workers, *shapes[k]), dtype=dtypes[k]) for k in self.keys}
        self.calls: dict[str, tuple[tuple, dict]] = {}  # the last env_method call of each name, for restarted actors
        self.deaths = 0  # simulator processes that died, each ending its episode as lost
        self.actions: np.ndarray | None = None

    # ------------------------------------------------------------------ VecEnv
    def reset(self):
        # seeds set by VecEnv.seed (SB3 seeds the run's envs with its seed + index), options by set_options
        results = self._gather([actor.reset.remote(seed, options or None)
                                for actor, seed, options in zip(self.pool.actors, self._seeds, self._options)])
        for index, result in enumerate(results):
            if result is None:  # died before its first step: the fresh process starts the episode
                result = self._restart(index)
            observation, self.reset_infos[index] = result
            self._save(index, observation)
        self._reset_seeds()
        self._reset_options()
        return self._observations()

    def step_async(self, actions: np.ndarray) -> None:
        self.actions = actions

    def step_wait(self):
        refs = [actor.step.remote(action) for actor, action in zip(self.pool.actors, self.actions)]
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        dones = np.zeros(self.num_envs, dtype=bool)
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        for index, result in enumerate(self._gather(refs)):
            if result is None:  # its process died (now or since the last step): the episode ends here, lost
                last = {k: self.buf_obs[k][index].copy() for k in self.keys}
                infos[index] = {"TimeLimit.truncated": True, LOST: True,
                                "terminal_observation": last if self.keys != [None] else last[None]}
                dones[index] = True
                observation, self.reset_infos[index] = self._restart(index)
            else:
                observation, rewards[index], dones[index], infos[index], reset_info = result
                if reset_info is not None:
                    self.reset_infos[index] = reset_info
            self._save(index, observation)
        return self._observations(), rewards, dones, infos

    def close(self) -> None:
        self.pool.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The attribute of each env (None from one whose process just died)."""
        return self._gather([self.pool.actors[i].get.remote(attr_name) for i in self._get_indices(indices)])

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        raise NotImplementedError("set_attr does not reach Ray actors that may restart; call a method (env_method)")

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        """Call a method of the envs; a call to every env is made again on any actor restarted later."""
        targets = list(self._get_indices(indices))
        if len(targets) == self.num_envs:
            self.calls[method_name] = (method_args, method_kwargs)
        # (one that died on the way answers None; its next step finds the process gone or fresh and ends
        # its episode there, and the restart makes the calls again, this one included)
        return self._gather([self.pool.actors[i].call.remote(method_name, method_args, method_kwargs) for i in targets])

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return self._gather([self.pool.actors[i].is_wrapped.remote(wrapper_class) for i in self._get_indices(indices)])

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None] * self.num_envs

    # ------------------------------------------------------------------ actors
    def pids(self) -> list[int]:
        return self.pool.pids()

    def _gather(self, refs: list) -> list[Any]:
        """Each ref's result, or None where the actor's process died with it. An actor that could not be
        made at all (a simulator that cannot start there) fails the run at once, and so does one that
        answers nothing for ``WAIT_S`` (a hung simulator, or actors the cluster has no CPUs for)."""
        import ray
        from ray.exceptions import ActorUnavailableError, GetTimeoutError, RayActorError

        results, deadline = [], time.monotonic() + WAIT_S
        for ref in refs:
            try:
                results.append(ray.get(ref, timeout=max(deadline - time.monotonic(), 1.0)))
            except (RayActorError, ActorUnavailableError) as error:
                raise_if_it_never_started(error, "a simulator of this run")
                results.append(None)
            except GetTimeoutError:
                raise WorkerError(f"a simulator on Ray answered nothing for {WAIT_S:.0f} s (hung, or not placed: "
                                  f"{self.num_envs} simulators need {self.num_envs} free CPUs on the cluster); "
                                  f"{RESUME}") from None
        return results

    def _restart(self, index: int) -> tuple[Any, dict]:
        """Wait for Ray's restart of actor ``index``, make its calls again and start an episode there."""
        import ray
        from ray.exceptions import ActorUnavailableError, GetTimeoutError, RayActorError

        self.deaths += 1
        actor, since = self.pool.actors[index], time.monotonic()
        while True:
            left = FAILING_S - (time.monotonic() - since)
            try:
                for name, (args, kwargs) in self.calls.items():
                    ray.get(actor.call.remote(name, args, kwargs), timeout=max(left, 1.0))
                # unseeded: a fresh process plays other episodes than the ones its predecessor played
                return ray.get(actor.reset.remote(None), timeout=max(left, 1.0))
            except (RayActorError, ActorUnavailableError, GetTimeoutError) as error:
                raise_if_it_never_started(error, f"simulator {index}")
                if time.monotonic() - since > FAILING_S:
                    raise WorkerError(f"simulator {index} on Ray did not come back within {FAILING_S:.0f} s after its "
                                      f"process died; {RESUME}") from None
                time.sleep(0.2)

    def _save(self, index: int, observation: Any) -> None:
        for key in self.keys:
            self.buf_obs[key][index] = observation if key is None else observation[key]

    def _observations(self):
        return dict_to_obs(self.observation_space, deepcopy(self.buf_obs))

    def _get_indices(self, indices: VecEnvIndices):
        if indices is None:
            return range(self.num_envs)
        if isinstance(indices, int):
            return [indices]
        return indices

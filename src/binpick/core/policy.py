"""One shape for every trained policy binpick makes, as Stable-Baselines3 users know it::

    from binpick import Policy
    policy = Policy.load("runs/fetchreach_gp_her/<time>")   # an RL run, an APRiL run, or a policy.safetensors
    action, state = policy.predict(observation, deterministic=True)

A run folder is recognised by the job it holds (:mod:`binpick.core.jobs`: each job kind that makes a
policy names its loader): an RL run gives its latest checkpoint's policy (SAC, SB3 SAC+HER, DQN or A3C),
an APRiL run the policy that acts on camera images. Nothing is unpickled."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from binpick.core.errors import ConfigError
from binpick.core.jobs import KINDS, job_kind_of_run, load_entry_point


class Policy:
    """A trained policy: its spaces and ``predict(observation) -> (action, state)`` (``state`` is a
    recurrent policy's memory; binpick's policies have none and return None)."""

    observation_space: Any
    action_space: Any

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = False) -> tuple[np.ndarray, Any]:
        raise NotImplementedError

    @staticmethod
    def load(path: str | Path, env_id: str | None = None) -> Policy:
        """The policy in ``path``: a run folder (the job it holds says how it is read) or a
        ``policy.safetensors`` file; ``env_id``: refuse a policy trained on another env."""
        path = Path(path)
        if path.is_file():
            return load_entry_point(POLICY_FILE_LOADER)(path)
        if not path.is_dir():
            raise ConfigError(f"{str(path)!r} is neither a run folder nor a policy file")
        return load_entry_point(_kind_with(path, "policy").policy)(path, env_id)

    @staticmethod
    def make_env(run_dir: str | Path):
        """The env exactly as the run trained on it (an RL run: semantic state, minimum action scale):
        what its policy's observations and actions mean."""
        return load_entry_point(_kind_with(Path(run_dir), "env").env)(Path(run_dir))


POLICY_FILE_LOADER = "binpick.rl.common.persistence:load_saved_policy"  # a policy.safetensors of any SB3 algorithm


def _kind_with(run_dir: Path, what: str):
    """The job kind of a run folder, refused in one line unless it declares ``what`` (its policy or env)."""
    kind = job_kind_of_run(run_dir)
    if getattr(kind, what) is None:
        holding = ", ".join(task for task, other in KINDS.items() if getattr(other, what))
        raise ConfigError(f"{str(run_dir)!r} is a {kind.task} run, which has no {what} to load (runs that do: {holding})")
    return kind

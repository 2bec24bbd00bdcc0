"""A trained A3C actor as a policy, read from its checkpoint (safetensors; an older run's ``a3c.pt`` as
plain tensors only)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from binpick.core import tensorfile
from binpick.core.errors import InputFileError
from binpick.core.files import require_fields
from binpick.core.policy import Policy
from binpick.rl.a3c.networks import ActorCritic

FORMAT = "binpick-a3c-checkpoint-1"
A3C_FILE = "a3c.safetensors"
ACTIONS = 6  # Arm2D's: each of three joints turned by ±π/8


class SampledPolicy(Policy):
    """The actor as a policy: called, it samples its distribution as A3C acted in training; ``predict``
    is greedy when asked to be (:func:`evaluate_policy` asks unless ``deterministic=False``)."""

    def __init__(self, model: ActorCritic, deterministic: bool = False, observation_shape: tuple[int, ...] | None = None) -> None:
        from gymnasium import spaces

        self.model, self.deterministic = model, deterministic
        self.action_space = spaces.Discrete(ACTIONS)
        self.observation_space = None if observation_shape is None else spaces.Box(-np.inf, np.inf, observation_shape, np.float32)

    def __call__(self, observation: np.ndarray) -> int:
        return self.model.act(observation, deterministic=self.deterministic)

    def predict(self, observation: np.ndarray, state=None, episode_start=None, deterministic: bool = False):
        """SB3's shape: ``(action, state)``. A3C acts by sampling unless ``deterministic``."""
        return self.model.act(observation, deterministic=deterministic or self.deterministic), None


def read_a3c_checkpoint(checkpoint: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(state, meta)`` of a checkpoint folder: ``a3c.safetensors``, or an older run's ``a3c.pt`` read
    as plain tensors only. Damage is one line naming the file."""
    checkpoint = Path(checkpoint)
    legacy = checkpoint / "a3c.pt"
    if legacy.is_file() and not (checkpoint / A3C_FILE).is_file():
        state = meta = tensorfile.load_legacy_torch(legacy, "A3C checkpoint")
        path = legacy
        if not isinstance(state, dict):
            raise InputFileError(f"A3C checkpoint {str(legacy)!r} is damaged: not a mapping")
    else:
        path = checkpoint / A3C_FILE
        _, meta, state = tensorfile.load(path, FORMAT, "A3C checkpoint")
        state = state or {}
    where = f"A3C checkpoint {str(path)!r}"
    require_fields(meta, {"observation_shape": (list, tuple)}, where)
    require_fields(state, {"model": dict, "optimizer": dict}, where)
    return state, meta


def load_a3c_policy(checkpoint: Path) -> SampledPolicy:
    """A trained A3C actor as a policy (samples its action distribution, as it acted in training)."""
    state, meta = read_a3c_checkpoint(checkpoint)
    try:
        model = ActorCritic(tuple(int(v) for v in meta["observation_shape"]), ACTIONS, str(meta.get("encoder", "flatten")),
                            int(meta.get("state_size", 0)), str(meta.get("policy_input", "features")),
                            hidden_layers=int(meta.get("hidden_layers", 1)))
        model.load_state_dict(state["model"])
    except (TypeError, ValueError, RuntimeError) as error:
        raise InputFileError(f"A3C checkpoint {checkpoint} is damaged ({str(error).splitlines()[0][:120]})") from None
    model.eval()
    return SampledPolicy(model, observation_shape=tuple(int(v) for v in meta["observation_shape"]))

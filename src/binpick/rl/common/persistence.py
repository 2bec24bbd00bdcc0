"""RL state on disk without pickle: Stable-Baselines3 algorithms, replay buffers and policies.

Stable-Baselines3's own zip files unpickle parts of themselves (spaces, schedules, the replay
buffer's reward function) when loaded, so binpick never reads them. Instead:

- ``algorithm.safetensors``: every network and optimiser state (SB3's ``get_parameters``), its
  tensor variables (SAC's entropy weight) and counters; restored into a model rebuilt from the
  run's config (:func:`save_algorithm`, :func:`load_algorithm`).
- ``replay.npz`` (``allow_pickle=False``) + the buffer's counters and random state in JSON
  (:func:`save_replay`, :func:`load_replay`), for binpick's episode replay and SB3's HER buffer.
- ``policy.safetensors``: what deploys — the policy network's weights and, as JSON, its spaces and
  architecture, from which :func:`load_saved_policy` rebuilds it (:class:`SavedPolicy`).
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import BasePolicy

from binpick.core import tensorfile
from binpick.core.policy import Policy
from binpick.envs.spaces import build_space, describe_space
from binpick.core.errors import InputFileError
from binpick.core.files import atomic_write, atomic_write_json, read_json_object, read_npz, require_fields

ALGORITHM_FORMAT = "binpick-sb3-algorithm-1"
POLICY_FORMAT = "binpick-sb3-policy-1"
REPLAY_FORMAT = "binpick-replay-1"
ALGORITHM_FILE = "algorithm.safetensors"  # in a checkpoint folder: the learner, to resume it
POLICY_FILE = "policy.safetensors"  # the policy network alone, to deploy it
COUNTERS = ("num_timesteps", "_n_updates", "_episode_num", "_n_calls")


# ---------------------------------------------------------------------- algorithm (training state)
def save_algorithm(model: BaseAlgorithm, path: Path) -> None:
    """Networks, optimisers, tensor variables and counters of ``model`` (no replay buffer)."""
    _, variables = model._get_torch_save_params()
    state = {"params": model.get_parameters(), "variables": {name: getattr(model, name) for name in variables}}
    counters = {name: int(getattr(model, name)) for name in COUNTERS if hasattr(model, name)}
    tensorfile.save(path, ALGORITHM_FORMAT, state=state, meta={"algorithm": type(model).__name__, "counters": counters})


def copy_algorithm(source: BaseAlgorithm, target: BaseAlgorithm) -> None:
    """What :func:`save_algorithm` keeps, from one model into another built the same way (e.g. for
    another number of simulators), in memory."""
    _, variables = source._get_torch_save_params()
    target.set_parameters(source.get_parameters(), exact_match=True, device="cpu")
    with torch.no_grad():
        for name in variables:
            getattr(target, name).copy_(getattr(source, name))
    for name in COUNTERS:
        if hasattr(source, name):
            setattr(target, name, int(getattr(source, name)))


def load_algorithm(model: BaseAlgorithm, path: Path) -> None:
    """Restore what :func:`save_algorithm` wrote into ``model``, built the same way from the run's config."""
    _, meta, state = tensorfile.load(path, ALGORITHM_FORMAT, "RL checkpoint")
    where = f"RL checkpoint {str(path)!r}"
    require_fields(meta, {"algorithm": str, "counters": dict}, where)
    require_fields(state or {}, {"params": dict, "variables": dict}, where)
    if meta["algorithm"] != type(model).__name__:
        raise InputFileError(f"{where} holds a {meta['algorithm']} model, this run trains {type(model).__name__}")
    try:
        model.set_parameters(state["params"], exact_match=True, device="cpu")
        for name, value in state["variables"].items():
            current = getattr(model, name)
            if not isinstance(current, torch.Tensor) or current.shape != value.shape:
                raise ValueError(f"variable {name} does not fit")
            with torch.no_grad():
                current.copy_(value)
    except (ValueError, RuntimeError, KeyError, AttributeError, TypeError) as error:
        raise InputFileError(f"{where} does not fit this run's model ({str(error).splitlines()[0][:120]})") from None
    for name, value in meta["counters"].items():
        if name in COUNTERS and isinstance(value, int):
            setattr(model, name, value)


# ---------------------------------------------------------------------- replay buffers
def _write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    atomic_write(path, lambda handle: np.savez(handle, **arrays))


def save_replay(buffer: Any, folder: Path) -> None:
    """``replay.npz`` (the stored transitions) and ``replay.json`` (counters, random state)."""
    from stable_baselines3 import HerReplayBuffer

    from binpick.rl.common.replay import EpisodeReplayBuffer

    if isinstance(buffer, EpisodeReplayBuffer):
        arrays, counters = buffer.state_arrays()
        kind = "episode"
    elif isinstance(buffer, HerReplayBuffer):
        used = buffer.buffer_size if buffer.full else buffer.pos
        arrays = {f"observations.{k}": v[:used] for k, v in buffer.observations.items()}
        arrays |= {f"next_observations.{k}": v[:used] for k, v in buffer.next_observations.items()}
        arrays |= {name: getattr(buffer, name)[:used] for name in ("actions", "rewards", "dones", "timeouts",
                                                                    "ep_start", "ep_length")}
        arrays["_current_ep_start"] = buffer._current_ep_start
        counters = {"pos": int(buffer.pos), "full": bool(buffer.full), "buffer_size": int(buffer.buffer_size)}
        kind = "her"
    else:
        raise TypeError(f"cannot save a {type(buffer).__name__}")
    _write_npz(folder / "replay.npz", arrays)
    atomic_write_json(folder / "replay.json", {"format": REPLAY_FORMAT, "kind": kind, "counters": counters})


def load_replay(buffer: Any, folder: Path) -> None:
    """Refill ``buffer`` (built from the run's config) from :func:`save_replay`'s files."""
    from stable_baselines3 import HerReplayBuffer

    from binpick.rl.common.replay import EpisodeReplayBuffer

    where = f"replay state {str(folder / 'replay.json')!r}"
    info = read_json_object(folder / "replay.json", "replay state", {"format": str, "kind": str, "counters": dict})
    if info["format"] != REPLAY_FORMAT:
        raise InputFileError(f"{where} is a {info['format']!r} file, expected {REPLAY_FORMAT!r}")
    arrays = read_npz(folder / "replay.npz", "replay buffer")
    try:
        if isinstance(buffer, EpisodeReplayBuffer) and info["kind"] == "episode":
            buffer.load_state_arrays(arrays, info["counters"])
        elif isinstance(buffer, HerReplayBuffer) and info["kind"] == "her":
            _load_her(buffer, arrays, info["counters"])
        else:
            raise ValueError(f"it holds a {info['kind']} buffer, this run uses {type(buffer).__name__}")
    except (KeyError, ValueError, TypeError, IndexError) as error:
        raise InputFileError(f"{where} does not fit this run's replay buffer ({error})") from None


def _load_her(buffer: Any, arrays: dict[str, np.ndarray], counters: dict[str, Any]) -> None:
    if counters["buffer_size"] != buffer.buffer_size:
        raise ValueError(f"capacity {counters['buffer_size']} != {buffer.buffer_size}")
    used = buffer.buffer_size if counters["full"] else int(counters["pos"])
    for key in buffer.observations:
        buffer.observations[key][:used] = arrays[f"observations.{key}"]
        buffer.next_observations[key][:used] = arrays[f"next_observations.{key}"]
    for name in ("actions", "rewards", "dones", "timeouts", "ep_start", "ep_length"):
        getattr(buffer, name)[:used] = arrays[name]
    buffer._current_ep_start[:] = arrays["_current_ep_start"]
    buffer.pos, buffer.full = int(counters["pos"]), bool(counters["full"])
    with warnings.catch_warnings():  # the resumed env starts a new episode: close the one in progress
        warnings.simplefilter("ignore")
        buffer.truncate_last_trajectory()


# ---------------------------------------------------------------------- deployable policies
_POLICY_KWARGS = {"net_arch": (list, dict), "n_critics": int, "share_features_extractor": bool, "normalize_images": bool,
                  "use_sde": bool}


def _policy_classes() -> dict[tuple[str, str], type[BasePolicy]]:
    """The only networks a policy file may ask for: no class is ever named by the file itself."""
    from stable_baselines3.dqn import policies as dqn
    from stable_baselines3.sac import policies as sac

    return {("sac", "MlpPolicy"): sac.MlpPolicy, ("sac", "MultiInputPolicy"): sac.MultiInputPolicy,
            ("sac", "CnnPolicy"): sac.CnnPolicy, ("dqn", "MlpPolicy"): dqn.MlpPolicy,
            ("dqn", "CnnPolicy"): dqn.CnnPolicy, ("dqn", "MultiInputPolicy"): dqn.MultiInputPolicy}


def _policy_family(model: BaseAlgorithm) -> tuple[str, str]:
    from stable_baselines3 import DQN, SAC

    family = "sac" if isinstance(model, SAC) else "dqn" if isinstance(model, DQN) else None
    for (kind, name), cls in _policy_classes().items():
        if kind == family and type(model.policy) is cls:
            return kind, name
    raise TypeError(f"cannot save a {type(model).__name__} policy of type {type(model.policy).__name__}")


@dataclass
class SavedPolicy(Policy):
    """A deployed policy rebuilt from ``policy.safetensors``: SB3's ``predict`` without the algorithm."""

    policy: BasePolicy
    algorithm: str
    meta: dict[str, Any]
    log_ent_coef: torch.Tensor | None = None

    @property
    def observation_space(self):
        return self.policy.observation_space

    @property
    def action_space(self):
        return self.policy.action_space

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = False):
        return self.policy.predict(observation, state, episode_start, deterministic)


def save_policy(model: BaseAlgorithm, path: Path, **meta: Any) -> None:
    """The policy network of ``model`` and what rebuilds it (spaces, architecture) as JSON ``meta``."""
    family, name = _policy_family(model)
    kwargs = {key: value for key, value in model.policy_kwargs.items() if key in _POLICY_KWARGS}
    json.dumps(kwargs)  # only data may go into the file
    tensors = {f"policy.{key}": value for key, value in model.policy.state_dict().items()}
    if getattr(model, "log_ent_coef", None) is not None:
        tensors["log_ent_coef"] = model.log_ent_coef.detach()
    description = {"family": family, "policy": name, "policy_kwargs": kwargs,
                   "observation_space": describe_space(model.policy.observation_space),
                   "action_space": describe_space(model.policy.action_space), **meta}
    tensorfile.save(path, POLICY_FORMAT, tensors=tensors, meta=description)


def load_saved_policy(path: Path) -> SavedPolicy:
    """A policy saved by :func:`save_policy`, rebuilt from its JSON description (never unpickled)."""
    path = Path(path)
    tensors, meta, _ = tensorfile.load(path, POLICY_FORMAT, "policy")
    where = f"policy {str(path)!r}"
    require_fields(meta, {"family": str, "policy": str, "policy_kwargs": dict, "observation_space": dict,
                          "action_space": dict}, where)
    cls = _policy_classes().get((meta["family"], meta["policy"]))
    if cls is None:
        raise InputFileError(f"{where} asks for an unknown network {meta['family']}/{meta['policy']}")
    kwargs = {}
    for key, value in meta["policy_kwargs"].items():
        if key not in _POLICY_KWARGS or not isinstance(value, _POLICY_KWARGS[key]):
            raise InputFileError(f"{where} has an unsupported network setting {key}={value!r}")
        kwargs[key] = value
    observation_space = build_space(meta["observation_space"], f"{where} observation_space")
    action_space = build_space(meta["action_space"], f"{where} action_space")
    weights = {key[len("policy."):]: value for key, value in tensors.items() if key.startswith("policy.")}
    try:
        policy = cls(observation_space, action_space, lambda _: 0.0, **kwargs)
        policy.load_state_dict(weights)
    except (ValueError, RuntimeError, TypeError, AssertionError, KeyError) as error:
        raise InputFileError(f"{where} does not describe a network its weights fit "
                             f"({str(error).splitlines()[0][:120]})") from None
    policy.set_training_mode(False)
    return SavedPolicy(policy, meta["family"], meta, tensors.get("log_ent_coef"))

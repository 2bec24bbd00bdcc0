"""A deployed APRiL policy: load it with one call, feed it a camera image, get an action, as every
trained policy of binpick (:class:`binpick.Policy`)::

    policy = Policy.load("runs/april_fetchreach/20261122-050000")
    action, _ = policy.predict(image, deterministic=True)   # image: (H, W, C) uint8, as the env's camera gives it
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from binpick.core.errors import ConfigError
from binpick.core.policy import Policy


class AprilPolicy(Policy):
    """Perception encoder + policy, as one object (thesis Fig 4.2, blue arrows)."""

    def __init__(self, run_dir: Path) -> None:
        from binpick.april.perception import load_perception, perception_path
        from binpick.april.run_folder import AprilRunFolder

        run = AprilRunFolder.resume(run_dir)
        if "policy" not in run.stages or not perception_path(run.run_dir).is_file():
            raise ConfigError(f"APRiL run {run.run_dir} has no trained policy yet (finished stages: "
                              f"{', '.join(run.stages) or 'none'})")
        self.run, self.mode = run, run.config.policy.mode
        self.perception = load_perception(perception_path(run.run_dir))
        self.min_action_scale = run.rl_settings.min_action_scale
        if self.mode == "semantic":
            from binpick.rl.policy import load_policy

            self.model, _ = load_policy(Path(run.stages["policy"]["semantic_run"]))
            spaces = self.model.observation_space
            state_dim = spaces["observation"].shape[0] + spaces["desired_goal"].shape[0]
            if self.perception.config.latent != state_dim:
                raise ConfigError(f"perception latent n={self.perception.config.latent} does not match the policy's "
                                  f"semantic state of {state_dim}")
        else:
            from binpick.april.evaluate import load_latent_policy

            self.model = load_latent_policy(run.run_dir)
            needed = self.model.observation_space.shape[0]
            state_dim = self.perception.state_dim if self.mode == "state_plus_latent" else 0
            free = self.perception.config.free if self.mode == "state_plus_latent" else self.perception.config.latent
            if needed != state_dim + free:
                raise ConfigError(f"perception gives {state_dim + free} features, the policy in {run.run_dir} "
                                  f"takes {needed}")
        self.image_shape = self.perception.image_shape

    @property
    def observation_space(self):
        """What it reads: camera images."""
        from gymnasium import spaces

        return spaces.Box(0, 255, self.image_shape, np.uint8)

    @property
    def action_space(self):
        return self.model.action_space

    def encode(self, image: np.ndarray) -> np.ndarray:
        """φ_enc(I) for one image (the conditioned part in the semantic state's units)."""
        image = np.asarray(image)
        if image.dtype != np.uint8:
            raise ConfigError(f"image must be uint8 (H, W, C) with values 0-255, got dtype {image.dtype}")
        return self.perception.encode(image)[0]

    def predict(self, image: np.ndarray, state=None, episode_start=None, deterministic: bool = False, *,
                semantic_state: np.ndarray | None = None) -> tuple[np.ndarray, None]:
        """``(action, None)`` for a camera image (SB3's shape: ``state`` is a recurrent policy's memory, which
        this one has none of); ``semantic_state`` (s̄) only for the ground-truth-plus-latent baseline."""
        from binpick.april.observations import semantic_observation

        latent = self.encode(image)
        if self.mode == "semantic":
            observation = semantic_observation(latent, self.model.observation_space["achieved_goal"].shape[0])
        elif self.mode == "state_plus_latent":
            if semantic_state is None:
                raise ConfigError("this policy also needs the ground-truth semantic state: predict(image, semantic_state=...)")
            observation = np.concatenate([np.asarray(semantic_state, np.float32), latent[self.perception.config.conditioned:]])
        else:
            observation = latent.astype(np.float32)
        action, _ = self.model.predict(observation, deterministic=deterministic)
        return self._scaled(np.asarray(action)), None

    def _scaled(self, action: np.ndarray) -> np.ndarray:
        from binpick.rl.common.wrappers import scale_up_small_action

        if not self.min_action_scale:
            return action
        return scale_up_small_action(action, self.model.action_space.high, self.min_action_scale)


def load_april_policy(run_dir: Path, env_id: str | None = None) -> AprilPolicy:
    """An APRiL run's deployed policy, for :meth:`binpick.core.policy.Policy.load`; ``env_id``: refuse a run
    of another env."""
    policy = AprilPolicy(Path(run_dir))
    if env_id is not None:
        from binpick.envs import resolve_env_id

        if resolve_env_id(env_id) != resolve_env_id(policy.run.config.env):
            raise ConfigError(f"APRiL run {run_dir} was trained on {policy.run.config.env}, not {resolve_env_id(env_id)}")
    return policy

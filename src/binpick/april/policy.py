"""A deployed APRiL policy: load it with one call, feed it a camera image, get an action.

    policy = Policy.load("runs/april_fetchreach/20261122-050000")
    action = policy.predict(image)        # image: (H, W, C) uint8, as the env's camera gives it
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from binpick.core.errors import ConfigError


class Policy:
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
            from binpick.rl.train import load_policy

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

    @classmethod
    def load(cls, run_dir: str | Path) -> Policy:
        return cls(Path(run_dir))

    def encode(self, image: np.ndarray) -> np.ndarray:
        """φ_enc(I) for one image (the conditioned part in the semantic state's units)."""
        image = np.asarray(image)
        if image.dtype != np.uint8:
            raise ConfigError(f"image must be uint8 (H, W, C) with values 0-255, got dtype {image.dtype}")
        return self.perception.encode(image)[0]

    def predict(self, image: np.ndarray, state: np.ndarray | None = None) -> np.ndarray:
        """The action for a camera image; ``state`` (s̄) only for the ground-truth-plus-latent baseline."""
        from binpick.april.observations import semantic_observation

        latent = self.encode(image)
        if self.mode == "semantic":
            observation = semantic_observation(latent, self.model.observation_space["achieved_goal"].shape[0])
        elif self.mode == "state_plus_latent":
            if state is None:
                raise ConfigError("this policy also needs the ground-truth semantic state: predict(image, state=...)")
            observation = np.concatenate([np.asarray(state, np.float32), latent[self.perception.config.conditioned:]])
        else:
            observation = latent.astype(np.float32)
        action, _ = self.model.predict(observation, deterministic=True)
        return self._scaled(np.asarray(action))

    def _scaled(self, action: np.ndarray) -> np.ndarray:
        from binpick.rl.common.wrappers import scale_up_small_action

        if not self.min_action_scale:
            return action
        return scale_up_small_action(action, self.model.action_space.high, self.min_action_scale)

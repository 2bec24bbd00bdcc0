"""An APRiL run folder and what its stages read from it: the config it was started with, the RL config
it carries, the finished stages (``stages.json``), the env it is about, the state the policy sees.

:class:`binpick.april.pipeline.AprilRun` runs the stages on it; evaluation, fine-tuning and the
deployed :class:`binpick.april.policy.Policy` read it without knowing the pipeline.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from binpick.april.config import AprilConfig
from binpick.core.config import from_dict, load_run_config, load_yaml, to_dict
from binpick.core.errors import ConfigError, InputFileError
from binpick.core.files import atomic_write_json, atomic_write_text, read_json_object
from binpick.core.runs import new_run

STAGES = ("collect", "perception", "policy", "refine", "finetune", "evaluate")
CAMERA_KWARGS = ("views", "image", "image_size")  # how the world is seen, not what it is
RL_CONFIG_FILE = "rl_config.yaml"  # the state policy's RL config, carried in the run folder


class AprilRunFolder:
    """A run folder holding ``config.yaml``, ``rl_config.yaml``, ``stages.json`` and every stage's outputs."""

    TASK = "april"  # its kind of job (binpick.core.jobs)

    def __init__(self, config: AprilConfig, run_dir: Path) -> None:
        self.config, self.run_dir = config, Path(run_dir)
        self.stages_path = self.run_dir / "stages.json"
        self.stages: dict[str, Any] = read_json_object(self.stages_path, "APRiL stages file") if self.stages_path.exists() else {}
        unknown = [stage for stage in self.stages if stage not in STAGES]
        if unknown or not all(isinstance(result, dict) for result in self.stages.values()):
            raise InputFileError(f"APRiL stages file {str(self.stages_path)!r} is damaged "
                                 f"({'unknown stage ' + repr(unknown[0]) if unknown else 'a stage result is not a mapping'}): "
                                 "delete it to redo every stage")

    @classmethod
    def new(cls, config: AprilConfig, runs_root: Path = Path("runs")):
        run = cls(config, new_run(runs_root, config, cls.TASK))
        run.carry_rl_config()
        return run

    @classmethod
    def resume(cls, run_dir: Path):
        """The run in ``run_dir`` with the config it was started with; its ``policy.rl_config`` is the
        copy the folder carries, where it carries one (the file it was copied from need not exist)."""
        run_dir = Path(run_dir)
        if not (run_dir / "config.yaml").is_file():
            raise ConfigError(f"{str(run_dir)!r} is not an APRiL run folder (no config.yaml)")
        data = load_yaml(run_dir / "config.yaml")
        data.pop("task", None)
        carried = run_dir / RL_CONFIG_FILE
        if carried.is_file() and isinstance(data.get("policy"), dict):
            data["policy"]["rl_config"] = str(carried)
        return cls(from_dict(AprilConfig, data, where=str(run_dir / "config.yaml")), run_dir)

    @property
    def gripper(self) -> bool:
        """Pick and place: s̄ also holds the gripper position (thesis Table 4.5: m = 9)."""
        from binpick.rl.common.wrappers import needs_gripper

        return needs_gripper(self.config.env)

    @cached_property  # read in every collection step: the RL config is loaded once
    def opening(self) -> bool:
        """s̄ also holds the fingers' opening: the state policy's RL config says ``gripper_opening``."""
        if self.config.policy.mode == "latent" and not self.config.policy.pretrain:
            return False  # no state policy (a scripted teacher or none): s̄ as the env defines it
        return self.state_policy_settings().gripper_opening

    @cached_property
    def rl_settings(self):
        """The RL config of ``policy.rl_config``: a resumed run's is the copy its folder carries
        (``rl_config.yaml``, see :meth:`resume`), so a deployed run reads no file of the repository."""
        from binpick.rl.config import RLConfig
        from binpick.core.config import load_config

        return load_config(RLConfig, self.config.policy.rl_config)

    def carry_rl_config(self) -> None:
        """Copy ``policy.rl_config`` (validated) into the run folder, where it exists."""
        from binpick.rl.config import RLConfig
        from binpick.core.config import load_config

        if Path(self.config.policy.rl_config).is_file():
            settings = load_config(RLConfig, self.config.policy.rl_config)
            atomic_write_text(self.run_dir / RL_CONFIG_FILE, yaml.safe_dump(to_dict(settings), sort_keys=False))

    def state_policy_settings(self):
        """The state policy's RL config: that of ``policy.state_run`` if one is shared, else :attr:`rl_settings`."""
        from binpick.rl.config import RLConfig

        if self.config.policy.state_run is not None:
            return load_run_config(RLConfig, Path(self.config.policy.state_run))
        return self.rl_settings

    @property
    def teacher_privileged(self) -> list[str]:
        """What the state policy reads beside s̄ (its RL config's ``privileged_state``): simulator
        state a camera-driven policy never gets, only a teacher for ``finetune: distill``."""
        if self.config.policy.teacher == "detour":
            return ["obstacle_position"]
        return list(self.state_policy_settings().privileged_state)

    def _done(self, stage: str, result: dict[str, Any]) -> None:
        self.stages[stage] = result
        atomic_write_json(self.stages_path, self.stages)

    def make_env(self, image: bool = True):
        from binpick.envs import make

        kwargs = dict(self.config.env_kwargs)
        if image:
            kwargs.update(image=self.config.image, image_size=self.config.image_size)
        return make(self.config.env, **kwargs)

    def check_state_policy_config(self):
        """The state policy's RL config against this run, before any stage spends minutes: same env and
        world (env_kwargs but the camera's), and privileged state only where a student distils it."""
        settings = self.state_policy_settings()
        if settings.env != self.config.env:
            raise ConfigError(f"the state policy trains on {settings.env}, this APRiL run is on {self.config.env}")
        world = {key: value for key, value in self.config.env_kwargs.items() if key not in CAMERA_KWARGS}
        if world != settings.env_kwargs:
            raise ConfigError(f"the state policy trains on env_kwargs {settings.env_kwargs}, this APRiL run's world is "
                              f"{world}: the state policy must learn the world it is deployed in")
        policy = self.config.policy  # (refine.act_on: pixels needs mode semantic: the config refuses it)
        if settings.privileged_state and (policy.mode != "latent" or policy.finetune != "distill"):
            raise ConfigError(f"the state policy reads privileged_state {settings.privileged_state}, which "
                              "pixels never give: it can only teach (policy.mode: latent, finetune: distill)")
        return settings

    @property
    def sim_episodes(self) -> dict[str, int]:
        """Simulator episodes by use: images for perception, the state policy, the latent policy."""
        return {"images": self.stages["collect"]["sim_episodes"] + self.stages.get("refine", {}).get("sim_episodes", 0),
                "state_policy": self.stages["policy"]["sim_episodes"] - self.stages["policy"].get("finetune", {}).get("sim_episodes", 0),
                "latent_policy": self.stages.get("finetune", {}).get("sim_episodes", 0)}

    def goal_in_views(self, states: np.ndarray) -> np.ndarray | None:
        """Where s̄'s goal (its last dimensions) lies in each camera view, for ``perception.goal_keypoints``
        (None without them): the cameras' poses are known in the simulator, so no collection stores it."""
        if not self.config.perception.goal_keypoints:
            return None
        env = self.make_env()
        try:
            goal_dim = env.observation_space["desired_goal"].shape[0]
            return env.unwrapped.in_views(np.asarray(states)[:, -goal_dim:])
        finally:
            env.close()

"""A stand-in for moving an APRiL policy to a physical robot (thesis §6.2, Fig 6.6, Table 6.1).

There is no robot here, so a second rendering domain plays the physical camera: other lighting,
a colour cast on every surface, a camera pose that is off by a few degrees and centimetres (and
jitters per episode), and sensor noise. Physics is unchanged — as in the thesis, control transfers
without retraining and only perception has to learn the new images.

``transfer(run)`` evaluates, in that domain, the run's state policy (ground-truth s̄) and its
pixel policy before and after retraining perception on at most 25 episodes recorded there (the
arm moving at random, the true s̄ logged beside each image, as a physical robot's joint readings
and known goal would give).
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from binpick.core.files import atomic_write_json, read_json_object
from binpick.core.runs import SILENT, RunCallback


class ShiftedDomain(gym.Wrapper):
    """The "physical" camera: same simulator, other images."""

    def __init__(self, env: gym.Env, seed: int = 0, cast=(1.08, 0.92, 0.78), light: float = 0.65,
                 pose_offset=(8.0, -5.0, 0.05), jitter=(2.0, 1.5, 0.02), noise: float = 6.0) -> None:
        super().__init__(env)
        base = env.unwrapped
        camera = getattr(base, "_camera", None)
        if camera is None:
            raise ValueError("the shifted domain changes camera images: make the env with image=...")
        self.rng = np.random.default_rng(seed)
        model = base.model
        model.geom_rgba[:, :3] = np.clip(model.geom_rgba[:, :3] * cast, 0, 1)  # paint and lighting differ
        model.mat_rgba[:, :3] = np.clip(model.mat_rgba[:, :3] * cast, 0, 1)
        model.light_diffuse[:] *= light
        self.view = camera._camera  # the MjvCamera behind the image observations
        self.nominal = (self.view.azimuth + pose_offset[0], self.view.elevation + pose_offset[1], self.view.distance + pose_offset[2])
        self.jitter, self.noise = jitter, noise

    def _image(self, observation: dict) -> dict:
        image = observation["image"].astype(np.float32)
        image += self.rng.normal(0, self.noise, image.shape)
        observation["image"] = np.clip(image, 0, 255).astype(np.uint8)
        return observation

    def reset(self, **kwargs):
        azimuth, elevation, distance = self.nominal
        self.view.azimuth = azimuth + self.rng.uniform(-1, 1) * self.jitter[0]
        self.view.elevation = elevation + self.rng.uniform(-1, 1) * self.jitter[1]
        self.view.distance = distance + self.rng.uniform(-1, 1) * self.jitter[2]
        observation, info = self.env.reset(**kwargs)
        return self._image(observation), info

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self._image(observation), reward, terminated, truncated, info


def _row(result, **counts) -> dict[str, Any]:
    return {"avg_actions": round(result.mean_length, 2), "std": round(result.std_length, 2),
            "success": round(result.success_rate, 3), **counts}


def transfer(run_dir: Path, out: Path, real_episodes: int = 25, eval_episodes: int = 100, epochs: int = 20,
             seed: int = 0, callback: RunCallback = SILENT) -> dict[str, Any]:
    """Table 6.1 for one APRiL run (a semantic-mode run: state policy + perception). The run is
    copied to ``out`` first; the original is never changed."""
    from binpick.april.evaluate import deployment_env
    from binpick.april.observations import semantic_state
    from binpick.april.run_folder import AprilRunFolder
    from binpick.april.perception import PERCEPTION_FILE, load_perception, perception_path, save_perception, train_perception
    from binpick.rl.common.evaluate import evaluate_policy

    out = Path(out)
    if not out.exists():
        shutil.copytree(run_dir, out, ignore=shutil.ignore_patterns("rl"))
    run = AprilRunFolder.resume(out)
    sim_rows = read_json_object(Path(run_dir) / "results.json", "APRiL results")
    rl_metrics = read_json_object(Path(run.stages["policy"]["semantic_run"]) / "metrics.json", "state policy metrics",
                                  {"sim_episodes": int})
    counts = {"simulator_episodes": rl_metrics["sim_episodes"], "gp_episodes": rl_metrics.get("imagined_episodes", 0)}
    image_episodes = run.sim_episodes["images"]
    pixel_name = next(k for k in sim_rows if k != "ground_truth")
    rows = {"simulated_ground_truth": {**sim_rows["ground_truth"], **counts, "physical_episodes": 0},
            "simulated_encoded": {**sim_rows[pixel_name], **counts, "perception_sim_episodes": image_episodes, "physical_episodes": 0}}
    original_make_env = run.make_env
    run.make_env = lambda image=True: ShiftedDomain(original_make_env(image=True), seed) if image else original_make_env(image=False)

    def evaluate(runtime_input: str):
        env, policy, _ = deployment_env(run, runtime_input)
        try:
            return evaluate_policy(policy, env, episodes=eval_episodes, seed=20_000)
        finally:
            env.close()

    started = time.perf_counter()
    rows["shifted_ground_truth"] = _row(evaluate("state"), **counts, physical_episodes=0)
    rows["shifted_encoded_before_retraining"] = _row(evaluate("pixels"), **counts, perception_sim_episodes=image_episodes,
                                                     physical_episodes=0)
    # "physical" episodes: random actions for the whole episode, as the sim images were collected
    # (the state policy would reach the goal in ~3 steps: too few images); true s̄ logged per image
    env = run.make_env()
    env.action_space.seed(seed + 3)
    images, states = [], []
    for episode in range(real_episodes):
        raw, _ = env.reset(seed=30_000 + episode)
        done = False
        while not done:
            images.append(raw["image"])
            states.append(semantic_state(raw, run.gripper, run.opening))
            raw, _, terminated, truncated, _ = env.step(env.action_space.sample())
            done = terminated or truncated
        images.append(raw["image"])
        states.append(semantic_state(raw, run.gripper, run.opening))
    env.close()
    training = run.config.perception_training
    model, history = train_perception(run.config.perception, np.stack(images), np.stack(states), epochs=epochs,
                                      batch_size=training.batch_size, learning_rate=training.learning_rate, seed=seed,
                                      callback=callback, initial=load_perception(perception_path(out)))
    save_perception(model, out / PERCEPTION_FILE)
    rows["shifted_encoded_retrained"] = _row(evaluate("pixels"), **counts, perception_sim_episodes=image_episodes,
                                             physical_episodes=real_episodes, physical_images=len(images))
    result = {"run": str(run_dir), "env": run.config.env, "domain": "ShiftedDomain (colour cast, dimmer light, camera "
              "off by 8°/-5°/5 cm with per-episode jitter, pixel noise σ = 6)", "eval_episodes": eval_episodes,
              "retraining_epochs": epochs, "retraining_state_mae": history["epochs"][-1]["state_mae"],
              "rows": rows, "wall_s": round(time.perf_counter() - started, 1)}
    atomic_write_json(out / "sim_to_real.json", result)
    return result

"""The APRiL pipeline (thesis §4.2, Fig 4.2), one resumable stage at a time.

    collect     random-policy (or heuristic) episodes: images and the semantic state s̄ (data/random.npz)
    perception  the AE / VAE trained on them (perception.safetensors, reconstructions.png)
    policy      the state policy: on s̄ with GP + HER (an ordinary binpick RL run under rl/)
    refine      optional: perception trained further on the state policy's episodes (data/policy.npz)
    finetune    latent modes: SAC on φ_enc(I) in the simulator, widened from the state policy
                (policy_latent.safetensors)
    evaluate    average actions, success and simulator episodes per row; Fig 4.7 heat maps

Each finished stage is recorded in ``stages.json`` (replaced atomically); after a crash ``run``
skips the finished stages and redoes the interrupted one (the RL run inside ``policy`` resumes
from its own latest checkpoint).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from binpick.april.observations import semantic_observation, semantic_state
from binpick.april.run_folder import CAMERA_KWARGS, STAGES, AprilRunFolder
from binpick.core.errors import ConfigError
from binpick.core.files import atomic_write, atomic_write_json, read_json_object, read_npz
from binpick.core.runs import SILENT, RunCallback

__all__ = ["AprilRun", "CAMERA_KWARGS", "STAGES"]


class AprilRun(AprilRunFolder):
    """The pipeline on a run folder: ``run`` does every stage not yet finished, in order."""

    # ------------------------------------------------------------------ the whole pipeline
    def run(self, callback: RunCallback = SILENT) -> dict[str, Any]:
        if self.config.policy.mode != "latent" or self.config.policy.pretrain:
            self.check_state_policy_config()
        for stage in STAGES:
            if stage in self.stages:
                continue
            callback.message(f"APRiL stage {stage} ({self.run_dir})")
            started = time.perf_counter()
            result = getattr(self, f"stage_{stage}")(callback)
            self._done(stage, result | {"wall_seconds": round(time.perf_counter() - started, 1)})
        return self.stages["evaluate"]

    # ------------------------------------------------------------------ stages
    def stage_collect(self, callback: RunCallback) -> dict[str, Any]:
        """Random-policy (or heuristic) episodes; every observation's image and s̄ (the reset one included)."""
        collect = self.config.collect
        env = self.make_env()
        env.action_space.seed(collect.seed)
        if collect.policy == "heuristic":
            from binpick.rl.common.heuristic import PickAndPlaceHeuristic

            heuristic = PickAndPlaceHeuristic(noise=collect.noise, seed=collect.seed)
            act = lambda: heuristic(env.unwrapped._get_obs())  # noqa: E731
        else:
            act = env.action_space.sample
        images, states, steps = [], [], 0
        with callback.task("collect", collect.episodes) as task:
            task.update(status=f"{collect.policy} policy")
            for episode in range(collect.episodes):
                observation, _ = env.reset(seed=collect.seed + episode)
                images.append(observation["image"])
                states.append(semantic_state(observation, self.gripper, self.opening))
                done = False
                while not done:
                    if collect.goal_every and steps % collect.goal_every == 0:  # a new goal, drawn only
                        env.unwrapped.goal = env.unwrapped._sample_goal()
                    observation, _, terminated, truncated, _ = env.step(act())
                    images.append(observation["image"])
                    states.append(semantic_state(observation, self.gripper, self.opening))
                    steps += 1
                    done = terminated or truncated
                task.update(advance=1, status=f"{len(images):,} images")
        env.close()
        path = self.run_dir / "data" / "random.npz"
        path.parent.mkdir(exist_ok=True)
        atomic_write(path, lambda handle: np.savez(handle, images=np.stack(images), states=np.stack(states)))
        return {"sim_episodes": collect.episodes, "sim_steps": steps, "images": len(images), "policy": collect.policy}

    def stage_perception(self, callback: RunCallback) -> dict[str, Any]:
        from binpick.april.perception import PERCEPTION_FILE, save_perception, train_perception
        from binpick.viz.april import plot_reconstructions

        data = read_npz(self.run_dir / "data" / "random.npz", "APRiL image data")
        images, states = data["images"], data["states"]
        training = self.config.perception_training
        model, history = train_perception(self.config.perception, images, states, epochs=training.epochs,
                                          batch_size=training.batch_size, learning_rate=training.learning_rate,
                                          schedule=training.schedule, seed=self.config.seed, callback=callback,
                                          points=self.goal_in_views(states))
        save_perception(model, self.run_dir / PERCEPTION_FILE)
        atomic_write_json(self.run_dir / "perception_history.json", history)
        rng = np.random.default_rng(self.config.seed)
        sample = images[rng.choice(len(images), size=min(8, len(images)), replace=False)]
        plot_reconstructions(sample, model.reconstruct(sample), self.run_dir / "reconstructions.png",
                             title=f"{self.config.name}: input (top) / reconstruction (bottom)")
        last = history["epochs"][-1]
        return {"recon": last["recon"], "state_mae": last["state_mae"], "epochs": len(history["epochs"])}

    def stage_policy(self, callback: RunCallback) -> dict[str, Any]:
        policy = self.config.policy
        if policy.mode != "latent" or policy.pretrain:
            return self._semantic_policy(callback)
        return {"sim_episodes": 0, "sim_steps": 0}

    def stage_finetune(self, callback: RunCallback) -> dict[str, Any]:
        if "finetune" in self.stages["policy"]:  # runs made before this was a stage of its own
            return self.stages["policy"]["finetune"]
        if self.config.policy.mode == "semantic":
            return {"sim_episodes": 0, "sim_steps": 0}
        return self._latent_policy(callback, self.stages["policy"].get("semantic_run"))

    def _semantic_policy(self, callback: RunCallback) -> dict[str, Any]:
        """Eq 4.8: the policy learns on ground-truth s̄ with the cheap tools of chapter 3 (GP + HER)."""
        from binpick.rl.train import trainer_for

        if self.config.policy.state_run is not None:  # perception variants can share one state policy
            run_dir = Path(self.config.policy.state_run)
            if not (run_dir / "metrics.json").is_file():
                raise ConfigError(f"policy.state_run: {str(run_dir)!r} is not a finished binpick rl run (no metrics.json)")
            metrics = read_json_object(run_dir / "metrics.json", "state policy metrics", {"env": str})
            if metrics["env"] != self.config.env:
                raise ConfigError(f"policy.state_run was trained on {metrics['env']}, this APRiL run is on {self.config.env}")
        else:
            settings = self.check_state_policy_config()
            root = self.run_dir / "rl"
            existing = sorted(root.glob(f"{settings.name}/*/config.yaml"))
            trainer = trainer_for(resume=existing[-1].parent) if existing else trainer_for(settings, root)
            metrics = trainer.run(callback)
            run_dir = trainer.run_dir
        return {"semantic_run": str(run_dir), "sim_episodes": int(metrics.get("sim_episodes") or 0),
                "sim_steps": int(metrics["sim_steps"]), "semantic_final_avg_actions": metrics["final_avg_actions"],
                "semantic_final_success": metrics["final_success"]}

    def _latent_policy(self, callback: RunCallback, semantic_run: str | None) -> dict[str, Any]:
        """Eq 4.9: SAC on φ_enc(I) in the simulator; first layers widened from the s̄ policy if there is one."""
        from binpick.april.finetune import finetune_latent_policy

        return finetune_latent_policy(self, semantic_run, callback)

    def stage_refine(self, callback: RunCallback) -> dict[str, Any]:
        """Episodes of the state policy (noisy actions; acting on the true s̄, or with ``act_on: pixels``
        on φ_enc(I) of the latest perception), images and true s̄ recorded, then more perception epochs
        on random + policy images; ``rounds`` times. Runs before any latent fine-tuning reads φ_enc."""
        from binpick.april.finetune import with_action_scale
        from binpick.april.perception import PERCEPTION_FILE, load_perception, perception_path, save_perception, train_perception
        from binpick.rl.policy import load_policy
        from binpick.rl.common.wrappers import privileged_values, semantic_inputs

        refine = self.config.refine
        if not refine.episodes:
            return {"sim_episodes": 0}
        privileged = self.teacher_privileged
        policy, _ = load_policy(Path(self.stages["policy"]["semantic_run"]))
        env = with_action_scale(self.make_env(), self.rl_settings.min_action_scale)
        goal_dim = env.observation_space["desired_goal"].shape[0]
        rng = np.random.default_rng(self.config.seed + 7)
        random = read_npz(self.run_dir / "data" / "random.npz", "APRiL image data")
        model = load_perception(perception_path(self.run_dir))
        images, states, rounds = [], [], []
        for round_ in range(refine.rounds):
            successes = 0
            with callback.task(f"refine round {round_ + 1}/{refine.rounds}: policy episodes on {refine.act_on}",
                               refine.episodes) as task:
                for episode in range(refine.episodes):
                    raw, _ = env.reset(seed=self.config.collect.seed + 100_000 + round_ * refine.episodes + episode)
                    done = success = False
                    while not done:
                        images.append(raw["image"])
                        states.append(semantic_state(raw, self.gripper, self.opening))
                        if refine.act_on == "pixels":
                            inputs = semantic_observation(model.encode(raw["image"])[0], goal_dim)
                        else:
                            inputs = semantic_inputs(raw, self.gripper, privileged_values(env, privileged), self.opening)
                        action = policy.predict(inputs, deterministic=True)[0]
                        action = np.clip(action + rng.normal(0, refine.action_noise, action.shape), -1, 1)
                        raw, _, terminated, truncated, info = env.step(action)
                        success = success or bool(info.get("is_success"))
                        done = terminated or truncated
                    images.append(raw["image"])
                    states.append(semantic_state(raw, self.gripper))
                    successes += int(success)
                    task.update(advance=1, status=f"{len(images):,} images · {successes}/{episode + 1} reached")
            atomic_write(self.run_dir / "data" / "policy.npz",
                         lambda handle: np.savez(handle, images=np.stack(images), states=np.stack(states)))
            training = self.config.perception_training
            every_state = np.concatenate([random["states"], np.stack(states)])
            model, history = train_perception(self.config.perception, np.concatenate([random["images"], np.stack(images)]),
                                              every_state, epochs=refine.epochs,
                                              batch_size=training.batch_size, learning_rate=training.learning_rate,
                                              schedule=training.schedule, seed=self.config.seed + 1 + round_,
                                              callback=callback, initial=model, points=self.goal_in_views(every_state))
            rounds.append({"round": round_ + 1, "success_while_collecting": successes / refine.episodes,
                           "images": len(images), "state_mae": history["epochs"][-1]["state_mae"], "history": history})
        env.close()
        save_perception(model, self.run_dir / PERCEPTION_FILE)
        atomic_write_json(self.run_dir / "refine_history.json", rounds[-1]["history"] | {"rounds": rounds})
        return {"sim_episodes": refine.episodes * refine.rounds, "images": len(images), "act_on": refine.act_on,
                "success_while_collecting": [r["success_while_collecting"] for r in rounds],
                "state_mae": rounds[-1]["state_mae"]}

    def stage_evaluate(self, callback: RunCallback) -> dict[str, Any]:
        from binpick.april.evaluate import evaluate_rows

        rows = evaluate_rows(self, callback)
        atomic_write_json(self.run_dir / "results.json", rows)
        return {"rows": rows}

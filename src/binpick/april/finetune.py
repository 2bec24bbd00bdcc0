"""Latent policies (thesis Eq 4.9): SAC on φ_enc(I), optionally widened from a policy trained on s̄.

"These networks may then be adapted to take input from the additional non-semantic encoded state by
increasing the size of the input layer and loading the learnt weights to the appropriate slice of the
first fully connected layer" (§4.4). :func:`widen_from_semantic` does exactly that for SB3's SAC:
the semantic policy reads the dict (achieved_goal = z, desired_goal = g, observation = z); the latent
policy reads the flat vector (z, g, free...). Columns for z are the sum of the two z columns, the
free features start at zero, so before fine-tuning the widened policy acts exactly as the old one.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback

from binpick.april.observations import EncodedObservation, semantic_state
from binpick.core.files import atomic_write_bytes, atomic_write_json
from binpick.rl.common.demonstrations import cloning_loss
from binpick.rl.common.persistence import SavedPolicy, save_policy
from binpick.rl.common.heuristic import ObstacleDetour
from binpick.rl.common.wrappers import MinActionScale, privileged_values, semantic_inputs
from binpick.core.runs import SILENT, RunCallback, Task

LATENT_POLICY_FILE = "policy_latent.safetensors"  # SAC on φ_enc(I): weights + spaces, no pickle
PRETRAINED_PERCEPTION_FILE = "perception_pretrained.safetensors"  # distill_encoder: the encoder before it


def with_action_scale(env, scale: float | None):
    """The semantic run's minimum action scale (thesis: 0.4 for Fetch) applies at deployment too."""
    return MinActionScale(env, scale) if scale else env

if TYPE_CHECKING:
    from binpick.april.run_folder import AprilRunFolder


def _semantic_columns(model: SavedPolicy, goal_dim: int) -> list[np.ndarray]:
    """For each feature column of the dict policy, the index in s̄ = (observation, g) it carries."""
    width = model.observation_space["observation"].shape[0]
    sources = {"observation": 0, "achieved_goal": width - goal_dim, "desired_goal": width}
    columns = []
    for key, space in model.observation_space.spaces.items():
        if key not in sources:
            raise ValueError(f"cannot widen a policy that reads {key!r}")
        columns.append(sources[key] + np.arange(space.shape[0]))
    return columns


def _widen_linear(old: torch.nn.Linear, new: torch.nn.Linear, columns: list[np.ndarray], tail: int) -> None:
    """Copy ``old`` into ``new``: old feature columns summed into their (z, g) slot; ``tail`` trailing
    columns (the action, for critics) copied to the end; the free-feature columns are zero."""
    with torch.no_grad():
        new.weight.zero_()
        new.bias.copy_(old.bias)
        offset = 0
        for index in columns:
            block = old.weight[:, offset:offset + len(index)]
            new.weight[:, torch.as_tensor(index)] += block
            offset += len(index)
        if tail:
            new.weight[:, -tail:] = old.weight[:, -tail:]


def widen_from_semantic(semantic: SavedPolicy, latent: SAC, goal_dim: int) -> None:
    """Load a semantic-state SAC's weights into a latent SAC with a wider input (see module doc)."""
    columns = _semantic_columns(semantic, goal_dim)
    action_dim = semantic.action_space.shape[0]
    old_actor, new_actor = semantic.policy.actor, latent.policy.actor
    _widen_linear(old_actor.latent_pi[0], new_actor.latent_pi[0], columns, 0)
    for name, parameter in old_actor.state_dict().items():
        if not name.startswith("latent_pi.0."):
            new_actor.state_dict()[name].copy_(parameter)
    for old_q, new_q in zip(semantic.policy.critic.q_networks, latent.policy.critic.q_networks):
        _widen_linear(old_q[0], new_q[0], columns, action_dim)
        for name, parameter in old_q.state_dict().items():
            if not name.startswith("0."):
                new_q.state_dict()[name].copy_(parameter)
    latent.policy.critic_target.load_state_dict(latent.policy.critic.state_dict())
    if semantic.log_ent_coef is not None and getattr(latent, "log_ent_coef", None) is not None:
        with torch.no_grad():  # a learnt entropy weight carries over; a fixed one is set by the config
            latent.log_ent_coef.copy_(semantic.log_ent_coef)


class _Progress(BaseCallback):
    def __init__(self, task: Task) -> None:
        super().__init__()
        self.task, self.episodes = task, 0

    def _on_step(self) -> bool:
        self.episodes += int(np.sum(self.locals["dones"]))
        self.task.update(self.num_timesteps, status=f"{self.episodes} episodes")
        return True


def latent_sac(run: AprilRunFolder, env, rl_settings, tensorboard_log: str | None = None) -> SAC:
    """The SAC a latent policy learns with: the state policy's RL config's SAC settings, the run's seed."""
    settings = rl_settings.sac
    return SAC("MlpPolicy", env, learning_rate=settings.learning_rate, batch_size=settings.batch_size,
               gamma=settings.gamma, tau=settings.tau, learning_starts=run.config.policy.learning_starts,
               ent_coef=settings.ent_coef, policy_kwargs={"net_arch": list(settings.net_arch)}, seed=run.config.seed,
               device="cpu", tensorboard_log=tensorboard_log)


def finetune_latent_policy(run: AprilRunFolder, semantic_run: str | None, callback: RunCallback = SILENT) -> dict[str, Any]:
    """Train (or fine-tune) SAC on encoded images; saves ``policy_latent.safetensors`` in the run folder."""
    from binpick.april.perception import load_perception, perception_path
    from binpick.rl.policy import load_policy

    torch.set_num_threads(1)  # small networks, one env: a second thread only competes with other jobs
    config, policy = run.config, run.config.policy
    joint = policy.finetune == "distill" and policy.distill_encoder
    source = perception_path(run.run_dir)
    if joint:  # the encoder changes: keep the perception stage's own, and always start from it (resume)
        pretrained = run.run_dir / PRETRAINED_PERCEPTION_FILE
        if not pretrained.is_file():
            atomic_write_bytes(pretrained, source.read_bytes())
        source = pretrained
    perception = load_perception(source)
    rl_settings = run.rl_settings
    env = with_action_scale(EncodedObservation(run.make_env(), perception.encode, perception.config.latent,
                                               perception.config.conditioned, with_state=policy.mode == "state_plus_latent",
                                               gripper=run.gripper, opening=run.opening),
                            rl_settings.min_action_scale)
    model = latent_sac(run, env, rl_settings, tensorboard_log=str(run.run_dir / "tb"))
    semantic = None
    widened = False
    if semantic_run is not None:
        semantic, _ = load_policy(Path(semantic_run))
        if not run.teacher_privileged:  # a teacher's extra inputs have no slot in φ_enc(I) to widen into
            widen_from_semantic(semantic, model, env.unwrapped.observation_space["achieved_goal"].shape[0])
            widened = True
    if policy.finetune == "distill":
        teacher = ObstacleDetour(env.unwrapped.obstacle_half_size) if policy.teacher == "detour" else semantic
        result = distill_from_state_policy(model, teacher, env, run, callback, perception if joint else None)
        if joint:
            from binpick.april.perception import save_perception

            save_perception(perception.eval(), perception_path(run.run_dir))
    else:
        with callback.task("fine-tune on φ_enc(I)", policy.finetune_steps) as task:
            report = _Progress(task)
            if policy.finetune_steps:
                model.learn(policy.finetune_steps, callback=report, tb_log_name="latent")
        result = {"sim_episodes": report.episodes, "sim_steps": int(model.num_timesteps)}
    save_policy(model, run.run_dir / LATENT_POLICY_FILE, algorithm="sac", env=config.env, mode=policy.mode)
    env.close()
    return result | {"widened": widened, "finetune": policy.finetune}


def distill_from_state_policy(student: SAC, teacher: SavedPolicy | ObstacleDetour | None, env, run: AprilRunFolder,
                              callback: RunCallback = SILENT, perception=None) -> dict[str, Any]:
    """DAgger (Ross et al., 2011) from the state policy: the student acts on φ_enc(I), the teacher
    labels every visited image with its own action on the true s̄ (and any ``privileged_state`` its
    RL config reads, e.g. where the obstacle is), and the student's actor regresses
    onto all labels so far. Unlike plain SAC on φ_enc(I), which starts from a critic that knows nothing
    of images and drags a good widened policy down, this only ever moves towards what the state
    policy does, on the states the student itself reaches (the arm in front of the goal, say).
    With ``perception`` (``distill_encoder``) the encoder learns too: each update regresses the actor
    on φ_enc of the stored images and adds the encoder's own L_VP, so s̄'s features stay s̄ while the
    free ones may carry whatever the teacher's actions depend on (the box it reads, say)."""
    if teacher is None:
        raise ValueError("distillation needs the state policy (policy.pretrain: true)")
    policy, privileged = run.config.policy, run.teacher_privileged
    encoded = env
    while not isinstance(encoded, EncodedObservation):
        encoded = encoded.env
    rng = np.random.default_rng(run.config.seed + 11)
    observations: list[np.ndarray] = []
    images: list[np.ndarray] = []
    states: list[np.ndarray] = []
    encoder_optimizer = None if perception is None else torch.optim.Adam(
        perception.parameters(), lr=run.config.perception_training.learning_rate)
    labels: list[np.ndarray] = []
    history: list[dict[str, float]] = []
    steps = episodes = successes = 0
    with callback.task("distil the state policy onto φ_enc(I)", policy.finetune_steps) as task:
        while steps < policy.finetune_steps:
            observation, _ = env.reset(seed=run.config.collect.seed + 200_000 + episodes)
            done = success = False
            while not done and steps < policy.finetune_steps:
                state = semantic_inputs(encoded.last_raw, run.gripper, privileged_values(encoded, privileged), run.opening)
                label = teacher.predict(state, deterministic=True)[0]
                if perception is not None:  # the image and s̄ behind φ_enc(I), for the encoder's updates
                    images.append(encoded.last_raw["image"])
                    states.append(semantic_state(encoded.last_raw, run.gripper, run.opening))
                observations.append(np.asarray(observation, np.float32))
                labels.append(student.policy.scale_action(np.asarray(label, np.float32)))
                first_round = steps < policy.distill_every  # DAgger's β = 1 for the first round, then 0
                action = label if first_round else student.predict(observation, deterministic=True)[0]
                observation, _, terminated, truncated, info = env.step(action)
                success = success or bool(info.get("is_success"))
                done = terminated or truncated
                steps += 1
                if steps % policy.distill_every == 0 or steps == policy.finetune_steps:
                    data, targets = np.stack(observations), np.stack(labels).astype(np.float32)
                    losses = []
                    for _ in range(policy.distill_gradient_steps):
                        if perception is None:
                            batch = rng.integers(0, len(data), size=min(256, len(data)))
                            loss, _ = cloning_loss(student, data[batch], targets[batch])
                        else:
                            batch = rng.integers(0, len(data), size=min(64, len(data)))
                            loss = joint_loss(student, perception, np.stack([images[i] for i in batch]),
                                              np.stack([states[i] for i in batch]), targets[batch])
                            encoder_optimizer.zero_grad()
                        student.actor.optimizer.zero_grad()
                        loss.backward()
                        student.actor.optimizer.step()
                        if encoder_optimizer is not None:
                            encoder_optimizer.step()
                        losses.append(float(loss.detach()))
                    history.append({"sim_steps": steps, "labels": len(data), "mse_before": losses[0] if losses else None,
                                    "mse": float(np.mean(losses[-50:])) if losses else None,
                                    "episodes": episodes, "success_so_far": successes / max(1, episodes)})
                    task.update(steps, status=f"{episodes} episodes · MSE {history[-1]['mse'] or 0:.4f}")
            episodes += 1
            successes += int(success)
    atomic_write_json(run.run_dir / "distill_history.json", history)
    return {"sim_episodes": episodes, "sim_steps": steps, "labels": len(labels),
            "final_mse": history[-1]["mse"] if history else None}


def joint_loss(student: SAC, perception, images: np.ndarray, states: np.ndarray, targets: np.ndarray) -> torch.Tensor:
    """Action regression of the student on φ_enc(I) (the encoder in the graph) plus the encoder's L_VP."""
    perception.train()
    losses = perception.loss(images, states)
    mean, _, _ = student.actor.get_action_dist_params(perception.features(losses["mu"]))
    return ((torch.tanh(mean) - torch.as_tensor(targets)) ** 2).mean() + losses["total"]

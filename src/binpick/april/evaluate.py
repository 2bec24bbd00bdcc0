"""Evaluate an APRiL run: one row per runtime input (ground-truth s̄, pixels), with Fig 4.7 heat maps."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from binpick.april.observations import EncodedObservation, GoalRecorder, PixelsAsSemantic
from binpick.rl.common.evaluate import evaluate_policy
from binpick.core.runs import SILENT, RunCallback

if TYPE_CHECKING:
    from binpick.april.run_folder import AprilRunFolder


def deployment_env(run: AprilRunFolder, runtime_input: str):
    """The env and policy exactly as deployed: ``state`` (ground truth, semantic modes) or ``pixels``."""
    from binpick.april.finetune import with_action_scale
    from binpick.april.perception import load_perception, perception_path
    from binpick.rl.policy import load_policy
    from binpick.rl.common.wrappers import SemanticState

    mode = run.config.policy.mode
    scale = run.rl_settings.min_action_scale
    if runtime_input == "state":  # the state policy on the simulator's s̄ (and its privileged state, if any)
        base = GoalRecorder(run.make_env(image=False))
        if run.config.policy.teacher == "detour":
            from binpick.rl.common.heuristic import ObstacleDetour

            policy = ObstacleDetour(base.unwrapped.obstacle_half_size)
        else:
            policy, _ = load_policy(Path(run.stages["policy"]["semantic_run"]))
        return with_action_scale(SemanticState(base, run.gripper, run.teacher_privileged, run.opening), scale), policy, base
    if mode == "semantic":
        policy, _ = load_policy(Path(run.stages["policy"]["semantic_run"]))
        base = GoalRecorder(run.make_env())
        encode = load_perception(perception_path(run.run_dir)).encode
        return with_action_scale(PixelsAsSemantic(base, encode, run.gripper, run.opening), scale), policy, base
    perception = load_perception(perception_path(run.run_dir))
    base = GoalRecorder(run.make_env())
    env = EncodedObservation(base, perception.encode, perception.config.latent, perception.config.conditioned,
                             with_state=mode == "state_plus_latent", gripper=run.gripper, opening=run.opening)
    return with_action_scale(env, scale), load_latent_policy(run.run_dir), base


def load_latent_policy(run_dir: Path):
    """The SAC policy on φ_enc(I) of a latent-mode run, rebuilt from ``policy_latent.safetensors``."""
    from binpick.april.finetune import LATENT_POLICY_FILE
    from binpick.core.errors import ConfigError
    from binpick.rl.common.persistence import load_saved_policy

    path = Path(run_dir) / LATENT_POLICY_FILE
    if not path.is_file():
        older = " (older runs saved SB3 zips, which binpick no longer loads because they can run code)" \
            if (Path(run_dir) / "policy_latent.zip").is_file() else ""
        raise ConfigError(f"APRiL run {run_dir} has no {LATENT_POLICY_FILE}{older}")
    return load_saved_policy(path)


def row_names(run: AprilRunFolder) -> dict[str, str]:
    """Runtime input -> the results row name (what the row is, e.g. pixels_ae_n6_m6_w1.0)."""
    p = run.config.perception
    views = run.config.views
    refine = run.config.refine
    refined = ("_refined_on_pixels" if refine.act_on == "pixels" else "_refined") if refine.episodes else ""
    cameras = {1: "", 2: "_two_views"}.get(len(views), f"_{len(views)}_views")
    every = run.config.collect.goal_every  # perception saw a new goal every step (_goals) or every k (_goals{k})
    goals = "" if not every else "_goals" if every == 1 else f"_goals{every}"
    on_path = run.config.env_kwargs.get("obstacle_on_path")  # another world: other rows (_on_path: always, else its share)
    world = "" if not on_path else "_on_path" if on_path == 1.0 else f"_on_path{on_path:g}"
    training = run.config.perception_training  # a longer, decayed schedule: its own rows
    trained = f"_cosine{training.epochs}" if training.schedule == "cosine" else ""
    foreground = f"_fg{p.foreground_weight:g}" if p.foreground_weight else ""  # reconstruction weighted to objects
    spatial = "_kp" if p.free_features == "keypoints" else ""  # free features read as keypoints
    spatial += f"_on{p.free_keypoint_channels}ch" if p.free_keypoint_channels else ""  # ... in the first channels only
    spatial = ("_goalkp" if p.goal_keypoints else "") + spatial  # s̄'s goal read through keypoints too
    replicate = f"_seed{run.config.seed}" if run.config.seed else ""  # the same row trained from another seed
    pixels = f"pixels_{p.kind}_n{p.latent}_m{p.conditioned}_w{p.omega:g}" + spatial + foreground + goals + trained + refined \
        + cameras + world + replicate
    if run.config.policy.mode == "semantic":  # a state policy whose actor trained on noisy s̄: its own rows
        noise = run.state_policy_settings().actor_noise  # e.g. _actor_noise5mm: its largest std on a position
        largest = max(max(noise.gripper), max(noise.achieved), max(noise.goal)) * 1000
        noisy = f"_actor_noise{largest:g}mm" if noise.enabled else ""
        opening = "_opening" if run.opening else ""  # s̄ with the fingers' opening: another state policy
        return {"state": "ground_truth" + world + opening + noisy, "pixels": pixels + opening + noisy}
    if run.config.policy.mode == "state_plus_latent":
        return {"pixels": f"ground_truth_plus_latent_{p.kind}_n{p.latent}_m{p.conditioned}" + cameras + world}
    detour = run.config.policy.teacher == "detour"
    distilled = "" if run.config.policy.finetune != "distill" else "_distilled_encoder" if run.config.policy.distill_encoder \
        else "_distilled"
    steps = run.config.policy.finetune_steps  # a longer DAgger than the 10,000 steps of the first rows: its own
    longer = f"_{steps // 1000}k" if distilled and detour and steps > 10_000 else ""
    rows = {"pixels": pixels + distilled + longer + ("_from_detour" if detour else "")}
    if detour:  # the scripted teacher itself, on the box position only it may read
        rows = {"state": "detour_teacher" + world} | rows
    elif run.config.policy.pretrain and run.teacher_privileged:  # the teacher itself, on what only it may read
        rows = {"state": "ground_truth_privileged" + world} | rows
    return rows


def evaluate_rows(run: AprilRunFolder, callback: RunCallback = SILENT) -> dict[str, Any]:
    from binpick.viz.april import plot_goal_heatmap

    episodes, seed = run.config.eval.episodes, run.config.eval.seed
    used = run.sim_episodes
    rows = {}
    for runtime_input, name in row_names(run).items():
        env, policy, recorder = deployment_env(run, runtime_input)
        with callback.task(f"evaluate {name}", episodes) as task:
            result = evaluate_policy(policy, env, episodes=episodes, seed=seed, on_episode=lambda *_: task.update(advance=1))
        env.close()
        goals = np.stack(recorder.goals[:episodes])
        plot_goal_heatmap(goals, np.asarray(result.lengths), run.run_dir / f"heatmap_{name}.png",
                          title=f"{run.config.name}: {name}")
        # simulator episodes the row needed: the state row never used the image episodes
        needed = used["state_policy"] + (0 if runtime_input == "state" else used["images"] + used["latent_policy"])
        rows[name] = {"avg_actions": result.mean_length, "std": result.std_length, "success": result.success_rate,
                      "sim_episodes": int(needed), "episodes": episodes}
    return rows

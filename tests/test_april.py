"""APRiL (thesis ch. 4): widening a state policy for extra latent features, the whole pipeline on a
tiny config, resuming it, the deployed Policy object and bad input."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import binpick_here
from gymnasium import spaces
from stable_baselines3 import SAC

from binpick.april.finetune import widen_from_semantic
from binpick.envs import make
from binpick.core.errors import ConfigError
from binpick.core.files import read_npz
from binpick.core.runs import SILENT
from binpick.rl.common.wrappers import SemanticState


RL = """
name: tiny_rl
env: FetchReach
algorithm: sac
min_action_scale: 0.4
total_timesteps: 200
checkpoint_every: 100
replay: {capacity_episodes: 200, her_additions: 1}
gp: {enabled: true, warmup_episodes: 2, refit_every: 100, imagined_per_real: 1, batch_episodes: 10, iterations: 3, max_points: 60}
sac: {batch_size: 16, net_arch: [8, 8]}
eval: {every: 100, episodes: 1}
"""

APRIL = """
name: tiny_april
env: FetchReach
image: grey
collect: {{episodes: 2}}
perception: {{kind: {kind}, latent: {n}, conditioned: {m}, omega: 1.0, channels: 4}}
perception_training: {{epochs: 1, batch_size: 16}}
policy: {{mode: {mode}, rl_config: {rl}, finetune_steps: 60, learning_starts: 30}}
eval: {{episodes: 2}}
"""


def test_widened_policy_acts_like_the_state_policy_before_fine_tuning():
    env = SemanticState(make("FetchReach"))
    semantic = SAC("MultiInputPolicy", env, policy_kwargs={"net_arch": [16, 16]}, device="cpu", seed=0)
    for parameter in semantic.policy.parameters():  # make every weight matter
        torch.nn.init.normal_(parameter, std=0.3)
    import gymnasium as gym

    flat = gym.make("Pendulum-v1")  # any env; SAC only needs the spaces
    flat.observation_space = spaces.Box(-np.inf, np.inf, (6 + 2,), np.float32)
    flat.action_space = env.action_space
    latent = SAC("MlpPolicy", flat, policy_kwargs={"net_arch": [16, 16]}, device="cpu", seed=1)
    widen_from_semantic(semantic, latent, goal_dim=3)
    rng = np.random.default_rng(0)
    for _ in range(5):
        z, g, free = rng.normal(size=3), rng.normal(size=3), rng.normal(size=2) * 5
        observation = {"observation": z, "achieved_goal": z, "desired_goal": g}
        expected, _ = semantic.predict(observation, deterministic=True)
        got, _ = latent.predict(np.concatenate([z, g, free]).astype(np.float32), deterministic=True)
        np.testing.assert_allclose(got, expected, atol=1e-5)
        action = torch.as_tensor(expected[None], dtype=torch.float32)
        q_old = semantic.policy.critic(semantic.policy.obs_to_tensor(observation)[0], action)
        q_new = latent.policy.critic(torch.as_tensor(np.concatenate([z, g, free])[None], dtype=torch.float32), action)
        for old, new in zip(q_old, q_new):
            assert torch.allclose(old, new, atol=1e-5)


def test_april_pipeline_runs_resumes_and_deploys_from_pixels(tmp_path):
    from binpick import Policy

    (tmp_path / "rl.yaml").write_text(RL)
    config = tmp_path / "april.yaml"
    config.write_text(APRIL.format(kind="ae", n=6, m=6, mode="semantic", rl=tmp_path / "rl.yaml")
                      .replace("eval:", "refine: {episodes: 2, epochs: 1, act_on: pixels, rounds: 2}\neval:"))
    result = binpick_here(["april", "run", str(config), "--runs", str(tmp_path / "runs")])
    assert result.returncode == 0, result.stderr
    (run,) = (tmp_path / "runs" / "tiny_april").iterdir()
    rows = json.loads((run / "results.json").read_text())
    pixels = "pixels_ae_n6_m6_w1_refined_on_pixels"
    assert set(rows) == {"ground_truth", pixels}
    assert all(0 < row["avg_actions"] <= 50 and row["sim_episodes"] >= 2 for row in rows.values())
    # perception refined twice on episodes of the policy acting on φ_enc(I): 2 random + 2 x 2 refine episodes
    assert rows[pixels]["sim_episodes"] == rows["ground_truth"]["sim_episodes"] + 2 + 4
    refine = json.loads((run / "stages.json").read_text())["refine"]
    assert refine["act_on"] == "pixels" and len(refine["success_while_collecting"]) == 2
    assert len(read_npz(run / "data" / "policy.npz", "images")["images"]) == refine["images"] > 4
    for picture in ("reconstructions.png", "heatmap_ground_truth.png", f"heatmap_{pixels}.png"):
        assert (run / picture).stat().st_size > 1000
    # a crash during evaluation: the finished stages are not redone
    stages = json.loads((run / "stages.json").read_text())
    del stages["evaluate"]
    (run / "stages.json").write_text(json.dumps(stages))
    data_time = (run / "data" / "random.npz").stat().st_mtime_ns
    resumed = binpick_here(["april", "run", "--resume", str(run)])
    assert resumed.returncode == 0, resumed.stderr
    assert "stage evaluate" in resumed.stdout and "stage collect" not in resumed.stdout
    assert (run / "data" / "random.npz").stat().st_mtime_ns == data_time
    # the deployed policy: one call to load, an image in, an action out; it reads the RL config the run
    # folder carries, not the file the run was started from (gone on a robot computer)
    assert "min_action_scale" in (run / "rl_config.yaml").read_text()
    (tmp_path / "rl.yaml").rename(tmp_path / "elsewhere.yaml")
    policy = Policy.load(run)
    env = make("FetchReach", image="grey", image_size=64)
    observation, _ = env.reset(seed=0)
    action, state = policy.predict(observation["image"], deterministic=True)  # SB3's shape, as every trained policy
    assert state is None and policy.action_space.shape == (4,) and policy.observation_space.contains(observation["image"])
    assert action.shape == (4,) and np.abs(action[:3]).max() >= 0.4 - 1e-6  # min action scale applies
    with pytest.raises(ConfigError, match="images of shape"):
        policy.predict(np.zeros((64, 64, 3), np.uint8))
    evaluation = binpick_here(["april", "eval", str(run), "--input", "pixels", "--episodes", "1"])
    assert evaluation.returncode == 0 and "actions per episode" in evaluation.stdout, evaluation.stderr
    (tmp_path / "elsewhere.yaml").rename(tmp_path / "rl.yaml")
    _latent_policy_widened_from_the_shared_state_policy(run, tmp_path)


def _latent_policy_widened_from_the_shared_state_policy(first_run, tmp_path):
    """m < n (Eq 4.9): the state policy of an earlier run, widened for the free latents and fine-tuned."""
    from binpick import Policy
    from binpick.april import AprilConfig, AprilRun
    from binpick.core.config import load_config

    state_run = json.loads((first_run / "stages.json").read_text())["policy"]["semantic_run"]
    config = tmp_path / "latent.yaml"
    config.write_text(APRIL.format(kind="vae", n=8, m=6, mode="latent", rl=tmp_path / "rl.yaml")
                      .replace("finetune_steps", f"state_run: {state_run}, finetune_steps")
                      .replace("eval:", "refine: {episodes: 2, epochs: 1}\neval:")
                      .replace("image: grey", "image: grey\nenv_kwargs: {views: [workspace, side]}"))
    run = AprilRun.new(load_config(AprilConfig, config), tmp_path / "runs")
    rows = run.run()["rows"]
    # two cameras: the perception reads both views, stacked as channels, and the row says so
    assert list(rows) == ["pixels_vae_n8_m6_w1_refined_two_views"] and not (run.run_dir / "rl").exists()
    assert read_npz(run.run_dir / "data" / "random.npz", "images")["images"].shape[1:] == (64, 64, 2)
    assert run.stages["policy"]["semantic_run"] == state_run
    assert run.stages["finetune"]["widened"] and run.stages["finetune"]["sim_steps"] == 60
    # refine: perception trained further on the state policy's episodes, counted in the row
    assert run.stages["refine"]["sim_episodes"] == 2 and (run.run_dir / "data" / "policy.npz").is_file()
    assert rows["pixels_vae_n8_m6_w1_refined_two_views"]["sim_episodes"] == 2 + 2 + run.sim_episodes["state_policy"] + run.stages["finetune"]["sim_episodes"]
    assert Policy.load(run.run_dir).model.observation_space.shape == (8,)
    state_policy = Policy.load(state_run)  # the RL run it widened: loaded and asked the same way
    action, state = state_policy.predict(state_policy.observation_space.sample(), deterministic=True)
    assert state is None and action.shape == (4,) and state_policy.action_space.contains(action.astype(np.float32))
    _latent_policy_distilled_from_the_state_policy(state_run, tmp_path)


def _latent_policy_distilled_from_the_state_policy(state_run, tmp_path):
    """policy.finetune distill (DAgger): the state policy labels the images the student visits."""
    from binpick.april import AprilConfig, AprilRun
    from binpick.core.config import load_config

    config = tmp_path / "distill.yaml"
    config.write_text(APRIL.format(kind="ae", n=8, m=6, mode="latent", rl=tmp_path / "rl.yaml")
                      .replace("finetune_steps: 60", f"state_run: {state_run}, finetune: distill, finetune_steps: 90, "
                                                     "distill_every: 30, distill_gradient_steps: 40"))
    run = AprilRun.new(load_config(AprilConfig, config), tmp_path / "runs")
    rows = run.run()["rows"]
    assert list(rows) == ["pixels_ae_n8_m6_w1_distilled"]
    assert run.stages["finetune"]["labels"] == 90 and run.stages["finetune"]["finetune"] == "distill"
    history = json.loads((run.run_dir / "distill_history.json").read_text())
    assert [round_["labels"] for round_ in history] == [30, 60, 90]
    # a student that starts from random weights (not widened) learns the state policy's actions
    from binpick.april.finetune import distill_from_state_policy
    from binpick.april.observations import EncodedObservation
    from binpick.april.perception import load_perception, perception_path
    from binpick.rl.policy import load_policy

    perception = load_perception(perception_path(run.run_dir))
    env = EncodedObservation(run.make_env(), perception.encode, 8, 6)
    student = SAC("MlpPolicy", env, learning_starts=0, policy_kwargs={"net_arch": [16, 16]}, seed=0, device="cpu")
    teacher, _ = load_policy(state_run)
    distill_from_state_policy(student, teacher, env, run)
    history = json.loads((run.run_dir / "distill_history.json").read_text())
    assert history[-1]["mse"] < 0.5 * history[0]["mse_before"], "the student's actions move to the state policy's"


def test_bad_april_input_is_one_clear_line(tmp_path):
    (tmp_path / "rl.yaml").write_text(RL)
    bad = tmp_path / "bad.yaml"
    bad.write_text(APRIL.format(kind="ae", n=6, m=8, mode="semantic", rl=tmp_path / "rl.yaml"))
    result = binpick_here(["april", "run", str(bad)])
    assert result.returncode == 2 and "conditioned (m=8) must be <= perception.latent (n=6)" in result.stderr
    assert "Traceback" not in result.stderr
    bad.write_text(APRIL.format(kind="ae", n=8, m=6, mode="semantic", rl=tmp_path / "rl.yaml"))
    result = binpick_here(["april", "run", str(bad)])
    assert result.returncode == 2 and "policy.mode semantic" in result.stderr
    bad.write_text(APRIL.format(kind="ae", n=8, m=6, mode="latent", rl=tmp_path / "rl.yaml")
                   .replace("eval:", "refine: {episodes: 2, act_on: actions}\neval:"))
    result = binpick_here(["april", "run", str(bad)])
    assert result.returncode == 2 and "refine.act_on must be one of 'state', 'pixels', got 'actions'" in result.stderr
    result = binpick_here(["april", "eval", str(tmp_path)])
    assert result.returncode == 2 and "not an APRiL run folder" in result.stderr


def test_state_policy_config_is_checked_before_any_stage(tmp_path):
    """A state policy for another world, or one that reads privileged state where pixels must stand in
    for it, is one line before collection starts (no stage runs)."""
    from binpick.april import AprilConfig, AprilRun
    from binpick.core.config import load_config

    obstacle_rl = RL.replace("env: FetchReach", "env: binpick/FetchReachObstacle-v0")
    (tmp_path / "rl.yaml").write_text(obstacle_rl)
    (tmp_path / "teacher.yaml").write_text(obstacle_rl.replace("gp: {enabled: true,", "privileged_state: [obstacle_position]\n"
                                                                "gp: {enabled: false,"))
    base = APRIL.replace("env: FetchReach", "env: binpick/FetchReachObstacle-v0")
    cases = [
        (base.format(kind="ae", n=6, m=6, mode="semantic", rl=tmp_path / "rl.yaml")
         .replace("image: grey", "image: grey\nenv_kwargs: {obstacle_on_path: 1.0, views: [workspace]}"),
         "the state policy trains on env_kwargs {}, this APRiL run's world is {'obstacle_on_path': 1.0}"),
        (base.format(kind="ae", n=6, m=6, mode="semantic", rl=tmp_path / "teacher.yaml"),
         "reads privileged_state ['obstacle_position'], which pixels never give"),
        (base.format(kind="ae", n=8, m=6, mode="latent", rl=tmp_path / "teacher.yaml")
         .replace("finetune_steps: 60", "pretrain: true, finetune_steps: 60"), "it can only teach"),
    ]
    with pytest.raises(ConfigError, match="policy.teacher detour is a scripted teacher for binpick/FetchReachObstacle-v0"):
        config = tmp_path / "detour.yaml"
        config.write_text(APRIL.format(kind="ae", n=8, m=6, mode="latent", rl=tmp_path / "rl.yaml")
                          .replace("finetune_steps: 60", "pretrain: false, teacher: detour, finetune: distill"))
        load_config(AprilConfig, config)
    for number, (text, message) in enumerate(cases):
        config = tmp_path / f"april{number}.yaml"
        config.write_text(text)
        run = AprilRun.new(load_config(AprilConfig, config), tmp_path / "runs")
        with pytest.raises(ConfigError, match=re.escape(message)):
            run.run()
        assert run.stages == {}, "nothing ran"


def _distilled_obstacle_run(tmp_path, rl: str, policy: str) -> tuple:
    """A tiny latent n = 8, m = 6 FetchReachObstacle run distilled from a teacher; (run, its rows)."""
    from binpick.april import AprilConfig, AprilRun
    from binpick.core.config import load_config

    config = tmp_path / "distill.yaml"
    config.write_text(APRIL.replace("env: FetchReach", "env: binpick/FetchReachObstacle-v0")
                      .format(kind="ae", n=8, m=6, mode="latent", rl=tmp_path / rl)
                      .replace("finetune_steps: 60", f"finetune: distill, {policy}"))
    run = AprilRun.new(load_config(AprilConfig, config), tmp_path / "runs")
    return run, run.run()["rows"]


def test_teachers_that_know_the_box_label_the_students_images(tmp_path):
    """A state policy with privileged_state, or the scripted detour, teaches a student that sees pixels only."""
    obstacle_rl = RL.replace("env: FetchReach", "env: binpick/FetchReachObstacle-v0")
    (tmp_path / "rl.yaml").write_text(obstacle_rl)
    (tmp_path / "teacher.yaml").write_text(obstacle_rl.replace("gp: {enabled: true,", "privileged_state: [obstacle_position]\n"
                                                                "gp: {enabled: false,"))
    run, rows = _distilled_obstacle_run(tmp_path, "teacher.yaml", "pretrain: true, finetune_steps: 40, distill_every: 20, "
                                                                  "distill_gradient_steps: 5")
    assert list(rows) == ["ground_truth_privileged", "pixels_ae_n8_m6_w1_distilled"]
    assert rows["ground_truth_privileged"]["sim_episodes"] == run.sim_episodes["state_policy"]
    assert run.stages["finetune"]["labels"] == 40 and run.stages["finetune"]["widened"] is False
    run, rows = _distilled_obstacle_run(tmp_path, "rl.yaml", "pretrain: false, teacher: detour, finetune_steps: 20, "
                                                             "distill_every: 10, distill_gradient_steps: 2")
    assert list(rows) == ["detour_teacher", "pixels_ae_n8_m6_w1_distilled_from_detour"]
    assert rows["detour_teacher"]["sim_episodes"] == 0 and run.stages["finetune"]["labels"] == 20
    # distill_encoder: the encoder learns from the labels too; the perception stage's own is kept
    import torch

    from binpick.april.finetune import PRETRAINED_PERCEPTION_FILE
    from binpick.april.perception import load_perception

    run, rows = _distilled_obstacle_run(tmp_path, "rl.yaml", "pretrain: false, teacher: detour, finetune_steps: 20, "
                                                             "distill_every: 10, distill_gradient_steps: 3, distill_encoder: true")
    assert list(rows) == ["detour_teacher", "pixels_ae_n8_m6_w1_distilled_encoder_from_detour"]
    before = load_perception(run.run_dir / PRETRAINED_PERCEPTION_FILE).state_dict()
    after = load_perception(run.run_dir / "perception.safetensors").state_dict()
    assert not torch.equal(before["to_latent.weight"], after["to_latent.weight"]), "the encoder did not learn"
    torch.testing.assert_close(before["state_mean"], after["state_mean"])  # s̄'s units stay the perception stage's


def test_row_names_say_what_differs_from_the_thesis_set_up(tmp_path):
    """Rows of another world, schedule or teacher never overwrite the thesis-protocol rows."""
    from binpick.april import AprilConfig, AprilRun
    from binpick.core.config import load_config
    from binpick.april.evaluate import row_names
    configs = Path(__file__).resolve().parents[1] / "configs" / "april"

    def rows(name: str) -> dict:
        seeded = re.fullmatch(r"(.+)_seed(\d+)", name)  # a seed is an override of its config, not a file of its own
        if seeded:
            return row_names(AprilRun(load_config(AprilConfig, configs / f"{seeded.group(1)}.yaml",
                                                        {"seed": int(seeded.group(2)), "name": name}), tmp_path))
        return row_names(AprilRun(load_config(AprilConfig, configs / f"{name}.yaml"), tmp_path))

    assert rows("april_obstacle_n6_m6") == {"state": "ground_truth", "pixels": "pixels_ae_n6_m6_w1"}
    assert rows("april_obstacle_on_path_n6_m6_goals") == {"state": "ground_truth_on_path",
                                                           "pixels": "pixels_ae_n6_m6_w1_goals_on_path"}
    assert rows("april_obstacle_on_path_n8_m6_distilled_goals") == {
        "state": "ground_truth_privileged_on_path", "pixels": "pixels_ae_n8_m6_w1_goals_on_path_distilled"}
    assert rows("april_pickandplace_ae_n9_m9_goals_two_views_long")["pixels"] == "pixels_ae_n9_m9_w1_goals5_cosine80_two_views"
    assert rows("april_pickandplace_ae_n9_m9_goals1_two_views_long")["pixels"] == "pixels_ae_n9_m9_w1_goals_cosine80_two_views"
    assert rows("april_pickandplace_ae_n9_m9_goals_two_views_long_noise5mm") == {
        "state": "ground_truth_actor_noise5mm", "pixels": "pixels_ae_n9_m9_w1_goals5_cosine80_two_views_actor_noise5mm"}
    assert rows("april_pickandplace_ae_n10_m10_goals_two_views_long_opening") == {
        "state": "ground_truth_opening", "pixels": "pixels_ae_n10_m10_w1_goals5_cosine80_two_views_opening"}
    assert rows("april_obstacle_on_path_n8_m6_foreground_distilled_detour")["pixels"] == \
        "pixels_ae_n8_m6_w1_fg20_goals_on_path_distilled_from_detour"
    assert rows("april_obstacle_on_path_n8_m6_distilled_encoder_detour") == {
        "state": "detour_teacher_on_path", "pixels": "pixels_ae_n8_m6_w1_goals_on_path_distilled_encoder_from_detour"}
    assert rows("april_obstacle_on_path_n8_m6_keypoints_distilled_detour")["pixels"] == \
        "pixels_ae_n8_m6_w1_kp_goals_on_path_distilled_from_detour"
    assert rows("april_obstacle_on_path_n6_m6_distilled_detour_40k")["pixels"] == \
        "pixels_ae_n6_m6_w1_goals_on_path_distilled_40k_from_detour"
    assert rows("april_obstacle_on_path0.5_n8_m6_keypoints_distilled_detour_40k") == {  # the box on the path half the time
        "state": "detour_teacher_on_path0.5", "pixels": "pixels_ae_n8_m6_w1_kp_goals_cosine80_on_path0.5_distilled_40k_from_detour"}
    assert rows("april_obstacle_on_path0.5_n6_m6_distilled_detour_40k_seed1")["pixels"] == \
        "pixels_ae_n6_m6_w1_goals_cosine80_on_path0.5_seed1_distilled_40k_from_detour"


def test_scripted_pick_and_place_heuristic_completes_the_task():
    from binpick.rl.common.heuristic import PickAndPlaceHeuristic
    from binpick.rl.common.evaluate import evaluate_policy

    result = evaluate_policy(PickAndPlaceHeuristic(), make("FetchPickAndPlace"), episodes=6, seed=0)
    assert result.success_rate >= 0.8 and result.mean_length < 60, (result.success_rate, result.mean_length)


def test_demonstrations_fill_the_replay_and_behaviour_cloning_imitates_the_heuristic(tmp_path):
    """Thesis §4.5.3: heuristic episodes in the replay and an actor pretrained to imitate them."""
    import yaml

    from binpick.core.config import from_dict
    from binpick.rl.config import RLConfig
    from binpick.rl.train import trainer_for

    config = from_dict(RLConfig, yaml.safe_load("""
name: tiny_pnp
env: FetchPickAndPlace
algorithm: sac
total_timesteps: 50
checkpoint_every: 1000
replay: {capacity_episodes: 100, her_additions: 2, her_min_motion: 0.01}
sac: {batch_size: 64, net_arch: [64, 64]}
demonstrations: {episodes: 4, bc_steps: 1000, noise: 0.0}
eval: {every: 1000, episodes: 1}
"""))
    from binpick.rl.common.heuristic import PickAndPlaceHeuristic
    from binpick.rl.common.demonstrations import collect_demonstrations

    trainer = trainer_for(config, tmp_path)
    episodes, _ = collect_demonstrations(trainer.env, PickAndPlaceHeuristic(), 4, seed=config.seed + 500_000)
    def imitation_error() -> float:  # the actor's deterministic actions against the heuristic's
        errors = []
        for episode in episodes:
            for t in range(episode.length):
                observation = {"observation": episode.observation[t], "achieved_goal": episode.achieved_goal[t],
                               "desired_goal": episode.desired_goal}
                errors.append(np.mean((trainer.model.predict(observation, deterministic=True)[0] - episode.actions[t]) ** 2))
        return float(np.mean(errors))

    before = imitation_error()
    trainer.learn_from_demonstrations()
    assert trainer.metrics.demo_episodes == 4 and trainer.model.replay_buffer.added["real"] == 4
    assert imitation_error() < 0.7 * before, (before, imitation_error())
    metrics = trainer.run()
    assert metrics["demo_episodes"] == 4 and metrics["sim_episodes"] >= 4
    with pytest.raises(ConfigError, match="GP models the gripper alone"):
        from_dict(RLConfig, {"env": "FetchPickAndPlace", "gp": {"enabled": True}})


def test_cloning_fits_sigma_goes_on_during_rl_and_survives_a_resume(tmp_path):
    """Pick and place: σ fitted to the demonstrations, Q-filtered cloning in every SAC update, kept
    in the checkpoint so a resumed run still clones."""
    import torch
    import yaml

    from binpick.core.config import from_dict
    from binpick.rl.config import RLConfig
    from binpick.rl.common.demonstrations import cloning_loss
    from binpick.rl.train import Trainer, trainer_for

    config = from_dict(RLConfig, yaml.safe_load("""
name: tiny_pnp_bc
env: FetchPickAndPlace
algorithm: sac
total_timesteps: 60
checkpoint_every: 30
replay: {capacity_episodes: 100, her_additions: 1, start_fraction: 0.01}
sac: {batch_size: 32, net_arch: [32, 32], learning_starts: 0, ent_coef: auto_0.01}
demonstrations: {episodes: 3, bc_steps: 1500, noise: 0.1, likelihood_weight: 0.1, bc_alpha: 2.5, critic_steps: 20, q_filter: true}
eval: {every: 1000, episodes: 1}
"""))
    trainer = trainer_for(config, tmp_path)
    demo_states = None

    def spread() -> float:  # the actor's exploration σ on the demonstrated states
        tensor, _ = trainer.model.policy.obs_to_tensor(demo_states)
        return float(trainer.model.actor.get_action_dist_params(tensor)[1].detach().exp()[:, :3].mean())  # the moves

    trainer.learn_from_demonstrations()
    demonstrations = trainer.model.demonstrations
    assert demonstrations is not None and len(demonstrations) == trainer.metrics.demo_steps
    demo_states, demo_actions = demonstrations.sample(np.random.default_rng(0), 64)
    assert np.all(np.abs(demo_actions) <= 1.0)
    assert spread() < 0.6, spread()  # an untouched actor explores with σ ≈ 1

    class Critic:  # rates the demonstrated action above anything else, or below
        def __init__(self, prefer_demo: bool) -> None:
            self.prefer_demo = prefer_demo

        def __call__(self, observation, action):
            distance = ((action - torch.as_tensor(demo_actions)) ** 2).sum(dim=1, keepdim=True)
            return (-distance if self.prefer_demo else distance,)

    fake = type("Fake", (), {"policy": trainer.model.policy, "actor": trainer.model.actor})()
    fake.critic = Critic(prefer_demo=True)
    kept, mse = cloning_loss(fake, demo_states, demo_actions, q_filter=True)
    fake.critic = Critic(prefer_demo=False)
    dropped, _ = cloning_loss(fake, demo_states, demo_actions, q_filter=True)
    assert float(kept) == pytest.approx(float(mse)) and float(mse) > 0 and float(dropped) == 0.0

    metrics = trainer.run()
    assert metrics["sim_steps"] == 60 and trainer.model._n_updates > 0
    resumed = Trainer.resume(trainer.run_dir)
    assert resumed.model.bc_alpha == 2.5 and resumed.model.bc_q_filter and resumed.model.bc_likelihood_weight == 0.1
    assert len(resumed.model.demonstrations) == len(demonstrations)


def test_pick_and_place_images_come_from_the_heuristic_so_the_object_moves(tmp_path):
    """A random arm almost never moves the object; perception must also see it lifted (§4.5.3)."""
    import yaml

    from binpick.april import AprilRun
    from binpick.april.config import AprilConfig
    from binpick.core.config import from_dict

    config = from_dict(AprilConfig, yaml.safe_load("""
name: tiny_pnp_collect
env: FetchPickAndPlace
image: rgb
collect: {episodes: 2, policy: heuristic, noise: 0.0}
perception: {kind: ae, latent: 9, conditioned: 9, channels: 4}
policy: {mode: latent, pretrain: false}
"""))
    run = AprilRun.new(config, tmp_path)
    result = run.stage_collect(SILENT)
    assert result["policy"] == "heuristic" and result["sim_episodes"] == 2
    states = np.load(run.run_dir / "data" / "random.npz")["states"]
    assert states.shape[1] == 9  # gripper, object, goal
    lift = states[:, 5].max() - states[0, 5]  # the object's height over its start
    assert lift > 0.03, lift
    with pytest.raises(ConfigError, match="collect.policy heuristic is the pick-and-place script"):
        from_dict(AprilConfig, {"env": "FetchReach", "collect": {"policy": "heuristic"}, "policy": {"mode": "latent", "pretrain": False},
                                "perception": {"latent": 6, "conditioned": 0, "omega": 0.0}})


def test_shifted_domain_changes_the_images_but_not_the_physics():
    from binpick.april.sim_to_real import ShiftedDomain
    from binpick.envs import make

    plain = make("binpick/FetchReach-v0", image="rgb", image_size=48)
    shifted = ShiftedDomain(make("binpick/FetchReach-v0", image="rgb", image_size=48), seed=0)
    try:
        a, _ = plain.reset(seed=3)
        b, _ = shifted.reset(seed=3)
        action = np.array([0.5, -0.3, 0.2, 0.0], dtype=np.float32)
        a, *_ = plain.step(action)
        b, *_ = shifted.step(action)
    finally:
        plain.close()
        shifted.close()
    assert np.allclose(a["observation"], b["observation"]) and np.allclose(a["desired_goal"], b["desired_goal"])
    difference = np.abs(a["image"].astype(float) - b["image"].astype(float)).mean()
    assert difference > 10  # another camera pose, colours, light and noise: a clearly different picture


def test_collect_can_redraw_the_goal_so_perception_sees_many(tmp_path):
    from binpick.april import AprilConfig, AprilRun
    from binpick.core.config import load_config

    (tmp_path / "rl.yaml").write_text(RL)
    config = tmp_path / "april.yaml"
    config.write_text(APRIL.format(kind="ae", n=6, m=6, mode="semantic", rl=tmp_path / "rl.yaml")
                      .replace("episodes: 2}", "episodes: 2, goal_every: 1}", 1).replace("image: grey", "image: rgb"))
    run = AprilRun.new(load_config(AprilConfig, config), tmp_path / "runs")
    run.stage_collect(SILENT)
    data = np.load(run.run_dir / "data" / "random.npz")
    goals = np.unique(data["states"][:, 3:].round(5), axis=0)
    assert len(goals) > 50, "a new goal at every step, not one per episode"
    # the image shows the goal the state names: the red sphere moves with it
    red = (data["images"][..., 0] > 150) & (data["images"][..., 1] < 60)
    assert red.any(axis=(1, 2)).mean() > 0.5 and len({tuple(np.argwhere(r).mean(0).round()) for r in red[:20] if r.any()}) > 5
    with pytest.raises(ConfigError, match="collect.goal_every"):  # Reacher's target is a body, not drawn
        load_config(AprilConfig, config, {"env": "Reacher"})

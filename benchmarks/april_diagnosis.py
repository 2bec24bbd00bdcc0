"""Why does an APRiL policy deployed on pixels fail where the same policy on s̄ succeeds? (Table 4.3)

    python benchmarks/april_diagnosis.py RUN_DIR [--episodes 100]
    python benchmarks/april_diagnosis.py --obstacle        # is FetchReachObstacle's box in the way at all?
    python benchmarks/april_diagnosis.py RUN_DIR --substitute   # pick and place: which part of φ_enc(I) breaks it?
    python benchmarks/april_diagnosis.py RUN_DIR --probe-box    # obstacle: do the free latents carry the box?
    python benchmarks/april_diagnosis.py RUN_DIR --distill-ceiling   # obstacle: students that read the truth

Rolls the run's pixel deployment on the evaluation seeds and records, at every step, φ_enc(I)
against the true s̄: the goal's error split into the part along the workspace camera's ray (depth,
which that view sees only through the sphere's few-pixel size) and the part across it, the gripper's error,
and how many pixels of the goal sphere the camera sees (rendered once with the sphere and once
without it: 0 means the arm hides it). Failed and successful episodes are then compared, so the
cause is measured rather than guessed. Writes ``results/april_diagnosis.json`` (one key per run).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.dirname(__file__))

import _common  # noqa: E402

from binpick.april import AprilRun  # noqa: E402
from binpick.april.evaluate import deployment_env  # noqa: E402


def visible_goal_pixels(fetch) -> int:
    """Pixels of the observation image(s) that change when the goal sphere is made invisible."""
    site = fetch.model.site("target0").id
    alpha = float(fetch.model.site_rgba[site, 3])
    fetch._prepare_frame()
    shown = fetch._with_image({}, fetch.data)["image"].astype(int)
    fetch.model.site_rgba[site, 3] = 0.0
    hidden = fetch._with_image({}, fetch.data)["image"].astype(int)
    fetch.model.site_rgba[site, 3] = alpha
    return int(np.any(shown != hidden, axis=-1).sum())


def in_the_way(fetch, start: np.ndarray, goal: np.ndarray) -> bool:
    """Would the detour teacher go round: the straight line start -> goal passes within its clearance of the box."""
    from binpick.rl.heuristic import ObstacleDetour, box_clearance

    clearance = box_clearance(start, goal, fetch.obstacle_position, fetch.obstacle_half_size)
    return bool(clearance < ObstacleDetour(fetch.obstacle_half_size).clearance)


def diagnose(run: AprilRun, episodes: int) -> dict:
    env, policy, _ = deployment_env(run, "pixels")
    fetch = env.unwrapped
    directions = [pose.forward for pose in fetch.observation_poses]
    seed = run.config.eval.seed
    per_episode = []
    obstacle = hasattr(fetch, "obstacle_position")
    m = run.config.perception.conditioned  # a free keypoint against where the box really is in the image
    free_keypoint = obstacle and run.config.perception.free_features == "keypoints"
    for episode in range(episodes):
        observation, _ = env.reset(seed=seed + episode)
        steps, done, success, touched = [], False, False, False
        if obstacle:  # is the box in the detour teacher's way at the start (it would go round)?
            start = fetch._get_obs()
            blocked = in_the_way(fetch, start["achieved_goal"], start["desired_goal"])
        while not done:
            raw = fetch._get_obs()
            truth_goal, truth_grip = raw["desired_goal"], raw["achieved_goal"]
            seen = observation if isinstance(observation, dict) else \
                {"achieved_goal": observation[:3], "desired_goal": observation[3:6]}  # φ_enc(I): s̄ = (z, g) first
            goal_error = seen["desired_goal"] - truth_goal
            along = float(goal_error @ directions[0])  # the workspace view's ray, in every run
            steps.append({"goal_error": float(np.linalg.norm(goal_error)),
                          "goal_error_along_ray": abs(along),
                          "goal_error_across_ray": float(np.linalg.norm(goal_error - along * directions[0])),
                          "gripper_error": float(np.linalg.norm(seen["achieved_goal"] - truth_grip)),
                          "goal_pixels": visible_goal_pixels(fetch),
                          **({"keypoint_error": keypoint_off_box(fetch, observation[m:m + 2])} if free_keypoint else {})})
            action = policy.predict(observation, deterministic=True)[0]
            observation, _, terminated, truncated, info = env.step(action)
            success = success or bool(info.get("is_success"))
            touched = touched or (obstacle and fetch.obstacle_contacts() > 0)
            done = terminated or truncated
        first = steps[0]
        per_episode.append({"success": success, "length": len(steps),
                            "start_goal_error": first["goal_error"], "start_goal_pixels": first["goal_pixels"],
                            "start_goal_error_along_ray": first["goal_error_along_ray"],
                            "mean_goal_error": float(np.mean([s["goal_error"] for s in steps])),
                            "mean_gripper_error": float(np.mean([s["gripper_error"] for s in steps])),
                            "hidden_fraction": float(np.mean([s["goal_pixels"] == 0 for s in steps])),
                            "last_goal_error": steps[-1]["goal_error"], "last_gripper_error": steps[-1]["gripper_error"],
                            **({"blocked": blocked, "touched_box": bool(touched)} if obstacle else {}),
                            **({"mean_keypoint_error": float(np.mean([s["keypoint_error"] for s in steps]))}
                               if free_keypoint else {})})
        print(f"episode {episode}: {'ok ' if success else 'FAIL'} length {len(steps)} "
              f"goal error start {first['goal_error'] * 100:.1f} cm (pixels {first['goal_pixels']}), "
              f"mean {per_episode[-1]['mean_goal_error'] * 100:.1f} cm, hidden {per_episode[-1]['hidden_fraction']:.0%}",
              flush=True)
    env.close()

    def summary(rows: list[dict]) -> dict:
        if not rows:
            return {"episodes": 0}
        keys = [k for k in rows[0] if k not in ("success", "blocked", "touched_box")]
        return {"episodes": len(rows), **{k: round(float(np.median([r[k] for r in rows])), 4) for k in keys}}

    failed = [r for r in per_episode if not r["success"]]
    succeeded = [r for r in per_episode if r["success"]]
    report = {"run_dir": str(run.run_dir), "episodes": episodes, "success": len(succeeded) / episodes,
              "median_failed": summary(failed), "median_succeeded": summary(succeeded),
              "failed_with_goal_hidden_at_start": sum(r["start_goal_pixels"] == 0 for r in failed)}
    if obstacle:  # where the box was in the way and where not: does the student go round, and does it arrive?
        report["by_blocked"] = {
            label: {"episodes": len(rows), "success": round(float(np.mean([r["success"] for r in rows])), 3),
                    "avg_actions": round(float(np.mean([r["length"] for r in rows])), 2),
                    "touched_box": round(float(np.mean([r["touched_box"] for r in rows])), 3),
                    "median_mean_goal_error_cm": round(float(np.median([r["mean_goal_error"] for r in rows])) * 100, 2),
                    "median_mean_gripper_error_cm": round(float(np.median([r["mean_gripper_error"] for r in rows])) * 100, 2),
                    "median_goal_hidden_fraction": round(float(np.median([r["hidden_fraction"] for r in rows])), 3),
                    **({"median_mean_keypoint_error": round(float(np.median([r["mean_keypoint_error"] for r in rows])), 3)}
                       if free_keypoint else {})}
            for label, rows in (("blocked", [r for r in per_episode if r["blocked"]]),
                                ("clear", [r for r in per_episode if not r["blocked"]])) if rows}
    return report | {"per_episode": per_episode}


def seen_against_new(run: AprilRun, episodes: int, samples: int = 500) -> dict:
    """Per-dimension mean absolute error of φ_enc(I)^{1:m} (cm) on the images perception trained on
    against the first frame of new episodes (new goals): a gap means it memorised the few hundred
    goals its collection episodes showed it rather than learning to find the goal."""
    from binpick.april.observations import semantic_state
    from binpick.files import read_npz
    from binpick.perception import load_perception, perception_path

    perception = load_perception(perception_path(run.run_dir))
    data = read_npz(run.run_dir / "data" / "random.npz", "APRiL image data")
    picked = np.random.default_rng(0).choice(len(data["images"]), min(samples, len(data["images"])), replace=False)
    m = perception.config.conditioned  # s̄'s part of φ_enc(I); free features (n > m) have no truth to match
    seen = np.concatenate([perception.encode(data["images"][picked[i:i + 100]])[:, :m] for i in range(0, len(picked), 100)])
    seen_error = np.abs(seen - data["states"][picked]).mean(0)
    env = run.make_env()
    new_error = []
    for episode in range(episodes):
        observation, _ = env.reset(seed=run.config.eval.seed + episode)
        new_error.append(np.abs(perception.encode(observation["image"])[0, :m] - semantic_state(observation, run.gripper)))
    env.close()
    return {"training_images_cm": [round(float(v) * 100, 2) for v in seen_error],
            "new_episodes_cm": [round(float(v) * 100, 2) for v in np.mean(new_error, 0)],
            "dimensions": "gripper xyz, goal xyz" if not run.gripper else "gripper xyz, object xyz, goal xyz"}


SUBSTITUTES = {"none": (), "true_goal": ("goal",), "true_gripper": ("gripper",), "true_object": ("object",),
               "true_gripper_and_object": ("gripper", "object")}


def substitute_truth(run: AprilRun, episodes: int) -> dict:
    """Pick and place deployed on pixels with one part of φ_enc(I) replaced by the simulator's truth
    (the goal, the gripper, the cube): the part whose truth restores the state policy's success is the
    one perception gets wrong for it. Also the share of episodes in which the cube is lifted > 2 cm
    (the policy grasped it) and the median error of the perceived cube while the gripper is within 3 cm."""
    from binpick.april.observations import semantic_observation, semantic_state

    if not run.gripper:
        raise SystemExit("--substitute is for pick and place (s̄ = gripper, object, goal)")
    env, policy, _ = deployment_env(run, "pixels")
    fetch = env.unwrapped
    report = {}
    for name, parts in SUBSTITUTES.items():
        successes, lifted, lengths, near_errors = 0, 0, [], []
        for episode in range(episodes):
            observation, _ = env.reset(seed=run.config.eval.seed + episode)
            table = fetch._get_obs()["achieved_goal"][2]
            done, success, lift, steps = False, False, 0.0, 0
            while not done:
                true = semantic_state(fetch._get_obs(), True)
                perceived = np.concatenate([observation["observation"], observation["desired_goal"]])
                if np.linalg.norm(true[3:6] - true[:3]) < 0.03:
                    near_errors.append(float(np.linalg.norm(perceived[3:6] - true[3:6])))
                for part in parts:
                    index = {"gripper": slice(0, 3), "object": slice(3, 6), "goal": slice(6, 9)}[part]
                    perceived[index] = true[index]
                action = policy.predict(semantic_observation(perceived, 3), deterministic=True)[0]
                observation, _, terminated, truncated, info = env.step(action)
                lift = max(lift, fetch._get_obs()["achieved_goal"][2] - table)
                steps, success, done = steps + 1, success or bool(info.get("is_success")), terminated or truncated
            successes, lifted, lengths = successes + int(success), lifted + int(lift > 0.02), lengths + [steps]
        report[name] = {"success": successes / episodes, "lifted": lifted / episodes, "avg_actions": float(np.mean(lengths)),
                        "object_error_near_gripper_cm": round(float(np.median(near_errors)) * 100, 2) if near_errors else None}
        print(name, json.dumps(report[name]), flush=True)
    env.close()
    return {"episodes": episodes, "seed": run.config.eval.seed, "rows": report}


def probe_box(run: AprilRun, images: int = 1000) -> dict:
    """Do φ_enc(I)'s features carry FetchReachObstacle's box? A linear probe (least squares, fit on
    half of ``images`` reset states, scored on the other half): the box centre's error (cm, mean
    Euclidean) from the conditioned features alone (s̄: on the path, the box lies between gripper and
    goal, so s̄ already predicts part of it) against from all of them. Free features that carry the
    box bring the error down; the run's perception is the deployed one (after any distill_encoder)."""
    from binpick.perception import load_perception, perception_path

    if "obstacle" not in run.config.env.lower():
        raise SystemExit("--probe-box is for binpick/FetchReachObstacle-v0 runs")
    perception = load_perception(perception_path(run.run_dir))
    env = run.make_env()
    features, boxes, pictures, blocked, truths = [], [], [], [], []
    for index in range(images):
        observation, _ = env.reset(seed=50_000 + index)
        features.append(perception.encode(observation["image"])[0])
        boxes.append(env.unwrapped.obstacle_position.copy())
        blocked.append(in_the_way(env.unwrapped, observation["achieved_goal"], observation["desired_goal"]))
        truths.append(np.concatenate([observation["achieved_goal"], observation["desired_goal"], boxes[-1]]))
        if index < 8:
            pictures.append(observation["image"])
    env.close()
    if perception.config.free_features == "keypoints" or perception.config.goal_keypoints:
        show_keypoints(run, perception, np.stack(pictures))
    features, boxes = np.asarray(features, np.float64), np.asarray(boxes, np.float64)
    half, m = images // 2, perception.config.conditioned

    def error(columns: slice) -> float:
        design = np.hstack([features[:, columns], np.ones((images, 1))])
        weights, *_ = np.linalg.lstsq(design[:half], boxes[:half], rcond=None)
        return round(float(np.linalg.norm(design[half:] @ weights - boxes[half:], axis=1).mean()) * 100, 2)

    def nearest(inputs: np.ndarray, k: int = 10) -> np.ndarray:
        """Each held-out image's k nearest training images (standardised inputs): a code read non-linearly."""
        scaled = inputs / inputs[:half].std(0).clip(1e-6)
        return np.argsort(np.linalg.norm(scaled[half:, None] - scaled[None, :half], axis=2), axis=1)[:, :k]

    def neighbours(columns: slice) -> float:
        guess = boxes[:half][nearest(features[:, columns])].mean(1)
        return round(float(np.linalg.norm(guess - boxes[half:], axis=1).mean()) * 100, 2)

    def blocked_from(inputs: np.ndarray) -> float:  # the detour teacher's own decision: go round or straight
        vote = blocked[:half][nearest(inputs)].mean(1) > 0.5
        return round(float((vote == blocked[half:]).mean()), 3)

    blocked, truths = np.asarray(blocked), np.asarray(truths, np.float64)
    spread = round(float(np.linalg.norm(boxes[half:] - boxes[:half].mean(0), axis=1).mean()) * 100, 2)
    return {"images": images, "latent": perception.config.latent, "conditioned": m,
            "box_error_cm": {"mean_only": spread, "conditioned": error(slice(0, m)), "all": error(slice(None))},
            "box_error_knn_cm": {"conditioned": neighbours(slice(0, m)), "all": neighbours(slice(None))},
            "blocked_share": round(float(blocked[half:].mean()), 3),
            "blocked_knn_accuracy": {"conditioned": blocked_from(features[:, :m]), "all": blocked_from(features),
                                     "true_state": blocked_from(truths[:, :6]), "true_state_and_box": blocked_from(truths)}}


def show_keypoints(run: AprilRun, perception, images: np.ndarray) -> None:
    """docs/img/april/<run>_free_keypoints.png (or _goal_keypoints.png without free ones): reset images with
    each free keypoint ringed in magenta and each view's goal keypoint in cyan (top) and the decoder's
    reconstruction (bottom), 4x enlarged, the stacked views side by side: where the keypoints look. A free
    keypoint's place is one for all stacked views: it is ringed in each."""
    import torch
    from PIL import Image, ImageDraw

    scale, m = 4, perception.config.conditioned
    per_view = 3 if run.config.image == "rgb" else 1
    free = perception.encode(images)[:, m:] if perception.config.free_features == "keypoints" else np.zeros((len(images), 0))
    goal = np.zeros((len(images), 0))
    if perception.config.goal_keypoints:
        with torch.no_grad():
            goal = perception.goal_points(perception._pixels(images)).numpy()
    drawn = perception.reconstruct(images)
    columns = []
    for image, free_points, goal_points, reconstruction in zip(images, free, goal, drawn):
        for view in range(image.shape[-1] // per_view):
            channels = slice(view * per_view, (view + 1) * per_view)
            picture = Image.fromarray(image[..., channels].squeeze()).convert("RGB")
            picture = picture.resize((image.shape[1] * scale, image.shape[0] * scale), Image.NEAREST)
            pen = ImageDraw.Draw(picture)
            rings = [(point, (255, 0, 255)) for point in free_points.reshape(-1, 2)]
            rings += [(goal_points.reshape(-1, 2)[view], (0, 255, 255))] if len(goal_points) else []
            for (x, y), colour in rings:
                u, v = (x + 1) / 2 * picture.width, (y + 1) / 2 * picture.height
                pen.ellipse([u - 7, v - 7, u + 7, v + 7], outline=colour, width=3)
            below = Image.fromarray(reconstruction[..., channels].squeeze()).convert("RGB").resize(picture.size, Image.NEAREST)
            columns.append(np.concatenate([np.asarray(picture), np.asarray(below)], axis=0))
    folder = _common.ROOT / "docs" / "img" / "april"
    folder.mkdir(parents=True, exist_ok=True)
    kind = "free" if perception.config.free_features == "keypoints" else "goal"
    Image.fromarray(np.concatenate(columns, axis=1)).save(folder / f"{run.config.name}_{kind}_keypoints.png")


class NoisyBox:
    """The box centre as a perception off by ``sigma`` metres would give it: one Gaussian offset per
    episode (perception errs the same way on the same scene), drawn anew when the box moves (a reset)."""

    def __init__(self, fetch, sigma: float, seed: int = 0) -> None:
        self.fetch, self.sigma, self.rng = fetch, sigma, np.random.default_rng(seed)
        self.box, self.offset = None, np.zeros(3)

    def __call__(self, image) -> np.ndarray:
        box = self.fetch.obstacle_position
        if self.box is None or not np.array_equal(box, self.box):
            self.box, self.offset = box.copy(), self.rng.normal(0.0, self.sigma, 3)
        return np.concatenate([np.zeros(6), box + self.offset])[None]


def keypoint_off_box(fetch, point: np.ndarray) -> float:
    """How far a free keypoint (x, y) is from the box centre's place in the image, in the nearest of the
    stacked views (one place serves them all), in image units ([-1, 1] across)."""
    places = fetch.in_views(fetch.obstacle_position[None])[0].reshape(-1, 2)
    return float(np.linalg.norm(places - point, axis=1).min())


class BoxInView:
    """Where the box centre lies in the workspace camera's image, (x, y) in [-1, 1]: what a free keypoint
    that sat exactly on the box would give (n = 8, m = 6), depth left out as one view leaves it out."""

    def __init__(self, fetch) -> None:
        self.fetch = fetch

    def __call__(self, image) -> np.ndarray:
        place = self.fetch.observation_poses[0].project(self.fetch.obstacle_position, self.fetch.model.vis.global_.fovy)
        return np.concatenate([np.zeros(6), place[0]])[None]


class GoalOff:
    """A truth student's input with s̄'s goal off by a Gaussian offset of ``sigma`` metres per axis, drawn
    once per episode (perception's goal error is mostly a per-scene bias): s̄ as φ_enc(I) gives it."""

    def __init__(self, encoded, inner, sigma: float, seed: int = 0) -> None:
        self.encoded, self.inner, self.sigma, self.rng = encoded, inner, sigma, np.random.default_rng(seed + 1)
        self.goal, self.offset = None, np.zeros(3)

    def __call__(self, image) -> np.ndarray:
        from binpick.april.observations import semantic_state

        raw = self.encoded.last_raw  # the observation being encoded
        if self.goal is None or not np.array_equal(raw["desired_goal"], self.goal):
            self.goal, self.offset = raw["desired_goal"].copy(), self.rng.normal(0.0, self.sigma, 3)
        features = np.array(self.inner(image), np.float64)
        features[0, :6] = semantic_state(raw) + np.concatenate([np.zeros(3), self.offset])
        return features


def distill_ceiling(run: AprilRun, steps: int | None = None, box_noise_cm: float | None = None,
                    box_in_view: bool = False, goal_noise_cm: float | None = None) -> dict:
    """What would perfect perception give a student distilled from the run's teacher? Students that
    read the true s̄, and the true s̄ plus the box centre, learn by the run's own DAgger (steps, rounds,
    network, seeds) and are evaluated on its evaluation seeds: the ceiling of the n = m = 6 row and of
    a row whose free features carried the box exactly. ``steps``: DAgger's simulator steps instead of the run's;
    ``box_noise_cm``: instead, a student reads the box off by that much (per axis, per episode), as perception would;
    ``box_in_view``: instead, one reads the box's exact place in the workspace image (x, y), as a keypoint would;
    ``goal_noise_cm``: the students read s̄'s goal off by that much (per axis, per episode), as φ_enc(I) does."""
    from dataclasses import replace

    from binpick.april.finetune import distill_from_state_policy, latent_sac, with_action_scale
    from binpick.april.observations import EncodedObservation
    from binpick.rl.config import load_rl_config
    from binpick.rl.evaluate import evaluate_policy
    from binpick.rl.heuristic import ObstacleDetour

    if steps is not None:
        run = AprilRun(replace(run.config, policy=replace(run.config.policy, finetune_steps=steps)), run.run_dir)
    policy = run.config.policy
    if policy.teacher != "detour" or policy.finetune != "distill":
        raise SystemExit("--distill-ceiling is for runs distilled from the detour teacher (policy.teacher: detour)")
    rl_settings = load_rl_config(policy.rl_config)
    report = {}
    seed = run.config.seed
    blind = ("state", 6, lambda fetch: lambda image: np.zeros((1, 6)))  # (name, n, what it reads beside s̄)
    students = [("state_plus_box", 9, lambda fetch: NoisyBox(fetch, 0.0, seed)), blind]
    if box_noise_cm is not None:
        students = [(f"state_plus_box_off_{box_noise_cm:g}cm", 9, lambda fetch: NoisyBox(fetch, box_noise_cm / 100, seed))]
    if box_in_view:
        students = [("state_plus_box_in_view", 8, BoxInView)] + ([blind] if goal_noise_cm is not None else [])
    for name, latent, reads in students:
        env = run.make_env()
        fetch = env.unwrapped
        truth = reads(fetch)
        encoded = EncodedObservation(env, truth, latent, 6, with_state=goal_noise_cm is None)
        if goal_noise_cm is not None:  # s̄ itself from the wrapper, off where φ_enc(I) is off
            encoded.encode = GoalOff(encoded, truth, goal_noise_cm / 100, seed=seed)
            name = f"{name}_goal_off_{goal_noise_cm:g}cm"
        env = with_action_scale(encoded, rl_settings.min_action_scale)
        student = latent_sac(run, env, rl_settings)
        distilled = distill_from_state_policy(student, ObstacleDetour(fetch.obstacle_half_size), env, run)
        result = evaluate_policy(student, env, episodes=run.config.eval.episodes, seed=run.config.eval.seed)
        env.close()
        report[name] = {"avg_actions": round(result.mean_length, 2), "success": result.success_rate,
                        "final_mse": distilled["final_mse"], "sim_steps": distilled["sim_steps"]}
        print(name, report[name], flush=True)
    return report


def obstacle_in_the_way(episodes: int = 300) -> dict:
    """Table 4.4 needs a box that matters: per placement, the share of episodes whose box comes within
    4 cm (and within 0 cm: crossing) of the straight line from the gripper to the goal, and how a
    controller that drives straight at the goal, blind to the box, does (success, actions)."""
    from binpick.envs import make
    from binpick.rl.heuristic import ReachController, box_clearance

    straight = ReachController(gain=20.0)  # full speed until 5 cm from the goal
    worlds = {"at_random": {}, "on_path": {"obstacle_on_path": 1.0, "obstacle_half_size": 0.03}}
    report = {}
    for world, kwargs in worlds.items():
        env = make("binpick/FetchReachObstacle-v0", **kwargs)
        fetch, near, crossing, successes, lengths = env.unwrapped, 0, 0, 0, []
        for episode in range(episodes):
            observation, _ = env.reset(seed=20_000 + episode)
            start, goal = observation["achieved_goal"], observation["desired_goal"]
            clearance = box_clearance(start, goal, fetch.obstacle_position, fetch.obstacle_half_size)
            near, crossing = near + int(clearance < 0.04), crossing + int(clearance < 0.0)
            done, success, steps = False, False, 0
            while not done:
                action = straight(observation)
                observation, _, terminated, truncated, info = env.step(action)
                steps, success = steps + 1, success or bool(info.get("is_success"))
                done = terminated or truncated
            successes, lengths = successes + int(success), lengths + [steps]
        env.close()
        report[world] = {"env_kwargs": kwargs, "episodes": episodes, "within_4cm_of_line": near / episodes,
                         "crossing_line": crossing / episodes, "straight_line_success": successes / episodes,
                         "straight_line_avg_actions": float(np.mean(lengths))}
    return report


def read_results(path) -> dict:
    results = json.loads(path.read_text()) if path.exists() else {}
    return {k: v for k, v in results.items() if k not in ("benchmark", "machine")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", nargs="?")
    parser.add_argument("--obstacle", action="store_true",
                        help="is FetchReachObstacle's box in the way: placed at random against obstacle_on_path")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--substitute", action="store_true",
                        help="pick and place: success with the goal, gripper or cube of φ_enc(I) replaced by the truth")
    parser.add_argument("--probe-box", action="store_true",
                        help="obstacle: how well a linear probe finds the box from the conditioned / all latent features")
    parser.add_argument("--distill-ceiling", action="store_true",
                        help="obstacle, detour teacher: students distilled onto the true s̄ / s̄ + box, the ceiling")
    parser.add_argument("--steps", type=int, help="--distill-ceiling: DAgger steps instead of the run's")
    parser.add_argument("--box-noise", type=float, metavar="CM",
                        help="--distill-ceiling: instead, one student reading the box off by CM per axis (per episode)")
    parser.add_argument("--box-in-view", action="store_true",
                        help="--distill-ceiling: instead, one student reading the box's exact (x, y) in the workspace image")
    parser.add_argument("--goal-noise", type=float, metavar="CM",
                        help="--distill-ceiling --box-in-view: that student and a blind one read s̄'s goal off by CM per axis")
    parser.add_argument("--perception-only", action="store_true",
                        help="only the seen-against-new perception errors (any APRiL env), added to the run's entry")
    args = parser.parse_args()
    path = _common.RESULTS / "april_diagnosis.json"
    results = read_results(path)
    if args.obstacle:
        results["obstacle_in_the_way"] = obstacle_in_the_way(args.episodes * 3)
        _common.write_result("april_diagnosis", results)
        write_report(results)
        print(json.dumps(results["obstacle_in_the_way"], indent=1))
        return
    if not args.run_dir:
        parser.error("give RUN_DIR (or --obstacle)")
    run = AprilRun.resume(args.run_dir)
    if args.substitute or args.probe_box or args.distill_ceiling:
        report = results.get(run.config.name, {})
        if args.distill_ceiling:
            key = "distill_ceiling" if args.steps is None else f"distill_ceiling_{args.steps}_steps"
            report[key] = distill_ceiling(run, args.steps, args.box_noise, args.box_in_view, args.goal_noise)
        if args.substitute:
            report["substitute"] = substitute_truth(run, args.episodes)
        if args.probe_box:
            report["probe_box"] = probe_box(run, args.episodes * 10)
    else:
        report = results.get(run.config.name, {}) if args.perception_only else diagnose(run, args.episodes)
        report["perception_error"] = seen_against_new(run, args.episodes)
    results = read_results(path)  # again: another diagnosis may have written while this one ran
    kept = results.get(run.config.name, {})
    for key in [key for key in report if key.startswith("distill_ceiling")]:  # students another run added stay
        report[key] = kept.get(key, {}) | report[key]
    results[run.config.name] = kept | report
    _common.write_result("april_diagnosis", results)
    write_report(results)
    print(json.dumps({k: v for k, v in report.items() if k != "per_episode"}, indent=1))


def what_it_reads(student: str) -> str:
    """A --distill-ceiling student's name in words: what it reads of the box (and of the goal)."""
    student, _, goal = student.partition("_goal_off_")
    box = {"state": "nothing (blind)", "state_plus_box": "its centre", "state_plus_box_in_view": "its (x, y) in the image"}
    read = box.get(student) or f"centre off by {student.removeprefix('state_plus_box_off_')} per axis"
    return read + (f"; s̄'s goal off by {goal} per axis" if goal else "")


def reports_with(results: dict, key: str) -> dict:
    """{run: its report[key]} for the runs whose diagnosis has ``key``."""
    return {name: report[key] for name, report in results.items() if isinstance(report, dict) and key in report}


def write_report(results: dict) -> None:
    """docs/RESULTS.md: failed against successful episodes (medians), and seen against new perception errors."""
    lines = ["## Why pixels fail where the state succeeds (APRiL diagnosis)", "",
             "`python benchmarks/april_diagnosis.py RUN_DIR` → `results/april_diagnosis.json`. The run's pixel deployment on "
             "its evaluation seeds; per episode the goal's error in φ_enc(I) at the first step (and the part of it along the "
             "workspace camera's ray) and over the episode, the gripper's error, and the share of steps at which no pixel of "
             "the goal sphere is visible (rendered with and without it). Medians, failed / successful episodes.", "",
             "| run | success | failed | goal error at start, cm | of it along the ray, cm | goal error mean, cm | "
             "gripper error mean, cm | steps with goal hidden | failed with goal hidden at start |",
             "|---|---:|---:|---|---|---|---|---|---:|"]
    for name, report in results.items():
        if not isinstance(report, dict) or "median_failed" not in report:
            continue
        failed, ok = report["median_failed"], report["median_succeeded"]

        def pair(key: str, scale: float = 100.0, fmt: str = "{:.1f}") -> str:
            return " / ".join(fmt.format(row[key] * scale) if key in row else "–" for row in (failed, ok))

        lines.append(f"| {name} | {report['success']:.0%} | {failed['episodes']} | {pair('start_goal_error')} | "
                     f"{pair('start_goal_error_along_ray')} | {pair('mean_goal_error')} | {pair('mean_gripper_error')} | "
                     f"{pair('hidden_fraction', 100, '{:.0f}%')} | {report['failed_with_goal_hidden_at_start']} |")
    lines += ["", "Perception's mean absolute error per dimension (cm) on 500 of its own training images against the first "
              "frame of the 100 evaluation episodes, whose goals it never saw (`perception_error`):", "",
              "| run | dimensions | training images | new episodes |", "|---|---|---|---|"]
    for name, report in results.items():
        error = report.get("perception_error") if isinstance(report, dict) else None
        if error:
            lines.append(f"| {name} | {error['dimensions']} | {' '.join(f'{v:.1f}' for v in error['training_images_cm'])} | "
                         f"{' '.join(f'{v:.1f}' for v in error['new_episodes_cm'])} |")
    split = reports_with(results, "by_blocked")
    if split:
        lines += ["", "FetchReachObstacle, the same episodes split by whether the box starts in the detour teacher's way "
                  "(the straight line to the goal passes within 3 cm of it): success, actions, share of episodes in which "
                  "the arm touched the box, and medians of the goal's and gripper's mean error in φ_enc(I) and of the share "
                  "of steps with the goal hidden; for free keypoints, how far the keypoint is from the box's true place "
                  "in the image (image width = 2):", "",
                  "| run | box in the way? | episodes | success | actions | touched the box | goal error, cm | "
                  "gripper error, cm | goal hidden | keypoint off the box |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for name, halves in split.items():
            for label, row in halves.items():
                lines.append(f"| {name} | {'in the way' if label == 'blocked' else 'clear'} | {row['episodes']} | "
                             f"{row['success']:.0%} | {row['avg_actions']:.2f} | {row['touched_box']:.0%} | "
                             f"{row['median_mean_goal_error_cm']:.2f} | {row['median_mean_gripper_error_cm']:.2f} | "
                             f"{row['median_goal_hidden_fraction']:.0%} | "
                             + (f"{row['median_mean_keypoint_error']:.3f} |" if "median_mean_keypoint_error" in row else "– |"))
    swapped = reports_with(results, "substitute")
    if swapped:
        lines += ["", "Pick and place on pixels with one part of φ_enc(I) replaced by the simulator's truth (`--substitute`): "
                  "success, share of episodes in which the cube was lifted > 2 cm, and the perceived cube's median error "
                  "while the gripper is within 3 cm of it:", "",
                  "| run | episodes | " + " | ".join(SUBSTITUTES) + " |", "|---|---:|" + "---|" * len(SUBSTITUTES)]
        for name, swap in swapped.items():
            cells = [f"{row['success']:.0%} (lifted {row['lifted']:.0%}, cube {row['object_error_near_gripper_cm'] or 0:.1f} cm)"
                     for row in (swap["rows"][key] for key in SUBSTITUTES)]
            lines.append(f"| {name} | {swap['episodes']} | " + " | ".join(cells) + " |")
    probed = reports_with(results, "probe_box")
    if probed:
        lines += ["", "Do the latent features carry FetchReachObstacle's box (`--probe-box`)? A linear probe fit on 500 reset "
                  "images and scored on 500 others: the box centre's mean error (cm) from the training mean alone, from the "
                  "m conditioned features (s̄; on the path the box lies between gripper and goal) and from all n; then the "
                  "same with 10 nearest neighbours (standardised features), for a code that is not linear:", "",
                  "| run | n | m | mean only | conditioned | all | conditioned (k-NN) | all (k-NN) |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for name, probe in probed.items():
            error = probe["box_error_cm"]
            knn = probe.get("box_error_knn_cm", {})
            lines.append(f"| {name} | {probe['latent']} | {probe['conditioned']} | {error['mean_only']:.2f} | "
                         f"{error['conditioned']:.2f} | {error['all']:.2f} | {knn.get('conditioned', float('nan')):.2f} | "
                         f"{knn.get('all', float('nan')):.2f} |")
        decided = {name: probe for name, probe in probed.items() if "blocked_knn_accuracy" in probe}
        if decided:
            lines += ["", "Can the features tell the teacher's decision, go round or straight (box within 3 cm of the "
                      "straight line)? 10 nearest neighbours on the same 500 / 500 images, accuracy; beside it the same "
                      "from the simulator's s̄, and s̄ and box centre:", "",
                      "| run | in the way | conditioned | all | true s̄ | true s̄ and box |", "|---|---:|---:|---:|---:|---:|"]
            for name, probe in decided.items():
                accuracy = probe["blocked_knn_accuracy"]
                lines.append(f"| {name} | {probe['blocked_share']:.0%} | {accuracy['conditioned']:.0%} | {accuracy['all']:.0%} | "
                             f"{accuracy['true_state']:.0%} | {accuracy['true_state_and_box']:.0%} |")
    ceilings = [(name, key, report[key]) for name, report in results.items() if isinstance(report, dict)
                for key in sorted(report) if key.startswith("distill_ceiling")]
    if ceilings:
        lines += ["", "What would perfect perception give a student distilled from the detour teacher (`--distill-ceiling`)? "
                  "Students that read the simulator's s̄, or s̄ and the box centre, in place of φ_enc(I), learn by the run's "
                  "own DAgger (network, rounds, seeds; `--steps` for a longer one) and play its 100 evaluation episodes "
                  "(the teacher on `obstacle_on_path: 1.0`: 97%, 6.86 actions; on 0.5: 99%, 4.38):", "",
                  "| run's DAgger | steps | student reads s̄: success | actions | s̄ and the box: success | actions |",
                  "|---|---:|---:|---:|---:|---:|"]
        for name, key, ceiling in ceilings:
            state, boxed = ceiling.get("state", {}), ceiling.get("state_plus_box", {})
            cells = [f"{row['success']:.0%} | {row['avg_actions']:.2f}" if row else "– | –" for row in (state, boxed)]
            steps = (boxed or state).get("sim_steps", 0)
            lines.append(f"| {name} | {steps:,} | " + " | ".join(cells) + " |")
        partial = [(name, student, row) for name, key, ceiling in ceilings for student, row in ceiling.items()
                   if student not in ("state", "state_plus_box")]
        if partial:
            lines += ["", "The box as perception would give it: a student reading s̄ and the box centre off by a Gaussian "
                      "offset of CM per axis, drawn once per episode (`--box-noise CM`), or s̄ and the box centre's exact "
                      "(x, y) in the workspace image, what a free keypoint on the box gives, n = 8, m = 6 "
                      "(`--box-in-view`), with s̄'s goal off by CM per axis per episode as φ_enc(I)'s is "
                      "(`--goal-noise CM`); same DAgger:", "",
                      "| run's DAgger | steps | what the student reads of the box | success | actions |",
                      "|---|---:|---|---:|---:|"]
            for name, student, row in partial:
                lines.append(f"| {name} | {row['sim_steps']:,} | {what_it_reads(student)} | {row['success']:.0%} | "
                             f"{row['avg_actions']:.2f} |")
    box = results.get("obstacle_in_the_way")
    if box:
        lines += ["", f"Is FetchReachObstacle's box in the way (`--obstacle`; {box['at_random']['episodes']} episodes, seeds 20000+)? "
                  "Share of episodes whose box comes within 4 cm of / crosses the straight line from the gripper to the goal, "
                  "and a controller that drives straight at the goal, blind to the box:", "",
                  "| placement | within 4 cm of the line | crossing it | straight line: success | straight line: actions |",
                  "|---|---:|---:|---:|---:|"]
        for world, row in box.items():
            lines.append(f"| {world} `{row['env_kwargs'] or '{}'}` | {row['within_4cm_of_line']:.0%} | {row['crossing_line']:.0%} | "
                         f"{row['straight_line_success']:.0%} | {row['straight_line_avg_actions']:.2f} |")
    _common.write_section("april_diagnosis", "\n".join(lines))


if __name__ == "__main__":
    main()

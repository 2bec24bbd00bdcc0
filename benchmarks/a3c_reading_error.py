"""Is it the pose-tied error of a pixel network's reading that slows A3C on Arm2D?

    python benchmarks/a3c_reading_error.py [--only tied shuffled precise] [--steps 175000]
        [--reader-run RUN_DIR] [--keypoints PATH] [--state-run RUN_DIR] [--also KEY=RUN_DIR ...]

The state learner (configs/rl_arm2d_curriculum_state_entropy.yaml: the single goal for its first 400k
steps) is trained for ``--steps`` on three inputs, each a ``wrap_env`` of binpick.rl.a3c_train:
  tied      the state that A3C's own pixel network (``--reader-run``: its auxiliary state head, frozen)
            reads off each 32 px picture -- what the detached bottleneck acted on;
  shuffled  the true state plus that network's reading error on another picture, a random one of 4,000
            (rl.wrappers.ReadingErrors): the same errors, untied from the pose;
  precise   the state the APRiL keypoint network (``--keypoints``, made by benchmarks/rl_arm2d_april.py)
            reads off each 64 px picture, frozen (binpick.april.arm2d.ReadStateOffPixels).
Their training episodes per 25k steps (benchmarks/a3c_learning_pace.py's reading of TensorBoard) are set
beside the state learner's own (``--state-run``), with each reader's error on the same 4,000 pictures.
Writes results/a3c_reading_error.json, docs/img/a3c_reading_error.png and a section of docs/RESULTS.md.
Each run resumes from its last checkpoint. ~10-20 min a run on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, os.path.dirname(__file__))

import _common  # noqa: E402
import a3c_learning_pace  # noqa: E402

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from gymnasium import spaces  # noqa: E402

CONFIG = _common.ROOT / "configs" / "rl_arm2d_curriculum_state_entropy.yaml"
FOLDER = _common.ROOT / "runs" / "bench" / "a3c_reading_error"
READER_RUN = "runs/explore/arm2d_curriculum_keypoints_bottleneck_detached/20261202-153424"
STATE_RUN = "runs/explore/state_noise_0/20261202-152647"
KEYPOINTS = "runs/bench/arm2d_keypoints/keypoints.safetensors"
PICTURES, PICTURE_SEED = 4000, 600_000
VARIANTS = {"tied": {"goal_conditioned": True, "image": "rgb", "image_size": 32},
            "shuffled": {"goal_conditioned": True, "image": None},
            "precise": {"goal_conditioned": True, "image": "rgb", "image_size": 64}}


def flat_state(continuous: np.ndarray) -> np.ndarray:
    """Arm2D's ``state_continuous`` rows (cos 3, sin 3, end point, goal) as the state learner's flattened
    goal-env observation (achieved goal, desired goal, observation = cos, sin, end point)."""
    c = np.atleast_2d(continuous)
    return np.concatenate([c[:, 6:8], c[:, 8:10], c[:, 0:6], c[:, 6:8]], axis=1)


def a3c_reader(run: str):
    from binpick.rl.a3c_train import load_a3c_policy
    from binpick.runs import latest_checkpoint

    checkpoint = latest_checkpoint(_common.ROOT / run / "checkpoints")
    if checkpoint is None:
        sys.exit(f"{run}: no checkpoint")
    model = load_a3c_policy(checkpoint).model
    if model.state is None:
        sys.exit(f"{run}: its network has no auxiliary state head to read with")

    @torch.no_grad()
    def read(images: np.ndarray) -> np.ndarray:
        images = np.asarray(images)
        batch = torch.from_numpy(images[None] if images.ndim == 3 else images)
        return flat_state(model.state(model.features(batch)).numpy().astype(np.float64))

    return read


class _ReadByNetwork(gym.ObservationWrapper):
    def __init__(self, env: gym.Env, read) -> None:
        super().__init__(env)
        self.read = read
        self.observation_space = spaces.Box(-np.inf, np.inf, (12,), np.float64)

    def observation(self, observation):
        return self.read(observation["image"])[0]


@dataclass(frozen=True)
class ReadWithA3C:
    """wrap_env: the state A3C's frozen pixel network reads off each picture (pose-tied error)."""
    run: str

    def __call__(self, env: gym.Env) -> gym.Env:
        return _ReadByNetwork(env, a3c_reader(self.run))


@dataclass(frozen=True)
class ShuffledErrors:
    """wrap_env: the true flattened state plus a random row of a saved table of reading errors."""
    table: str

    def __call__(self, env: gym.Env) -> gym.Env:
        from gymnasium.wrappers import FlattenObservation

        from binpick.rl.wrappers import ReadingErrors

        return ReadingErrors(FlattenObservation(env), np.load(self.table, allow_pickle=False))


def pictures(image_size: int) -> tuple[np.ndarray, np.ndarray]:
    """PICTURES seeded random poses at the single goal: images and true flattened states."""
    from binpick.envs.arm2d import Arm2DEnv

    env = Arm2DEnv(image_size=image_size, goal_conditioned=True, image="rgb", goal_area=0.0)
    images, states = [], []
    for index in range(PICTURES):
        observation, info = env.reset(seed=PICTURE_SEED + index)
        images.append(observation["image"])
        states.append(info["state_continuous"])
    env.close()
    return np.stack(images), flat_state(np.stack(states))


def error_summary(errors: np.ndarray) -> dict:
    """Median / 95th percentile of the end-point and goal errors (play-area units; success radius 0.07)."""
    end, goal = np.linalg.norm(errors[:, 0:2], axis=1), np.linalg.norm(errors[:, 2:4], axis=1)
    return {"end_point_median": float(np.median(end)), "end_point_p95": float(np.percentile(end, 95)),
            "goal_median": float(np.median(goal)), "goal_p95": float(np.percentile(goal, 95)),
            "cos_sin_rms": float(np.sqrt(np.mean(errors[:, 4:10] ** 2)))}


def reader_errors(reader_run: str, keypoints: Path) -> dict:
    """Each reader's errors on the same pictures; the A3C network's table is saved for ``shuffled``."""
    from binpick.april.arm2d import load_keypoints, state_from_keypoints

    FOLDER.mkdir(parents=True, exist_ok=True)
    images, truth = pictures(32)
    read = np.concatenate([a3c_reader(reader_run)(images[i:i + 500]) for i in range(0, len(images), 500)])
    errors = read - truth
    np.save(FOLDER / "a3c_reading_errors.npy", errors)
    summary = {"tied": error_summary(errors)}
    if keypoints.is_file():
        model = load_keypoints(keypoints)
        images64, truth64 = pictures(64)
        points = np.concatenate([model.keypoints(images64[i:i + 256]) for i in range(0, len(images64), 256)])
        flat = np.stack([spaces.flatten(_STATE_SPACE, state_from_keypoints(p)) for p in points])
        summary["precise"] = error_summary(flat - truth64)
    return summary


_STATE_SPACE = spaces.Dict({"achieved_goal": spaces.Box(-np.inf, np.inf, (2,)), "desired_goal": spaces.Box(-np.inf, np.inf, (2,)),
                            "observation": spaces.Box(-np.inf, np.inf, (8,))})


def train(variant: str, steps: int, wrap_env) -> Path:
    from binpick.config import load_run_config
    from binpick.rl.a3c_train import A3CTrainer
    from binpick.rl.config import RLConfig, load_rl_config
    from binpick.terminal import RichCallback

    config = load_rl_config(CONFIG, {"name": f"a3c_reading_{variant}", "total_timesteps": steps,
                                     "env_kwargs": VARIANTS[variant]})
    latest = _common.latest_run(FOLDER, config.name)
    if latest is not None and load_run_config(RLConfig, latest) == config:
        print(f"{config.name}: continuing {latest}", flush=True)
        trainer = A3CTrainer.resume(latest, wrap_env)
    else:
        trainer = A3CTrainer.new(config, FOLDER, wrap_env)
    with RichCallback() as callback:
        trainer.run(callback)
    return trainer.run_dir


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", choices=list(VARIANTS), default=list(VARIANTS))
    parser.add_argument("--steps", type=int, default=175_000)
    parser.add_argument("--reader-run", default=READER_RUN)
    parser.add_argument("--keypoints", default=KEYPOINTS)
    parser.add_argument("--state-run", default=STATE_RUN)
    parser.add_argument("--also", nargs="*", default=[], metavar="KEY=RUN_DIR",
                        help="more curves, e.g. precise=<the read-state curriculum run of rl_arm2d.py>, whose first steps "
                             "are this benchmark's precise run")
    parser.add_argument("--note", default="", help="a paragraph for docs/RESULTS.md: what the runs show")
    args = parser.parse_args()
    from binpick.april.arm2d import ReadStateOffPixels

    keypoints = _common.ROOT / args.keypoints
    errors = reader_errors(args.reader_run, keypoints)
    print("reading errors:", errors, flush=True)
    wraps = {"tied": ReadWithA3C(args.reader_run), "shuffled": ShuffledErrors(str(FOLDER / "a3c_reading_errors.npy")),
             "precise": ReadStateOffPixels(str(keypoints))}
    if "precise" in args.only and not keypoints.is_file():
        sys.exit(f"{args.keypoints}: no keypoint weights; make them with benchmarks/rl_arm2d_april.py")
    runs = {"state": _common.ROOT / args.state_run}
    for variant in VARIANTS:
        latest = _common.latest_run(FOLDER, f"a3c_reading_{variant}")
        if variant in args.only:
            latest = train(variant, args.steps, wraps[variant])
        if latest is not None:
            runs[variant] = latest
    runs |= dict(_common.keyed_run_dirs(args.also))
    curves = {key: a3c_learning_pace.curve(run, 25_000, args.steps) for key, run in runs.items()}
    _common.write_result("a3c_reading_error", {"steps": args.steps, "bucket": 25_000, "reader_run": args.reader_run,
                                               "keypoints": args.keypoints, "pictures": PICTURES, "reading_errors": errors,
                                               "runs": curves, "peak_rss_mib": round(_common.peak_rss_mib(), 1)})
    image = _common.ROOT / "docs" / "img" / "a3c_reading_error.png"
    a3c_learning_pace.plot(curves, image, "Arm2D, single goal: A3C on read states and from pixels")
    describe = {"state": "the true state (the state learner: two layers on the state)",
                "tied": "read by A3C's pixel network (frozen)", "shuffled": "true + that network's errors, shuffled",
                "precise": "read by the APRiL keypoint network (frozen)",
                "state_one_layer": "the true state, one layer on it (a3c.hidden_layers: 0)",
                "pixels": "pixels, pretrained, one layer above the keypoints (the runs so far)",
                "pixels_deep": "pixels, pretrained, two layers above the keypoints (a3c.hidden_layers: 2)",
                "bottleneck": "pixels, bottleneck: one layer on the state estimate",
                "bottleneck_deep": "pixels, bottleneck: two layers on the state estimate (a3c.hidden_layers: 2)"}
    _common.write_section("a3c_reading_error", "\n".join([
        "## What slows A3C from pixels on Arm2D's single goal: the reading, or the network above it?",
        "",
        f"`python benchmarks/a3c_reading_error.py --steps {args.steps} --also KEY=RUN ...`: mean length of each run's own "
        "training episodes per 25,000 steps at the single goal (`rl_arm2d_curriculum_*` configs). Reading errors on the "
        f"same {PICTURES:,} seeded pictures (median end point / goal, play-area units; success radius 0.07): "
        + "; ".join(f"{key}: {e['end_point_median']:.3f} / {e['goal_median']:.3f}" for key, e in errors.items()) + ". "
        + "Runs: " + "; ".join(f"{key}, {describe.get(key, key)}: `{curves[key]['run_dir']}`"
                               for key, run in runs.items()) + ".",
        "",
        *a3c_learning_pace.table(curves, 25_000),
        "",
        *([args.note, ""] if args.note else []),
        "![training episodes per step](img/a3c_reading_error.png)",
    ]))
    for key, measured in curves.items():
        print(key, [round(b["mean_length"], 1) for b in measured["buckets"]])


if __name__ == "__main__":
    main()

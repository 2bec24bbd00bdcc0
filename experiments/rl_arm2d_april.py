"""Table 3.2 from pixels the APRiL way: A3C state runs deployed on pixels through learnt keypoints.

    python experiments/rl_arm2d_april.py KEY=RUN_DIR [KEY=RUN_DIR ...] [--images 12000] [--epochs 12]

Trains (or reuses) the Arm2D keypoint network (binpick.april.arm2d; runs/bench/arm2d_keypoints/
keypoints.safetensors, remade with --retrain) on rendered random poses and goals, measures its error on
2,000 held-out images, then plays each run's state policy on the 200 seeded whole-area episodes of
experiments/rl_arm2d.py -- the same seeds as the state rows -- from the image alone, greedy and sampling.
Rows ``KEY_pixels`` and ``KEY_pixels_sampled`` are merged into results/rl_arm2d.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time


import _common  # noqa: E402
import rl_arm2d  # noqa: E402

FOLDER = _common.ROOT / "runs" / "bench" / "arm2d_keypoints"
TRAIN_SEED, HELD_OUT_SEED = 3_000_000, 4_000_000  # away from the evaluation episodes' seeds (50,000 on)


def perception(images: int, epochs: int, retrain: bool) -> tuple[object, dict]:
    import torch

    from binpick.april.arm2d import collect, keypoint_errors, load_keypoints, save_keypoints, train_keypoints
    from binpick.cli.terminal import RichCallback

    torch.set_num_threads(2)
    path = FOLDER / "keypoints.safetensors"
    if path.is_file() and not retrain:
        model, info = load_keypoints(path), json.loads((FOLDER / "keypoints.json").read_text())
        print(f"keypoints: reusing {path}", flush=True)
        return model, info
    start = time.time()
    pictures, points = collect(images, TRAIN_SEED)
    with RichCallback() as callback:
        model, history = train_keypoints(pictures, points, epochs=epochs, callback=callback)
    held_pictures, held_points = collect(2000, HELD_OUT_SEED)
    info = {"train_images": images, "epochs": epochs, "seconds": round(time.time() - start, 1), "history": history,
            "held_out_images": 2000, "held_out": keypoint_errors(model, held_pictures, held_points)}
    FOLDER.mkdir(parents=True, exist_ok=True)
    save_keypoints(model, path, **{k: v for k, v in info.items() if k != "history"})
    from binpick.core.files import atomic_write_text

    atomic_write_text(FOLDER / "keypoints.json", json.dumps(info, indent=1))
    return model, info


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rows", nargs="+", help="KEY=RUN_DIR (an A3C run with a3c.encoder: state)")
    parser.add_argument("--images", type=int, default=12000)
    parser.add_argument("--epochs", type=int, default=12)
    parser.add_argument("--retrain", action="store_true")
    args = parser.parse_args()
    from binpick.april.arm2d import PixelsAsArm2DState
    from binpick.envs import make
    from binpick.rl.common.evaluate import evaluate_policy

    model, info = perception(args.images, args.epochs, args.retrain)
    print("keypoints held out:", {k: round(v, 4) for k, v in info["held_out"].items()}, flush=True)
    rows = {}
    for key, run, policy, config, metrics in rl_arm2d.keyed_runs(args.rows):
        if config.a3c.encoder != "state":
            sys.exit(f"{run}: a3c.encoder is {config.a3c.encoder!r}; deploying on pixels needs a state run")
        for deterministic, suffix in ((True, "_pixels"), (False, "_pixels_sampled")):
            env = PixelsAsArm2DState(make(config.env, goal_conditioned=True, image="rgb", goal_area=1.0),
                                     lambda image: model.keypoints(image)[0])
            result = evaluate_policy(policy, env, episodes=rl_arm2d.EPISODES, seed=50_000, deterministic=deterministic)
            env.close()
            rows[key + suffix] = {"mean": result.mean_length, "std": result.std_length, "success_rate": result.success_rate,
                                  "episodes": rl_arm2d.EPISODES, "goal_area": 1.0, "deterministic": deterministic,
                                  "sim_steps": metrics["sim_steps"], "run_dir": run,
                                  "perception": {"file": str(FOLDER.relative_to(_common.ROOT) / "keypoints.safetensors"),
                                                 "train_images": info["train_images"], "epochs": info["epochs"],
                                                 "seconds": info["seconds"], **info["held_out"]}}
            print(key + suffix, f"{result.mean_length:.1f} ± {result.std_length:.1f}, success {result.success_rate:.0%}",
                  flush=True)
    rl_arm2d.merge_rows(rows)


if __name__ == "__main__":
    main()

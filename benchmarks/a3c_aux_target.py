"""What should A3C's auxiliary head regress? Arm2D's joint angles raw, or as cos/sin (Table 3.2).

    python benchmarks/a3c_aux_target.py [--sizes 32 64] [--updates 6000]

``a3c.state_weight`` makes the trunk's features also regress the arm's semantic state, so that they
say where the end point and the goal are before the sparse reward teaches it. ``info["state"]`` holds
the joint angles raw, wrapped to [-π, π): a target with a jump that the network cannot follow and
whose variance (π²/3 a joint) is ten times the end point's and the goal's, so the loss is mostly
about the jump. ``info["state_continuous"]`` holds cos and sin of each angle instead. Without RL,
this trains A3C's keypoints network (:class:`binpick.rl.a3c.ActorCritic` and its state head) on each
target exactly as the auxiliary loss does (Adam at A3C's learning rate 1e-4, 20 pictures an update,
goals anywhere) and reports the median error of the end point and the goal it reads on 1,000 held-out
pictures, in play-area units (the success radius is 0.07). About 1.5 min a row at 32 px and 4.5 min at
64 px on one core. Writes results/a3c_aux_target.json and its section of docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.dirname(__file__))

import _common  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from binpick.envs.arm2d import Arm2DEnv  # noqa: E402
from binpick.rl.a3c import ActorCritic  # noqa: E402

TARGETS = {"state": 7, "state_continuous": 10}  # info key -> length; both end with end point (2), goal (2)
LEARNING_RATE = 1e-4  # A3C's (configs/rl_arm2d_*.yaml)
BATCH = 20  # one A3C rollout (n_steps)


def pictures(size: int, count: int, seed: int) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """``count`` pictures with goals anywhere and, per target key, their (count, D) targets."""
    env = Arm2DEnv(image_size=size, goal_area=1.0)
    images, targets = [], {key: [] for key in TARGETS}
    for index in range(count):
        image, info = env.reset(seed=seed + index)
        images.append(image)
        for key in TARGETS:
            targets[key].append(info[key])
    return torch.from_numpy(np.stack(images)), {key: torch.as_tensor(np.stack(v), dtype=torch.float32) for key, v in targets.items()}


def train_row(size: int, key: str, updates: int, train, held_out, every: int = 1000) -> dict:
    """Train the keypoints network's state head on ``key`` alone; errors of end point and goal on the way."""
    (images, targets), (test_images, test_targets) = train, held_out
    torch.manual_seed(0)
    model = ActorCritic((size, size, 3), 6, "keypoints", state_size=TARGETS[key])
    optimizer = torch.optim.Adam(model.parameters(), lr=LEARNING_RATE)
    truth = test_targets["state"]  # angles (3), end point (2), goal (2)
    rng = np.random.default_rng(0)
    curve, started = [], time.perf_counter()
    for update in range(updates + 1):
        if update % every == 0:
            with torch.no_grad():
                predicted = model.state(model.features(test_images))
            curve.append({"updates": update,
                          "end_point": float((predicted[:, -4:-2] - truth[:, 3:5]).norm(dim=1).median()),
                          "goal": float((predicted[:, -2:] - truth[:, 5:7]).norm(dim=1).median())})
            print(f"{size} px {key}: {curve[-1]}", flush=True)
        if update == updates:
            break
        batch = torch.as_tensor(rng.integers(0, len(images), BATCH))
        loss = (model.state(model.features(images[batch])) - targets[key][batch]).pow(2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return {"image_size": size, "target": key, "updates": updates, "end_point": curve[-1]["end_point"],
            "goal": curve[-1]["goal"], "curve": curve, "wall_seconds": round(time.perf_counter() - started, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[32, 64])
    parser.add_argument("--updates", type=int, default=6000)
    parser.add_argument("--train-pictures", type=int, default=20_000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = []
    for size in args.sizes:
        train, held_out = pictures(size, args.train_pictures, 0), pictures(size, 1000, 10**6)
        rows += [train_row(size, key, args.updates, train, held_out) for key in TARGETS]
    _common.write_result("a3c_aux_target", {"rows": rows, "learning_rate": LEARNING_RATE, "batch": BATCH,
                                            "train_pictures": args.train_pictures,
                                            "peak_rss_mib": round(_common.peak_rss_mib(), 1)})
    table = [f"| {r['image_size']} px | `info[\"{r['target']}\"]` | {r['updates']:,} | {r['end_point']:.3f} | {r['goal']:.3f} |"
             for r in rows]
    _common.write_section("a3c_aux_target", "\n".join([
        "### What A3C's auxiliary head should regress",
        "",
        "`python benchmarks/a3c_aux_target.py`: A3C's keypoints network and state head trained on the auxiliary "
        f"target alone (Adam {LEARNING_RATE:g}, {BATCH} pictures an update, goals anywhere, "
        f"{args.train_pictures:,} pictures); median error on 1,000 held-out pictures (success radius 0.07). "
        "Raw angles jump at ±π and carry most of the target's variance; as cos/sin they do neither.",
        "",
        "| pictures | target | updates | end point | goal |",
        "|---|---|---:|---:|---:|",
        *table,
    ]))


if __name__ == "__main__":
    main()

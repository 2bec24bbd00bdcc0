"""How deterministic is one grasp's pickability label? (issues 16 and 17)

    python benchmarks/label_noise.py [--data runs/data/bins_2000] [--worlds 15] [--scenes 2]

For target instances of binpick's default bins (the worlds of --data's generator settings), Policy
y's grasp runs from the saved scene state as the generator runs it, then four times more with the
jaws' centre moved by 2 mm along +-x and +-y — less than one pixel of the 416 px camera. An
instance whose outcome changes is one whose label no image can predict for sure. Writes
results/label_noise.json and its section of docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.dirname(__file__))

import _common  # noqa: E402
import numpy as np  # noqa: E402

JITTER = 0.002


def main() -> None:
    from binpick.sim.gripper import TopDownGrasp
    from binpick.warehouse.dataset import (GenerateConfig, build_library, grasp_outcomes, label_offsets, trial_ready,
                                           world_scene, world_sim)

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="runs/data/bins_2000")
    parser.add_argument("--worlds", type=int, default=15)
    parser.add_argument("--scenes", type=int, default=2, help="scenes per world")
    args = parser.parse_args()
    stored = json.loads((_common.ROOT / args.data / "dataset.json").read_text())["config"]
    config = GenerateConfig(out="unused", **{k: v for k, v in stored.items()
                                             if k in GenerateConfig.__dataclass_fields__ and k not in ("out", "scenes")})
    library, policy = build_library(config), TopDownGrasp("y")
    offsets = label_offsets(5, JITTER, np.random.default_rng(0))
    outcomes: list[list[bool]] = []
    for world in range(args.worlds):
        sim, products, _ = world_sim(config, world, library, gripper=True)
        try:
            for index in range(args.scenes):
                scene, _ = world_scene(sim, config, world, index)
                trial_ready(sim)
                outcomes += [grasp_outcomes(sim, scene.state, policy, instance.slot, offsets)
                             for instance in scene.instances if instance.is_target]
        finally:
            sim.close()
        print(f"world {world} ({products[0].name}): {len(outcomes)} instances so far", flush=True)
    nominal = [o[0] for o in outcomes]
    changed = [any(v != o[0] for v in o[1:]) for o in outcomes]
    result = {"instances": len(outcomes), "worlds": args.worlds, "scenes_per_world": args.scenes, "policy": "y",
              "jitter_m": JITTER, "held_nominal": int(sum(nominal)), "label_changes": int(sum(changed)),
              "label_change_rate": float(np.mean(changed)),
              "changes_among_held": int(sum(c for c, n in zip(changed, nominal) if n)),
              "changes_among_not_held": int(sum(c for c, n in zip(changed, nominal) if not n)),
              "success_share_histogram": {"bins": [0, 0.1, 0.3, 0.5, 0.7, 0.9, 1.0],
                                          "counts": np.histogram([np.mean(o) for o in outcomes],
                                                                 bins=[0, 0.1, 0.3, 0.5, 0.7, 0.9, 1.01])[0].tolist()},
              "peak_rss_mib": round(_common.peak_rss_mib(), 1)}
    _common.write_result("label_noise", result)
    _common.write_section("label_noise", "\n".join([
        "## How deterministic is a pickability label? (issues 16, 17)", "",
        f"Policy y's grasp on {result['instances']} target instances of binpick's default bins ({args.worlds} worlds × "
        f"{args.scenes} scenes), then with the jaws moved by 2 mm along ±x and ±y (under a pixel): the outcome changed for "
        f"**{result['label_changes']}** ({result['label_change_rate']:.0%}) — {result['changes_among_held']} of "
        f"{result['held_nominal']} that held, {result['changes_among_not_held']} of "
        f"{result['instances'] - result['held_nominal']} that did not. Labels from one grasp carry that much noise that no "
        "image shows; `binpick data generate --set label_trials=5` labels by the majority of five such grasps. "
        "`python benchmarks/label_noise.py` → `results/label_noise.json`.",
    ]))
    print(json.dumps(result))


if __name__ == "__main__":
    main()

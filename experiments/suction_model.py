"""Which way to simulate a suction cup: MuJoCo's ``adhesion`` actuator, or a weld made only when the
lip's ring seals and broken when the vacuum's limits are passed (binpick's ``Vacuum``)?

    python experiments/suction_model.py       # results/suction_model.json, a section of docs/RESULTS.md

The same cup (30 mm, 30 N) tries the cases that decide a real cell's picks, each product alone in the
tote, the cup pressed on at the given place and lifted 15 cm, held 1 s and carried sideways at the
pick pipeline's speed: a box face at its centre (a real cup lifts it), the box's edge (half the lip in
the air: no seal), a small ball (its curve leaves the lip's ring), a lying can's side (the ring is
not flat across its curve), and a 1 kg bar held at its centre and 8 cm from it (the seal peels). The
adhesion actuator pulls at whatever contacts the cup has (its gain set so the pull at full control is
the vacuum's 30 N), so the case table shows which model fails where a real cup fails.
"""

from __future__ import annotations

import json
import os
import sys

os.environ.setdefault("MUJOCO_GL", "egl")

import _common  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

CASES = [  # name, product (shape, half sizes m, mass kg), where the cup goes (m from the centre along the long axis), real cup
    ("box face, centre", ("box", (0.05, 0.04, 0.03), 0.3), 0.0, True),
    ("box edge", ("box", (0.05, 0.04, 0.03), 0.05), 0.05, False),
    ("small ball, top", ("sphere", (0.03,), 0.2), 0.0, False),
    ("lying can, side", ("cylinder", (0.033, 0.06), 0.3), 0.0, False),
    ("1 kg bar, centre", ("box", (0.11, 0.025, 0.02), 1.0), 0.0, True),
    ("1 kg bar, 8 cm off centre", ("box", (0.11, 0.025, 0.02), 1.0), 0.08, False),
]


def adhesion_trial(world, tips, yaw: float) -> bool:
    """The same lift with an adhesion actuator on the cup in place of the vacuum's weld."""
    from binpick.sim.gripper import CARRY_TRIAL, HOLD_SECONDS, LIFT_SUCCESS, SUCTION_PRESS

    model, data, gripper = world.model, world.data, world.gripper
    body = world.body_ids[0]
    start = data.xipos[body][2]
    gripper.use(data, "suction")
    below = gripper.tool_point_below()
    actuator = model.actuator("adhesion").id
    x, y, z = tips
    gripper.teleport(data, [x, y, z + below + 0.08], yaw)
    mujoco.mj_forward(model, data)

    def move(target, seconds: float, on: bool) -> None:
        begin = data.mocap_pos[gripper.mocap].copy()
        steps = max(1, int(seconds / model.opt.timestep))
        for step in range(steps):
            data.mocap_pos[gripper.mocap] = begin + (np.asarray(target) - begin) * (step + 1) / steps
            data.ctrl[actuator] = 1.0 if on else 0.0
            mujoco.mj_step(model, data)

    move([x, y, z + below - SUCTION_PRESS], 0.3, False)
    move([x, y, z + below - SUCTION_PRESS], 0.3, True)
    lifted = [x, y, z + below + 0.15]
    move(lifted, 0.5, True)
    move(lifted, HOLD_SECONDS, True)
    move([x + CARRY_TRIAL[0], y + CARRY_TRIAL[1], lifted[2]], CARRY_TRIAL[2], True)
    move(data.mocap_pos[gripper.mocap].copy(), 0.3, True)
    return bool(data.xipos[body][2] - start >= LIFT_SUCCESS)


def trial(case, model_kind: str) -> tuple[bool, str | None]:
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.gripper import lift_test, trial_timestep
    from binpick.sim.mjcf import CameraSpec
    from binpick.sim.products import Product
    from binpick.grippers import SuctionCup

    name, (shape, size, mass), along, _ = case
    product = Product(f"test/{shape}", "test", shape=shape, size=size, mass=mass)
    extra = ""
    if model_kind == "adhesion":  # gain: the pull at control 1 is the vacuum's force
        extra = f'<actuator><adhesion name="adhesion" body="cup" ctrlrange="0 1" gain="{SuctionCup().vacuum_force}"/></actuator>'
    world = BinWorld(product, [], max_copies=1, camera=CameraSpec(size=48), gripper="suction", extra=extra)
    try:
        scene = world.scene(1, 0, seed=0)
        world.set_guards(False)
        world.restore(scene.state)
        body = world.body_ids[0]
        rotation = world.data.xmat[body].reshape(3, 3)
        axis = rotation[:, 0][:2] / max(np.linalg.norm(rotation[:, 0][:2]), 1e-9)
        x, y = world.data.xpos[body][:2] + along * axis
        geom = np.zeros((1, 1), np.int32)
        z = 1.0 - mujoco.mj_ray(world.model, world.data, np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0]),
                                np.array([1, 1, 1, 0, 1, 1], np.uint8), 1, -1, geom)
        with trial_timestep(world.model):
            if model_kind == "adhesion":
                return adhesion_trial(world, (x, y, z), 0.0), None
            held = lift_test(world, 0, (x, y, z), 0.0, z, carry=True, tool="suction")
            return held, world.gripper.vacuum.why
    finally:
        world.close()


def section(result: dict) -> str:
    """The suction-model section of docs/RESULTS.md, from results/suction_model.json."""
    rows, agree = result["cases"], result["agrees_with_a_real_cup"]
    lines = ["## How the suction cup is simulated", "",
             "`python experiments/suction_model.py` → `results/suction_model.json`: the same 30 mm, 30 N cup on six cases, "
             "each lifted 15 cm, held 1 s and carried sideways, with MuJoCo's `adhesion` actuator (its pull at full control the "
             "vacuum's 30 N) and with binpick's seal-and-wrench model (a weld made only where the lip's ring seals, broken past "
             "the vacuum's pull, shear, peel and twist limits). A real cup's outcome is the one the case is chosen for.", "",
             "| case | a real cup | seal and wrench (why not) | adhesion |", "|---|---|---|---|"]
    for row in rows:
        why = f" ({row['why']})" if row["why"] else ""
        lines.append(f"| {row['case']} | {lifts(row['real_cup'])} | {lifts(row['seal_and_wrench'])}{why} | {lifts(row['adhesion'])} |")
    lines += ["", f"Agreement with a real cup: seal and wrench {agree['seal_and_wrench']} of {len(rows)}, adhesion "
              f"{agree['adhesion']} of {len(rows)}. binpick simulates the cup with the seal-and-wrench model."]
    return "\n".join(lines)


def lifts(held: bool) -> str:
    return "lifts" if held else "fails"


def main() -> None:
    rows = []
    for case in CASES:
        weld, why = trial(case, "seal")
        adhesion, _ = trial(case, "adhesion")
        rows.append({"case": case[0], "real_cup": case[3], "seal_and_wrench": weld, "why": why, "adhesion": adhesion})
        print(json.dumps(rows[-1]), flush=True)
    agree = {kind: sum(row[kind] == row["real_cup"] for row in rows) for kind in ("seal_and_wrench", "adhesion")}
    result = {"cases": rows, "agrees_with_a_real_cup": agree, "chosen": "seal_and_wrench"}
    _common.write_result("suction_model", result)
    _common.write_section_of("suction_model", section, "suction_model.json")
    sys.exit(0)


if __name__ == "__main__":
    main()

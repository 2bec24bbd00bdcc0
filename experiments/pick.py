"""Orders fulfilled end to end (thesis ch. 6, Fig 1.1): shop photo -> ROD with external
conditioning -> grasp point from depth -> top-down grasp (jaws along y, the policy the detector's
pickability labels are for) -> order tote.

    python experiments/pick.py [--orders 50] [--weights src/binpick/detection/weights/rod_photo_learnt_tiny_320.safetensors]
                              [--grasp learnt|analytic|fixed] [--compare-grasps] [--keep-oracle] [--robot floating|panda|ur5e]

Runs ``--orders`` orders of products the detector saw in training and as many of held-out products
(zero-shot), each a new bin seeded from its order number; then the seen orders again with the
simulator's boxes in place of the detector's (the grasp's own ceiling; with ``--compare-grasps`` once
per grasp policy: fixed yaw, analytic, learnt, on the same bins). Seen products are taken in turn from the
detector's training list, held-out ones from the library's other products. Writes results/pick.json
({seen, held_out} with orders, pick_success, right_product, picks_per_min, failure reasons and per
product), the pick section of docs/RESULTS.md, and GIFs with an HTML report per group under
runs/pick_bench/. Targets: pick success >= 80%, right product >= 95%.

``--robot panda`` runs the same seen and held-out orders (same products, same bin seeds) with the Panda
arm executing the picks (binpick.arm: mink IK, Ruckig timing, the arm's reach in the plan) and writes
them to results/pick.json's ``arm`` section beside the floating gripper's rows, which it keeps: share
placed, right product, cycle time per pick and picks per hour of simulated robot time, the motion
limits used, collisions, grasps dropped for reach, and wall seconds per order for both.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import _common  # noqa: E402
import numpy as np  # noqa: E402

WEIGHTS = _common.ROOT / "src" / "binpick" / "detection" / "weights" / "rod_photo_learnt_tiny_320.safetensors"
SEEDS = {"seen": 10_000, "held_out": 20_000, "per_product": 30_000}  # away from the data set's scene seeds


def report_progress(group: str, orders: int):
    done: list[bool] = []

    def on_order(result) -> None:
        done.append(result.success)
        if len(done) % 10 == 0 or len(done) == orders:
            print(f"{group}: {len(done)}/{orders} orders, pick success {sum(done) / len(done):.0%}", flush=True)

    return on_order


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--orders", type=int, default=50)
    parser.add_argument("--weights", type=Path, default=WEIGHTS)
    parser.add_argument("--out", type=Path, default=_common.ROOT / "runs" / "pick_bench")
    parser.add_argument("--grasp", default=None, help="grasp policy (default: binpick's, the best in results/grasp.json)")
    parser.add_argument("--compare-grasps", action="store_true", help="run the simulator-boxes orders with every grasp policy")
    parser.add_argument("--robot", default="floating", choices=["floating", "panda", "ur5e"],
                        help="what executes the picks (panda, ur5e: that arm's rows go to its arm section, the rest is kept; "
                             "with --cell --skip-main: the cell's rows on that arm)")
    parser.add_argument("--keep-oracle", action="store_true",
                        help="keep the simulator-boxes rows of results/pick.json (they do not depend on the detector)")
    parser.add_argument("--gripper", default="both", choices=["jaws", "suction", "both"], help="the hand's tools for the main rows")
    parser.add_argument("--tool-rows", action="store_true", help="also the seen and held-out orders with each other hand (by_gripper)")
    parser.add_argument("--per-product", type=int, default=0, metavar="N",
                        help="also N orders of every product, seen and held out, with --gripper (by_product)")
    parser.add_argument("--cell", type=Path, default=None, metavar="YAML",
                        help="also the seen and held-out orders with a cell file's hand, e.g. configs/cells/franka_hand.yaml (by_cell)")
    parser.add_argument("--skip-main", action="store_true", help="keep results/pick.json's seen, held-out and oracle rows "
                                                                  "(made with the same --gripper and --orders) and run only the extra rows")
    args = parser.parse_args()

    import torch

    from binpick.cli import DEFAULT_POLICY
    from binpick.detection.weights_file import load_detector
    from binpick.grasping import GraspPlanner
    from binpick.sim import default_library
    from binpick.warehouse.orders import fulfil
    from binpick.warehouse.pipeline import PickPipeline

    torch.set_num_threads(2)
    if args.cell is not None:  # a bad cell file, or one for another arm: one line before hours of orders
        from binpick.cell import load_cell

        load_cell(args.cell).check_arm(args.robot)
    if args.robot != "floating" and args.cell is None:
        return arm_rows(args)
    model = load_detector(args.weights)
    if not model.trained_products:
        sys.exit(f"{args.weights} does not list its training products; ship it with tools/ship_weights.py")
    library = default_library()
    seen = [p for p in sorted(library.products) if p in model.trained_products]
    held_out = [p for p in sorted(library.products) if p not in model.trained_products]
    result: dict = {}
    policy = args.grasp or DEFAULT_POLICY
    planners = {name: GraspPlanner.load(name, hand=args.gripper if name != "fixed" else "jaws")
                for name in ({policy} | ({"fixed", "analytic", "learnt"} if args.compare_grasps else set()))}
    groups = [("seen", seen, False, policy), ("held_out", held_out, False, policy), ("oracle", seen, True, policy)]
    groups += [(f"oracle_{name}", seen, True, name) for name in sorted(planners) if args.compare_grasps and name != policy]
    previous = json.loads((_common.RESULTS / "pick.json").read_text()) if (_common.RESULTS / "pick.json").is_file() else {}
    if args.keep_oracle and "oracle" in previous:
        groups = groups[:2]
        result["oracle"], result["oracle_by_policy"] = previous["oracle"], previous.get("oracle_by_policy", {})
    if str(previous.get("grasp", "")).startswith("scripted"):  # the last results before the grasp planner: keep them as "before"
        result["before"] = {k: {m: previous[k][m] for m in ("pick_success", "right_product")} for k in ("seen", "held_out")
                            if k in previous} | {"weights": previous.get("weights"), "grasp": "fixed (jaws along y)",
                                                 "oracle": {"pick_success": previous["seen_ground_truth_boxes"]["pick_success"]}}
    elif "before" in previous:
        result["before"] = previous["before"]
    for key in ("arm", "arm_ur5e"):  # the arms' rows (--robot panda, --robot ur5e) stay until that run is made again
        if key in previous:
            result[key] = previous[key]
    if args.skip_main:
        if previous.get("gripper") != args.gripper or any(k not in previous for k in ("seen", "held_out")):
            sys.exit(f"--skip-main keeps rows made with --gripper {args.gripper}: results/pick.json has none")
        if previous["seen"].get("orders") != args.orders:
            sys.exit(f"--skip-main keeps rows of {previous['seen'].get('orders')} orders: give --orders {previous['seen'].get('orders')}")
        result.update({k: previous[k] for k in ("seen", "held_out", "oracle", "oracle_by_policy") if k in previous})
        groups = []
    for group, products, oracle, name in groups:
        pipeline = PickPipeline(model, library, grasp=planners[name], oracle=oracle)
        seed = SEEDS["seen" if oracle else group]  # the oracle gets the very bins the detector got
        summary, _ = fulfil(pipeline, products, args.orders, seed, args.out / group,
                            on_order=report_progress(group, args.orders), title=f"binpick: {group.replace('_', ' ')} ({name} grasps)")
        row = {"products": len(products), "grasp": name, "gripper": pipeline.gripper, "folder": str(args.out / group), **summary}
        if oracle:
            result.setdefault("oracle_by_policy", {})[name] = row
        if group.startswith("oracle_"):
            continue
        result[group] = row
        print(group, json.dumps({k: summary[k] for k in ("orders", "pick_success", "right_product", "picks_per_min", "reasons")}),
              flush=True)
    result["by_gripper"] = {args.gripper: {g: result[g] for g in ("seen", "held_out") if g in result}}
    hands_measured = {args.gripper} if any(group in ("seen", "held_out") for group, *_ in groups) else set()
    if args.tool_rows:
        hands_measured |= {"jaws", "suction", "both"}
        for gripper in [g for g in ("jaws", "suction", "both") if g != args.gripper]:
            planner = GraspPlanner.load(policy, hand=gripper)
            for group, products in (("seen", seen), ("held_out", held_out)):
                pipeline = PickPipeline(model, library, grasp=planner, gripper=gripper)
                summary, _ = fulfil(pipeline, products, args.orders, SEEDS[group], args.out / f"{gripper}_{group}",
                                    on_order=report_progress(f"{gripper} {group}", args.orders),
                                    title=f"binpick: {group.replace('_', ' ')} ({gripper})")
                result["by_gripper"].setdefault(gripper, {})[group] = {"products": len(products), "grasp": policy, "gripper": gripper,
                                                                       "folder": str(args.out / f"{gripper}_{group}"), **summary}
                print(gripper, group, json.dumps({k: summary[k] for k in ("orders", "pick_success", "right_product", "reasons")}), flush=True)
    elif "by_gripper" in previous:  # the other hands' rows stay until they are run again
        result["by_gripper"] = {**previous["by_gripper"], **result["by_gripper"]}
    cells_measured: set[str] = set()
    if args.cell is not None:
        measured_cells = cell_rows(model, library, policy, args.cell, seen, held_out, args.orders, args.out, args.robot)
        cells_measured = set(measured_cells)
        result["by_cell"] = {**(previous.get("by_cell") or {}), **measured_cells}
    elif "by_cell" in previous:
        result["by_cell"] = previous["by_cell"]
    if args.per_product:
        result["by_product"] = per_product_rows(model, library, policy, args.gripper, seen, held_out, args.per_product, args.out)
    elif "by_product" in previous:
        result["by_product"] = previous["by_product"]
    result.update(pooled_rows(library, result.get("by_gripper") or {}, previous))
    # a kept arm row keeps the floating-gripper rows it was measured beside (the same code): the arm's run
    # (--robot panda) writes both anew
    pipeline = PickPipeline(model, library, grasp=planners[policy])  # the settings every row shares
    result.update({"weights": str(args.weights.relative_to(_common.ROOT) if args.weights.is_absolute() else args.weights),
                   "grasp": f"{policy} (binpick.grasping), up to 3 grasps down the ranked detections (detections without a feasible grasp skipped)",
                   "verifier": "learnt" if not isinstance(pipeline.picker.verifier, str) else pipeline.picker.verifier,
                   "check": pipeline.check, "photos": pipeline.photo_set, "size_check": pipeline.size_check,
                   "gripper": args.gripper,
                   "targets": {"seen.pick_success": 0.97, "held_out.pick_success": 0.97, "seen.right_product": 0.98,
                               "held_out.right_product": 0.98, "by_product.min_pick_success": 0.90},
                   "peak_rss_mib": _common.peak_rss_mib(),
                   "load_average": round(os.getloadavg()[0], 2)})
    # each hand's rows and each cell's say which run measured them (a run may keep the others' from an earlier one)
    _common.write_result("pick", result, merged={"by_gripper": hands_measured, "by_cell": cells_measured})
    _common.write_section_of("pick", section, "pick.json")


SHAPES = {  # the library's categories by shape, for by_category
    "boxes": ("procedural_box", "box", "carton"), "cylinders": ("procedural_cylinder", "can", "bottle"),
    "spheres": ("procedural_sphere", "fruit"), "irregular": ("toy", "mug", "plush", "bakery", "random_shape")}


def shape_of(category: str) -> str:
    return next((shape for shape, categories in SHAPES.items() if category in categories), "irregular")


def per_product_rows(model, library, policy: str, gripper: str, seen: list[str], held_out: list[str], orders: int, out: Path) -> dict:
    """``orders`` orders of every product with ``gripper``: placed share per product (the weakest product's figure)."""
    from binpick.grasping import GraspPlanner
    from binpick.warehouse.orders import fulfil
    from binpick.warehouse.pipeline import PickPipeline

    pipeline = PickPipeline(model, library, grasp=GraspPlanner.load(policy, hand=gripper), gripper=gripper)
    rows = {}
    for index, product in enumerate(seen + held_out):
        summary, _ = fulfil(pipeline, [product], orders, SEEDS["per_product"] + 1000 * index, out / "per_product" / product.replace("/", "_"))
        rows[product] = {"orders": summary["orders"], "pick_success": summary["pick_success"], "right_product": summary["right_product"],
                         "seen": product in seen, "category": library[product].category, "shape": shape_of(library[product].category),
                         "reasons": summary["reasons"], "by_tool": summary["by_tool"]}
        print(f"per product: {product} {summary['pick_success']:.0%} of {summary['orders']}", flush=True)
    return rows


def cell_rows(model, library, policy: str, path: Path, seen: list[str], held_out: list[str], orders: int, out: Path,
              robot: str = "floating") -> dict:
    """The seen and held-out orders (the same bins) with the hand a cell file describes, built in the
    simulator as the file gives it (on ``robot``: the floating hand, or the Panda at the file's tool
    point); the widest jaw grasp it executed beside the widest its jaws take."""
    from binpick.cell import Cell
    from binpick.grasping import GraspPlanner
    from binpick.warehouse.orders import fulfil
    from binpick.warehouse.pipeline import PickPipeline

    cell = Cell.load(path)
    planner = GraspPlanner.load(policy, hand=cell.tools, gripper=cell.jaws, cup=cell.cup)
    name = cell.name if robot == "floating" else f"{cell.name}+{robot}"
    from binpick.sim.robot_arm import TCP

    rows = {"file": str(path), "tools": cell.tools, "stroke": cell.jaws.opening, "widest_taken": round(cell.widest, 4), "robot": robot,
            "tcp": None if robot == "floating" else (TCP if cell.tcp is None else cell.tcp)}
    for group, products in (("seen", seen), ("held_out", held_out)):
        folder = out / f"cell_{name}_{group}"
        summary, results = fulfil(PickPipeline(model, library, grasp=planner, gripper=cell.tools, robot=robot, tcp=cell.tcp,
                                                mount=cell.base), products,
                                  orders, SEEDS[group], folder,
                                  on_order=report_progress(f"{name} {group}", orders), title=f"binpick: {group} ({name})")
        widths = [a.width for r in results for a in r.attempts if a.tool == "jaws" and a.width is not None]
        rows[group] = {"products": len(products), "grasp": policy, "folder": str(folder),
                       "widest_jaw_grasp": round(max(widths), 4) if widths else None, **summary}
        print(name, group, json.dumps({k: summary[k] for k in ("orders", "pick_success", "right_product", "reasons")}), flush=True)
    return {name: rows}


def pooled_rows(library, by_gripper: dict, previous: dict) -> dict:
    """``by_category`` and ``calibration``, which pool every hand's orders: made again when all the hands'
    orders are on this machine, else kept as they were (another clone or another run measured some of
    them), rather than made from a part of them."""
    executed = executed_orders(by_gripper)
    if executed and set(executed) >= set(by_gripper):
        return {"by_category": category_rows(library, executed), "calibration": calibration_rows(executed)}
    return {key: previous[key] for key in ("by_category", "calibration") if key in previous}


def executed_orders(rows: dict) -> dict[str, list[dict]]:
    """Every order behind the rows in ``rows`` (hand -> groups), read back from each row's results.json."""
    orders: dict[str, list[dict]] = {}
    for hand, groups in rows.items():
        for row in groups.values():
            path = Path(row.get("folder") or "") / "results.json"
            if row.get("folder") and path.is_file():
                orders.setdefault(hand, []).extend(json.loads(path.read_text())["orders"])
    return orders


def category_rows(library, executed: dict[str, list[dict]]) -> dict:
    """Placed share per shape (boxes, cylinders, spheres, irregular) for each hand that ran the seen and held-out orders."""
    rows: dict = {}
    for gripper, orders in executed.items():
        for shape in SHAPES:
            mine = [o for o in orders if shape_of(library[o["product"]].category) == shape]
            if mine:
                rows.setdefault(shape, {})[gripper] = {"orders": len(mine), "pick_success": round(sum(o["success"] for o in mine) / len(mine), 4)}
    return rows


def calibration_rows(executed: dict[str, list[dict]]) -> dict:
    """Each tool's quality model on the grasps the picks executed: predicted success against what
    happened (the ordered product placed), its expected calibration error and reliability bins."""
    from binpick.core.metrics import calibration_error, reliability

    rows = {}
    for tool in ("jaws", "suction"):
        pairs = [(a["quality"], a["outcome"] == "placed" and a.get("lifted_product") == o["product"])
                 for orders in executed.values() for o in orders for a in o["attempts"]
                 if a.get("tool") == tool and a.get("quality") is not None and a["outcome"] != "no feasible grasp"]
        if pairs:
            predicted, placed = np.array([p for p, _ in pairs]), np.array([float(k) for _, k in pairs])
            rows[tool] = {"grasps": len(pairs), "predicted_mean": round(float(predicted.mean()), 4), "placed": round(float(placed.mean()), 4),
                          "ece": round(calibration_error(placed, predicted), 4), "reliability": reliability(placed, predicted)}
    return rows


def floating_row(group: dict) -> dict:
    """The floating gripper's figures the arm's row is compared with."""
    return {"orders": group["orders"], "pick_success": group["pick_success"], "right_product": group["right_product"],
            "wall_s_per_order": round(group["wall_s"] / max(1, group["orders"]), 2)}


ARM_NAMES = {"panda": "Panda", "ur5e": "UR5e"}
ARM_MAKERS = {"panda": "Franka", "ur5e": "Universal Robots"}


def arm_key(robot: str) -> str:
    """results/pick.json's key for an arm's rows: ``arm`` (the Panda's), ``arm_<robot>`` for another arm."""
    return "arm" if robot == "panda" else f"arm_{robot}"


def arm_rows(args) -> None:
    """The seen and held-out orders with the arm, beside the floating gripper's rows already in results/pick.json."""
    from binpick.cli import DEFAULT_POLICY
    from binpick.detection.weights_file import load_detector
    from binpick.sim import default_library
    from binpick.sim.robot_arm import arm_model
    from binpick.warehouse.orders import fulfil
    from binpick.warehouse.pipeline import PickPipeline

    path = _common.RESULTS / "pick.json"
    result = json.loads(path.read_text()) if path.is_file() else {}
    if "seen" not in result or "held_out" not in result:
        sys.exit("results/pick.json has no floating-gripper rows to compare with: run python experiments/pick.py first")
    model = load_detector(args.weights)
    library = default_library()
    seen = [p for p in sorted(library.products) if p in model.trained_products]
    held_out = [p for p in sorted(library.products) if p not in model.trained_products]
    policy = args.grasp or DEFAULT_POLICY
    limits = arm_model(args.robot).limits
    arm: dict = {"robot": args.robot, "grasp": policy, "limits": {
        "velocity_rad_s": list(limits.velocity), "acceleration_rad_s2": list(limits.acceleration),
        "jerk_rad_s3": list(limits.jerk), "source": limits.source}}
    pipeline = PickPipeline(model, library, grasp=policy, robot=args.robot, gripper=args.gripper)
    arm["gripper"] = args.gripper
    cycles: list[float] = []
    for group, products in (("seen", seen), ("held_out", held_out)):
        summary, results = fulfil(pipeline, products, args.orders, SEEDS[group], args.out / f"{arm_key(args.robot)}_{group}",
                                  on_order=report_progress(f"arm {group}", args.orders), title=f"binpick: {group.replace('_', ' ')} ({ARM_NAMES[args.robot]} arm)")
        arm[group] = {"products": len(products), **summary, "wall_s_per_order": round(summary["wall_s"] / max(1, summary["orders"]), 2),
                      "floating": floating_row(result[group])}
        cycles += [sum(a.motion_s.values()) for r in results for a in r.attempts if a.motion_s and a.outcome == "placed"]
        print(f"arm {group}", json.dumps({k: summary[k] for k in ("orders", "pick_success", "right_product", "reasons")}), flush=True)
    both = [arm[group]["arm"] for group in ("seen", "held_out") if "arm" in arm[group]]
    if not both or not cycles:
        sys.exit("the arm executed no pick: nothing to time (see the groups' results.json under --out)")
    robot_seconds = sum(a["robot_seconds"] for a in both)
    placed = sum(round(arm[g]["pick_success"] * arm[g]["orders"]) for g in ("seen", "held_out"))
    orders = arm["seen"]["orders"] + arm["held_out"]["orders"]
    arm.update({"picks_per_hour": round(3600 * placed / robot_seconds, 1),
                "cycle_s_median": round(float(np.median(cycles)), 3),
                "collisions": sum(a["collisions"] for a in both),
                "picks_with_collisions": sum(a["picks_with_collisions"] for a in both),
                "grasp_error_mm_max": max(a["grasp_error_mm_max"] or 0.0 for a in both),
                "dropped_for_reach_per_100_orders": round(100 * sum(sum(a["dropped_for_reach"].values()) for a in both) / orders, 1),
                "ik_failures_per_100_orders": round(100 * sum(a["dropped_for_reach"]["no IK solution"] for a in both) / orders, 1),
                "targets": {"pick_success_within": 0.03, "right_product": 0.97, "picks_per_hour": 300, "collisions": 0},
                "peak_rss_mib": _common.peak_rss_mib(), "load_average": round(os.getloadavg()[0], 2)})
    result[arm_key(args.robot)] = arm
    for key in ("benchmark", "machine"):
        result.pop(key, None)
    _common.write_result("pick", result)
    _common.write_section_of("pick", section, "pick.json")


def per_product(group: dict) -> str:
    return ", ".join(f"{name.split('/')[-1]} {count}" for name, count in group["by_product"].items())


def section(result: dict) -> str:
    """The pick-pipeline section of docs/RESULTS.md, from results/pick.json (``--orders``: its main rows' orders)."""
    def row(name: str, group: dict, target: tuple[float, float | None]) -> str:
        right = "n/a" if group["right_product"] is None else f"{group['right_product']:.0%}"
        reasons = ", ".join(f"{k} {v}" for k, v in sorted(group["reasons"].items(), key=lambda kv: -kv[1]))
        met = group["pick_success"] >= target[0] and (target[1] is None or (group["right_product"] or 0) >= target[1])
        goal = f"≥ {target[0]:.0%}" + (f" / ≥ {target[1]:.0%}" if target[1] is not None else "")
        return (f"| {name} ({group['products']} products) | {group['orders']} | {group['pick_success']:.0%} | {right} | "
                f"{group['picks_per_min']} | {group['attempts_per_order']} | {reasons} | {goal}: {'met' if met else 'missed'} |")

    before = result.get("before", {})
    policies = result.get("oracle_by_policy", {})
    targets = result.get("targets") or {}  # the targets the rows are judged by, as the results file records them
    lines = ["## Pick pipeline (thesis ch. 6)", "",
             f"`python experiments/pick.py --orders {result['seen']['orders']} --compare-grasps` → `results/pick.json`. Each order is a new bin "
             f"(3–6 copies of the product, 2–3 other products); the detector (`{Path(result['weights']).name}`, ROD conditioned on "
             "the product's catalogue photos, the best match over them) finds the instances; detections the learnt product check "
             f"(`binpick.detection.verifier`) gives a probability under {result['check']} of being the ordered product are skipped and the rest, "
             "down to a score of 0.01, are ranked by detector score times that probability (`PickPipeline(rank_from=0.01)`), the best eight of them times their support to the fourth power (how much the other likely copies agree with each one, `binpick.picking.agreement`); detections whose instance depth shows to be clearly bigger than the "
             "product's catalogue dimensions are skipped (`size_check`; "
             f"{'on' if result.get('size_check') else 'off'} here); the planner (`binpick.picking.Picker`, the same call "
             "`binpick plan` and the ROS nodes make, on depth in whole millimetres) chooses each detection's "
             f"grasp with the **{result['oracle']['grasp']}** policy and skips detections without a feasible one; the grasp "
             "lifts the product, carries it to the order tote and the result is checked; after a failure the next detection "
             "is tried (3 grasps at most). Right product: of all grasps that lifted something, the share that lifted the ordered "
             "product (a wrong one goes to the customer). The thesis reports no pick rate for its pipeline; the targets are this project's.", "",
             "| products | orders | pick success | right product | picks/min | grasps/order | outcomes | target |",
             "|---|---|---|---|---|---|---|---|",
             row("seen in training", result["seen"], (targets.get("seen.pick_success", 0.88), targets.get("seen.right_product", 0.97))),
             row("held out (zero-shot)", result["held_out"], (targets.get("held_out.pick_success", 0.75), targets.get("held_out.right_product"))),
             row("seen, boxes from the simulator (grasp alone)", result["oracle"], (0.92, None)), "",
             "The last row replaces the detector by the simulator's boxes of the ordered product (most visible first) in "
             "the same bins: the grasp's own ceiling. The gap between it and the first row is the detector's.", ""]
    if policies:
        lines += ["Grasp policies on the simulator's boxes, same bins:", "",
                  "| grasp policy | placed | outcomes |", "|---|---|---|"]
        for name in ("fixed", "analytic", "learnt"):
            if name in policies:
                group = policies[name]
                reasons = ", ".join(f"{k} {v}" for k, v in sorted(group["reasons"].items(), key=lambda kv: -kv[1]))
                lines.append(f"| {name} | {group['pick_success']:.0%} | {reasons} |")
        lines.append("")
    lines += [f"Per product (placed/orders), seen: {per_product(result['seen'])}.", f"Held out: {per_product(result['held_out'])}."]
    lines += ["", *tool_lines(result)]
    if before.get("seen"):
        lines.append(f"Before (`{before.get('weights')}`, {before.get('grasp') or 'jaws along y'}): seen "
                     f"{before['seen']['pick_success']:.0%} placed, held out {before['held_out']['pick_success']:.0%}"
                     + (f", simulator's boxes {before['oracle']['pick_success']:.0%}" if before.get("oracle") else "") + ".")
    lines.append(f"Peak RSS {result['peak_rss_mib']:.0f} MiB.")
    for key in ("arm", "arm_ur5e"):
        if key in result:
            lines += ["", arm_section(result[key])]
    return "\n".join(lines)


def tool_lines(result: dict) -> list[str]:
    """The hand's tools: the same orders with jaws alone, suction alone and both (the planner choosing per
    detection), per shape, the weakest product, and each quality model's calibration on the grasps executed."""
    lines = []
    rows = result.get("by_gripper") or {}
    if rows:
        lines += ["### Jaws, a suction cup, or both", "",
                  "The same seen and held-out orders (same bins) with a hand carrying jaws alone, a suction cup alone (30 mm, "
                  "`binpick.grippers.SuctionCup`: a seal only where its lip's ring lies flat on one product, a hold within the "
                  "vacuum's pull, shear and peel limits) or both (the cup on a rod between the fingers; per detection the planner "
                  "takes the grasp of either tool with the highest predicted success). After a failed grasp the robot looks at "
                  "the bin again and plans anew (up to 3 grasps). Default: `both`.", "",
                  "| hand | seen placed | seen right product | held out placed | held out right product | grasps by tool (placed/grasps) |",
                  "|---|---|---|---|---|---|"]
        for gripper in ("both", "jaws", "suction"):
            if gripper not in rows or "seen" not in rows[gripper]:
                continue
            seen, held = rows[gripper]["seen"], rows[gripper].get("held_out") or {}
            tools = {}
            for group in (seen, held):
                for tool, counts in (group.get("by_tool") or {}).items():
                    tools.setdefault(tool, [0, 0])
                    tools[tool][0] += counts["placed"]
                    tools[tool][1] += counts["grasps"]
            used = ", ".join(f"{tool} {k}/{n}" for tool, (k, n) in sorted(tools.items()))
            cell = lambda v: "n/a" if v is None else f"{v:.0%}"  # noqa: E731
            lines.append(f"| {gripper} | {cell(seen['pick_success'])} | {cell(seen['right_product'])} | "
                         f"{cell(held.get('pick_success'))} | {cell(held.get('right_product'))} | {used} |")
        lines.append("")
    cells = result.get("by_cell") or {}
    if cells:
        lines += ["### Your cell's gripper", "",
                  "The same seen and held-out orders with the hand a cell file describes (`python experiments/pick.py --cell FILE`, "
                  "`--robot panda --skip-main` for the cell on an arm; the planner and the simulated hand both take its jaws' stroke and fingers and its cup, "
                  "the arm its tool point). The widest jaw grasp executed is never wider than the jaws take (stroke less the margin).", "",
                  "| cell | robot (tool point) | tools | stroke | seen placed | held out placed | right product (seen, held out) | "
                  "widest jaw grasp / widest taken |",
                  "|---|---|---|---|---|---|---|---|"]
        for name, row in cells.items():
            seen, held = row.get("seen") or {}, row.get("held_out") or {}
            share = lambda v: "n/a" if v is None else f"{v:.0%}"  # noqa: E731
            widest = max((r.get("widest_jaw_grasp") or 0.0 for r in (seen, held)), default=0.0)
            robot = row.get("robot", "floating")
            robot = f"{robot} ({100 * row['tcp']:.1f} cm)" if robot != "floating" and row.get("tcp") is not None else robot
            lines.append(f"| {name.split('+')[0]} | {robot} | {row['tools']} | {100 * row['stroke']:.1f} cm | {share(seen.get('pick_success'))} | "
                         f"{share(held.get('pick_success'))} | {share(seen.get('right_product'))}, {share(held.get('right_product'))} | "
                         f"{100 * widest:.1f} / {100 * row['widest_taken']:.1f} cm |")
        lines.append("")
    shapes = result.get("by_category") or {}
    if shapes:
        grippers = [g for g in ("suction", "jaws", "both") if any(g in row for row in shapes.values())]
        lines += ["Placed per shape (`by_category`; seen and held-out orders together):", "",
                  "| shape | " + " | ".join(grippers) + " |", "|---" * (len(grippers) + 1) + "|"]
        for shape, row in shapes.items():
            lines.append(f"| {shape} | " + " | ".join(f"{row[g]['pick_success']:.0%} of {row[g]['orders']}" if g in row else "—"
                                                    for g in grippers) + " |")
        lines.append("")
    calibration = result.get("calibration") or {}
    if calibration:
        lines += ["Each quality model on the grasps the picks executed (predicted success against placed; expected "
                  "calibration error over 10 bins): " + "; ".join(
                      f"{tool}: {row['grasps']} grasps, predicted {row['predicted_mean']:.2f} on average, placed {row['placed']:.2f}, "
                      f"ECE {row['ece']:.3f}" for tool, row in calibration.items()) + ".", ""]
    products = result.get("by_product") or {}
    if products:
        weakest = sorted(products.items(), key=lambda kv: kv[1]["pick_success"])[:5]
        orders = {row["orders"] for row in products.values()}
        lines += [f"Per product ({'/'.join(map(str, sorted(orders)))} orders of each of {len(products)} products, default hand; "
                  f"`by_product`): the weakest " + ", ".join(f"{name.split('/')[-1]} {row['pick_success']:.0%}" for name, row in weakest)
                  + f"; {sum(row['pick_success'] >= 0.9 for row in products.values())} of {len(products)} products at 90% or more.", ""]
    return lines


def arm_section(arm: dict) -> str:
    """The arm's rows beside the floating gripper's, its cycle time and what its reach cost."""
    def row(name: str, group: dict) -> str:
        floating = group["floating"]
        gap = group["pick_success"] - floating["pick_success"]
        right = "n/a" if group["right_product"] is None else f"{group['right_product']:.0%}"
        reasons = ", ".join(f"{k} {v}" for k, v in sorted(group["reasons"].items(), key=lambda kv: -kv[1]))
        return (f"| {name} | {group['orders']} | {group['pick_success']:.0%} | {floating['pick_success']:.0%} | {gap:+.0%} | {right} | "
                f"{group['arm']['cycle_s_median'] or float('nan'):.2f} | {group['wall_s_per_order']} / {floating['wall_s_per_order']} | {reasons} |")

    segments = arm["seen"]["arm"]["segment_s_median"]
    limits, robot = arm["limits"], arm.get("robot", "panda")
    return "\n".join([
        f"### With the {ARM_NAMES[robot]} arm", "",
        f"`python experiments/pick.py --robot {robot} --orders {arm['seen']['orders']}`: the same orders (products and bin seeds) "
        f"executed by a {ARM_MAKERS[robot]} {ARM_NAMES[robot]} beside the bin (`binpick.arm`): each segment of the pick solved by inverse kinematics "
        "with mink (joint limits, joint velocity limits, collision avoidance against the table and both totes) and timed by "
        "Ruckig within the arm's joint limits (below), executed by joint position targets at the simulator's 4 ms step; "
        "the picker drops grasps the arm cannot take (no IK solution, a collision on the way down, a wrist flip) and takes "
        "the detection's next best candidate. Cycle time: simulated robot seconds from home (out of the camera's view) "
        "back to home. The bins settle from the same seeds with the arm in the model, so a few piles differ slightly "
        "from the floating gripper's (MuJoCo's solver does not give the same floats with more bodies in the model); "
        "wall seconds are this 2-core machine's, each run under its own load.", "",
        "| orders | n | placed (arm) | placed (floating) | difference | right product | cycle s (median) | wall s per order, arm / floating | outcomes |",
        "|---|---|---|---|---|---|---|---|---|",
        row("seen in training", arm["seen"]), row("held out (zero-shot)", arm["held_out"]), "",
        f"Picks per hour of robot time: **{arm['picks_per_hour']:.0f}** (target ≥ 300; Dex-Net 4.0 reports about 300 on an "
        f"ABB YuMi); median cycle {arm['cycle_s_median']:.2f} s per placed pick, segments (median, s): "
        + ", ".join(f"{k} {v:.2f}" for k, v in segments.items()) + ". "
        f"Collisions with the table or totes in executed motions: {arm['collisions']}. Grasps dropped for the arm's reach: "
        f"{arm['dropped_for_reach_per_100_orders']} per 100 orders (IK failures {arm['ik_failures_per_100_orders']} per 100). "
        f"Motion limits (rad/s, rad/s², rad/s³ per joint): velocity {limits['velocity_rad_s']}, acceleration "
        f"{limits['acceleration_rad_s2']}, jerk {limits['jerk_rad_s3']}; source: {limits['source']}. "
        f"Peak RSS {arm['peak_rss_mib']:.0f} MiB."])


if __name__ == "__main__":
    main()

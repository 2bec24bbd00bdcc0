"""Pick planning from a camera's files and through ROS (thesis ch. 6).

    python experiments/plan.py files [--sensor perfect|realistic] [--orders 30] [--default-orders 100]
    python experiments/plan.py single [--sensor realistic] [--orders 42]
    python experiments/plan.py latency [--sensor realistic] [--frames 30] [--ros-orders 20]
    python experiments/plan.py sim [--domain shifted] [--orders 50] [--verifier learnt|colour|none] \
        [--photos catalogue|canonical] [--copies-from-match 0.9]

``files``: orders on the shifted-domain set-up (its camera, tote and light; its held-out products can,
mug, toy), each bin planned twice: by the simulator pipeline (render -> Picker.plan on arrays ->
execute) and by ``binpick plan`` on the bin's exported files (rgb.png, depth.png in mm, camera.yaml,
photo.png, ``--product-size`` the product's catalogue dimensions as the pipeline checks them), whose plan.json
the simulator then executes in the same bin. Both run the same planner; the rows say how often they
placed and how often they agreed. ``--default-orders`` does the same on the default set-up (the
products the detector was trained on), where the detector works. ``--sensor realistic`` runs each
set-up's sensor-realistic twin (``binpick/sim/sensors/realistic.yaml``).

``single``: bins with one copy of the ordered product, the query box drawn on it (:func:`single_copy`).

``sim``: orders through the simulator pipeline alone, one variant of the order path per run (the
product check, the photos an order gives, copies found from the surest match), each a row of
``sim_orders``.

``latency``: planning time per frame from the exported files (read + plan, in one process after a
warm-up), and the round trip through each ROS version's node (`benchmarks/ros_loop.py`; ROS 2 inside
``unshare -n``). Run it on an otherwise idle machine.

Each writes its keys into results/plan.json (``file_orders``, ``file_orders_by_sensor``,
``single_copy``, ``latency_ms.{api,ros1,ros2}``) and the plan section of docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import _common  # noqa: E402

OUT = _common.ROOT / "runs" / "plan_bench"
SEEDS = {"shifted": 40_000, "default": 41_000, "single": 42_000}  # away from the data sets' and the pick benchmark's seeds
CLI = [sys.executable, "-c", "from binpick.cli import main; main()"]


def load() -> dict:
    path = _common.RESULTS / "plan.json"
    return json.loads(path.read_text()) if path.is_file() else {}


GRIPPER = "both"  # the hand's tools (--gripper)


def pipeline_for(domain: str, sensor: str = "perfect", **options):
    from binpick.cli import DEFAULT_POLICY
    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.grasping import GraspPlanner
    from binpick.sim import default_library
    from binpick.sim.domain import load_domain
    from binpick.sim.sensor import load_sensor
    from binpick.warehouse.pipeline import PickPipeline

    model = Detector.load(PICKING).network
    return PickPipeline(model, default_library(), grasp=GraspPlanner.load(DEFAULT_POLICY, hand=GRIPPER),
                        domain=None if domain == "default" else load_domain(domain), sensor=load_sensor(sensor), **options)


def products_for(domain: str, pipeline) -> list[str]:
    if domain == "shifted":  # the shifted set's held-out products (sim/domains/shifted.yaml)
        return [pid for category in ("can", "mug", "toy") for pid in pipeline.library.resolve(category)]
    trained = set(pipeline.detector.trained_products or [])  # the catalogue's products it saw (not the randomised shapes)
    return [pid for pid in sorted(pipeline.library.products) if pid in trained]


def file_orders(domain: str, orders: int, sensor: str = "perfect") -> dict:
    """Each bin planned by the simulator pipeline and by `binpick plan` on its files; both executed."""
    from binpick.grasping import PinholeCamera
    from binpick.picking import GraspPlan
    from binpick.core.depth import as_camera_depth
    from binpick.warehouse.export import cut_out, export_frame
    from binpick.warehouse.grasping import Reason
    from binpick.sim.products import product_dimensions
    from binpick.warehouse.orders import OrderResult, summarise
    from PIL import Image

    pipeline = pipeline_for(domain, sensor)
    products = products_for(domain, pipeline)
    folder_name = domain if sensor == "perfect" else f"{domain}_{sensor}"
    sim_results, file_results, same_plans, cli_seconds = [], [], [], []
    same_as_memory = {"float": [], "millimetres": []}  # plan.json == Picker.plan on the in-memory frame
    started = time.perf_counter()
    for order in range(orders):
        product, seed = products[order % len(products)], SEEDS[domain] + order
        sim_results.append(pipeline.run_order(product, order, seed))
        world, rng = pipeline.build_world(product, seed)
        try:
            scene = pipeline.settle(world, rng, seed)
            views = [cut_out(*view) for view in pipeline.photos_and_masks(product)]  # the order's photos of the product
            folder = export_frame(OUT / folder_name / f"order_{order:03d}", scene.rgb, scene.depth, scene.camera,
                                  views[0], {"product": product, "seed": seed, "domain": domain,
                                             "sensor": scene.sensor or {"name": "perfect"}})
            photo_files = [folder / "photo.png"]
            for k, view in enumerate(views[1:], start=1):
                photo_files.append(folder / f"photo_{k}.png")
                Image.fromarray(view).save(photo_files[-1])
            tick = time.perf_counter()
            size = ",".join(f"{v:.4f}" for v in product_dimensions(pipeline.library[product]))  # the catalogue's, as the pipeline checks
            ran = subprocess.run(CLI + ["plan", "--rgb", str(folder / "rgb.png"), "--depth", str(folder / "depth.png"),
                                        "--camera", str(folder / "camera.yaml"),
                                        *[arg for path in photo_files for arg in ("--photo", str(path))], "--product-size", size, "--out", str(folder)],
                                 capture_output=True, text=True)
            cli_seconds.append(time.perf_counter() - tick)
            if ran.returncode != 0:
                raise SystemExit(f"binpick plan failed on {folder}: {ran.stderr.strip()[-500:]}")
            written = json.loads((folder / "plan.json").read_text())
            plans = [GraspPlan(**p) for p in written["plans"]]
            camera = PinholeCamera.from_record(scene.camera)
            dimensions = product_dimensions(pipeline.library[product])
            for key, depth in (("float", scene.depth), ("millimetres", as_camera_depth(scene.depth))):
                memory = pipeline.picker.plan(scene.rgb, depth, camera, photo=views, size=dimensions)
                same_as_memory[key].append([(p.box, p.position) for p in memory] == [(p.box, p.position) for p in plans])
            result = OrderResult(order, product, seed, False, Reason.NO_DETECTION, detections=written["detections"])
            if written["detections"] and not plans:
                result.reason = Reason.NOT_THE_PRODUCT
            pipeline.execute(world, scene, plans, result)
            file_results.append(result)
        finally:
            world.close()
        a, b = sim_results[-1], file_results[-1]
        same_plans.append([x.box for x in a.attempts] == [x.box for x in b.attempts])
        print(f"{folder_name} order {order}: {product} sim {'placed' if a.success else a.reason} / files "
              f"{'placed' if b.success else b.reason}{'' if same_plans[-1] else ' (plans differ)'}", flush=True)
    wall = time.perf_counter() - started
    sim, files = summarise(sim_results, wall), summarise(file_results, wall)
    keep = ("orders", "pick_success", "right_product", "reasons", "by_product")
    return {"domain": domain, "sensor": sensor, "orders": orders, "pick_success": files["pick_success"],
            "files": {k: files[k] for k in keep}, "simulator": {k: sim[k] for k in keep},
            "same_outcome": round(sum(a.success == b.success for a, b in zip(sim_results, file_results)) / orders, 4),
            "same_detections_tried": round(sum(same_plans) / orders, 4),
            # the plan from files equals the picker's plan on the frame in memory: with the simulator's
            # float depth, and with that depth in whole millimetres as depth.png holds it (the pipeline's)
            "same_plan_as_memory": {k: round(sum(v) / orders, 4) for k, v in same_as_memory.items()},
            "cli_seconds_median": round(sorted(cli_seconds)[len(cli_seconds) // 2], 2)}


def sim_orders(domain: str, orders: int, sensor: str, **options) -> dict:
    """Orders through the simulator pipeline alone (no files): the order path's variants side by side
    (product check, photos, copies from the surest match) on the same bins as ``files``."""
    from binpick.warehouse.orders import summarise

    pipeline = pipeline_for(domain, sensor, **options)
    products = products_for(domain, pipeline)
    results, started = [], time.perf_counter()
    for order in range(orders):
        product = products[order % len(products)]
        results.append(pipeline.run_order(product, order, SEEDS[domain] + order))
        r = results[-1]
        print(f"{domain} {options} order {order}: {product} {'placed' if r.success else r.reason}", flush=True)
    summary = summarise(results, time.perf_counter() - started)
    return {"domain": domain, "sensor": sensor, "options": options, "check_used": pipeline.check,
            **{k: summary[k] for k in ("orders", "pick_success", "right_product", "reasons", "by_product")}}


def single_copy(orders: int, sensor: str) -> dict:
    """Bins with one instance of the ordered product (and other products): the query box is drawn on
    it, as a user pointing at it would, and the picker plans on the pointed instance first, then any
    copies its detector finds; the simulator executes the best grasp, and after a failed one
    the robot looks again and plans anew (up to three grasps: ``PickPipeline.pick_pointed``). Placed:
    the pointed instance reached the order tote; right object: of everything lifted, the share that
    was the pointed instance; pointed or nothing: the orders in which nothing else was lifted."""
    from binpick.core.errors import BinpickError
    from binpick.warehouse.grasping import Reason
    from binpick.warehouse.orders import OrderResult, summarise

    pipeline = pipeline_for("default", sensor, copies=(1, 1))
    products = products_for("default", pipeline)
    results, refused, only_pointed, started = [], 0, [], time.perf_counter()
    for order in range(orders):
        product, seed = products[order % len(products)], SEEDS["single"] + order
        world, rng = pipeline.build_world(product, seed)
        try:
            scene = pipeline.settle(world, rng, seed)
            mine = [i for i in scene.instances if i.product_id == product]
            result = OrderResult(order, product, seed, False, Reason.NO_DETECTION)
            if not mine:  # it bounced out of the tote while settling: nothing to point at
                print(f"single order {order}: {product} not in view, skipped", flush=True)
                continue
            x, y, w, h = mine[0].bbox
            box = (x - 2, y - 2, w + 4, h + 4)  # drawn by a person: a little loose
            try:
                pipeline.pick_pointed(world, scene, box, result)
            except BinpickError as error:
                refused += 1
                print(f"single order {order}: {product} refused: {error}", flush=True)
            results.append(result)
            lifted = [a.lifted_product for a in result.attempts if a.lifted_product is not None]
            only_pointed.append(all(p == product for p in lifted))
        finally:
            world.close()
        print(f"single order {order}: {product} {'placed' if result.success else result.reason} "
              f"({result.grasps} grasp{'s' if result.grasps != 1 else ''})", flush=True)
    summary = summarise(results, time.perf_counter() - started)
    return {"sensor": sensor, "orders": summary["orders"], "pick_success": summary["pick_success"],
            "right_object": summary["right_product"], "pointed_or_nothing": round(sum(only_pointed) / max(1, len(only_pointed)), 4),
            "lifts": summary["lifts"], "grasps_per_order": summary["attempts_per_order"], "refused": refused,
            "reasons": summary["reasons"], "by_product": summary["by_product"]}


def api_latency(frames: int, sensor: str = "realistic") -> dict:
    """Read + plan per exported frame, in one process, after one warm-up frame."""
    import numpy as np

    from binpick.picking import Picker
    from binpick.picking.frames import read_frame, read_photo

    folders = sorted(p.parent for p in OUT.glob(f"default_{sensor}/order_*/plan.json"))[:frames + 1] if sensor != "perfect" else []
    folders = folders or sorted(p.parent for p in OUT.glob("*/order_*/plan.json"))[:frames + 1]
    if len(folders) < 2:
        raise SystemExit("no exported frames: run `python experiments/plan.py files` first")
    picker = Picker.load()
    times, stages = [], []
    for index, folder in enumerate(folders):
        tick = time.perf_counter()
        rgb, depth, info = read_frame(folder / "rgb.png", folder / "depth.png", folder / "camera.yaml")
        plans = picker.plan(rgb, depth, info, photo=read_photo(folder / "photo.png"))
        if index:  # the first is the warm-up
            times.append(1000 * (time.perf_counter() - tick))
            stages.append(plans.timing_ms)
    return {"median": round(float(np.median(times)), 1), "p95": round(float(np.percentile(times, 95)), 1), "frames": len(times),
            "from": sorted({f.parent.name for f in folders}),
            "stages_median": {k: round(float(np.median([s.get(k, 0.0) for s in stages])), 1) for k in stages[0]}}


def ros_latency(version: int, orders: int) -> dict:
    loop = [str(Path(__file__).resolve().parents[1] / "benchmarks" / "ros_loop.py"), "--ros", str(version), "--orders", str(orders), "--goal", "photo"]
    if version == 1:
        ran = subprocess.run([sys.executable, *loop], capture_output=True, text=True)
    else:
        python = Path(sys.prefix).with_name(Path(sys.prefix).name + "-ros2") / "bin" / "python"
        ran = subprocess.run(["unshare", "-n", "sh", "-c", f"ip link set lo up && exec {python} {' '.join(loop)}"],
                             capture_output=True, text=True)
    if ran.returncode != 0:
        return {"error": ran.stderr.strip()[-400:]}
    summary = json.loads(ran.stdout.strip().splitlines()[-1])
    return {**summary["latency_ms"], "planning_ms": summary["planning_ms"], "orders": summary["orders"],
            "placed": summary["placed"], "interfaces": summary["interfaces"]}


def changes_onto_latest(started_with: dict, result: dict) -> dict:
    """results/plan.json as it is now with this run's changes on it (rows, and a row's entries, that
    differ from what the run started with): stages run side by side each add their own rows."""
    same = lambda a, b: json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)  # noqa: E731
    latest = load()
    for key, value in result.items():
        before = started_with.get(key)
        if same(before, value):
            continue
        if isinstance(value, dict) and isinstance(before, dict | None) and isinstance(latest.get(key), dict):
            before = before or {}  # a row another stage made meanwhile keeps its entries
            latest[key] = {**latest[key], **{k: v for k, v in value.items() if not same(before.get(k), v)}}
        else:
            latest[key] = value
    return latest


def write(result: dict, measured: set[str] | frozenset[str] = frozenset()) -> None:
    """results/plan.json and its page section; ``measured``: the rows this run measured (their provenance
    is this run's even where the figures came out the same)."""
    _common.write_result("plan", {k: v for k, v in result.items() if k not in ("benchmark", "machine")}, measured)
    _common.write_section_of("plan", section, "plan.json")


def section(result: dict) -> str:
    """The planning section of docs/RESULTS.md (from a camera's files, through ROS), from results/plan.json."""
    lines = ["## Pick planning from a camera's files and through ROS", "",
             "`python experiments/plan.py files` / `latency`: the planner with no simulator in it (`binpick.picking`), "
             "fed the files a real RGB-D camera gives (`binpick plan`) or ROS topics; the simulator executes its grasps. "
             "Thesis ch. 6 has no planning-latency figure; its ROS set-up is §6.1.", ""]
    orders = result.get("file_orders", {})
    if orders:
        lines += ["| set-up | orders | placed from files (`binpick plan`) | placed by the simulator pipeline | same outcome | "
                  "plan from files = in-memory plan, float depth / depth in mm |", "|---|---|---|---|---|---|"]
        others = [row for row in result.get("file_orders_by_domain", {}).values() if row.get("domain") != orders.get("domain")]
        for row in [orders, *others]:  # file_orders is also its domain's entry
            lines.append(f"| {row['domain']} | {row['orders']} | {row['files']['pick_success']:.0%} | "
                         f"{row['simulator']['pick_success']:.0%} | {row['same_outcome']:.0%} | "
                         f"{row['same_plan_as_memory']['float']:.0%} / {row['same_plan_as_memory']['millimetres']:.0%} |")
        lines += ["", "Both paths run `Picker.plan` on the same frame: depth in whole millimetres, as a camera's 16-bit frame "
                  "(and depth.png) holds it; the simulator pipeline rounds its float depth so. The last column compares "
                  "the plan from the files with the picker's plan on the frame in memory: with the simulator's float depth "
                  "grasp positions differ by under a millimetre (an exact comparison); with the millimetre depth they are "
                  f"the same plan in {orders['same_plan_as_memory']['millimetres']:.0%} of the shifted bins. Each row's "
                  "failures by reason are in `results/plan.json` (`files.reasons`).", ""]
    variants = result.get("sim_orders", {})
    if variants:
        lines += ["The order path's variants side by side (`python experiments/plan.py sim --domain D [--verifier V] [--photos P] "
                  "[--check T] [--copies-from-match P]`): the simulator pipeline alone on the same bins as `files` (seeds 40000+ "
                  "shifted, 41000+ default). *check*: the product check before a grasp (learnt: `binpick.detection.verifier`, "
                  "at its threshold; colour: the hue-saturation histogram at 0.15); *photos*: the order's photos (catalogue: the "
                  "product's two catalogue views, the best match counting; canonical: one); *copies*: the box-query detector "
                  "seeded with the surest photo match.", "",
                  "| set-up | check | photos | copies from the surest match | orders | placed | right product | main failures |",
                  "|---|---|---|---|---|---|---|---|"]
        for row in variants.values():
            options = row["options"]
            check = options.get("verifier") or "none"
            used = options.get("check") if options.get("check") is not None else row.get("check_used")
            if used is None and check == "learnt":
                used = 0.2  # rows measured before the threshold was recorded: the learnt check's default then
            check += f" ≥ {used:g}" if used is not None else ""
            failures = ", ".join(f"{k} {n}" for k, n in sorted(row["reasons"].items(), key=lambda kv: -kv[1]) if k != "placed")
            lines.append(f"| {row['domain']} | {check} | {options.get('photos')} | "
                         f"{'—' if options.get('copies_from_match') is None else options['copies_from_match']} | {row['orders']} | "
                         f"{row['pick_success']:.0%} | {row['right_product']:.0%} | {failures} |")
        lines.append("")
    by_sensor = result.get("file_orders_by_sensor", {})
    if by_sensor:
        lines += ["Depth as sensors give it (`python experiments/plan.py files --sensor realistic`): each set-up's twin with the "
                  "`realistic` sensor (`binpick/sim/sensors/realistic.yaml`: a structured-light camera's shadows beside tall edges, "
                  "dark, shiny and grazing surfaces unread, border and blob dropout, axial noise after Nguyen et al. 2012, lateral "
                  "noise, flying pixels, 1/8-pixel disparity quantisation, depth 0-2 px off colour; the camera tilted 0-20° and "
                  "the tote 0-3° off level); products and light as the set-up's own. The planner inpaints the holes, fits the "
                  "support plane and judges fingers on the pixels read.", "",
                  "| set-up | depth | orders | placed from files (`binpick plan`) | placed by the simulator pipeline | right product | target |",
                  "|---|---|---|---|---|---|---|"]
        labels = {"perfect": ("default", "perfect", ">= 95%"), "realistic": ("default", "realistic", ">= 85%"),
                  "shifted": ("shifted", "perfect", ""), "shifted_realistic": ("shifted", "realistic", "")}
        for key, (setup, depth, target) in labels.items():
            row = by_sensor.get(key)
            if row:
                right = row["files"].get("right_product")
                lines.append(f"| {setup} | {depth} | {row['orders']} | {row['files']['pick_success']:.0%} | "
                             f"{row['simulator']['pick_success']:.0%} | {'–' if right is None else f'{right:.0%}'} | {target} |")
        lines.append("")
    single = result.get("single_copy_by_sensor", {})
    if single:
        lines += ["The object the user points at (`python experiments/plan.py single --orders 40 --sensor realistic`): bins with "
                  "one instance of the ordered product among others, the query box drawn on it; the picker plans on the "
                  "pointed instance first, then the copies its detector finds (`copies_only=True` keeps the thesis's "
                  "\"other copies only\").", "",
                  "| depth | orders | pointed instance placed | right object (of lifts) | target |", "|---|---|---|---|---|"]
        for key, row in single.items():
            right = row.get("right_object")
            lines.append(f"| {key} | {row['orders']} | {row['pick_success']:.0%} | {'–' if right is None else f'{right:.0%}'} | >= 90% |")
        lines.append("")
    latency = result.get("latency_ms", {})
    if latency:
        lines += ["| planning latency per frame (2 cores) | median ms | p95 ms | target |", "|---|---|---|---|"]
        api_from = ", ".join(latency.get("api", {}).get("from", [])) or "exported frames"
        for key, label in (("api", f"from files ({api_from}), in process (read + plan: inpainting, support plane)"),
                           ("ros1", "through ROS 1 (goal -> result)"),
                           ("ros2", "through ROS 2, in `unshare -n` (goal -> result)")):
            row = latency.get(key)
            if row and "median" in row:
                lines.append(f"| {label} | {row['median']} | {row['p95']} | {'<= 100' if key == 'api' else '<= 150'} |")
            elif row:
                lines.append(f"| {label} | failed: {row.get('error', '')[:80]} | | |")
    planning = result.get("planning_latency", {})
    if planning.get("by_size"):
        three = planning.get("by_size_three_plans") or {}
        lines += ["", f"Planning per frame as a warm `Picker` caller sees it (`python benchmarks/plan_latency.py`; "
                  f"{planning['frames']} frames x {planning['repeats']}, {planning['gripper']} tools, file reading excluded; "
                  "frames over 640x480 are planned at 640x480). Rows: `Picker.plan` as it comes (max_grasps "
                  f"{planning.get('max_grasps', 3)}: planning stops at that many feasible grasps); beside them max_grasps 3, "
                  "as `binpick plan` makes:", "",
                  "| camera | median ms | p95 ms | stages (median ms) | 3 plans: median / p95 ms | target (median) |",
                  "|---|---|---|---|---|---|"]
        for size, row in planning["by_size"].items():
            stages = ", ".join(f"{k} {v}" for k, v in row["stages_median"].items() if k != "total")
            other = three.get(size)
            other_text = f"{other['median']} / {other['p95']}" if other else "–"
            lines.append(f"| {size.replace('x', '×')} | {row['median']} | {row['p95']} | {stages} | {other_text} | "
                         f"<= {row['target_median']:g} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("stage", choices=("files", "single", "latency", "sim"))
    parser.add_argument("--sensor", default="perfect", help="files/single: perfect or realistic depth (the set-ups' "
                                                            "sensor-realistic twins); latency: the exported frames to time")
    parser.add_argument("--orders", type=int, default=30)
    parser.add_argument("--default-orders", type=int, default=100)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--ros-orders", type=int, default=20)
    parser.add_argument("--domain", default="shifted", choices=("shifted", "default"), help="sim: the set-up")
    parser.add_argument("--verifier", default="learnt", help="sim: the product check (learnt, colour, none)")
    parser.add_argument("--photos", default="catalogue", choices=("catalogue", "canonical"), help="sim: the order's photos")
    parser.add_argument("--copies-from-match", type=float, default=None, help="sim: seed the box query from the surest match")
    parser.add_argument("--check", type=float, default=None, help="sim: the product check's threshold (default: the check's own)")
    parser.add_argument("--gripper", default="both", choices=("jaws", "suction", "both"), help="the hand's tools")
    args = parser.parse_args()
    global GRIPPER
    GRIPPER = args.gripper
    result = load()
    started_with = json.loads(json.dumps(result))
    measured = {f"peak_rss_mib_{args.stage}"}  # the rows this run measures (its provenance, even for the same figures)
    if args.stage == "files":
        by_sensor = result.setdefault("file_orders_by_sensor", {})
        measured.add("file_orders_by_sensor")
        shifted = file_orders("shifted", args.orders, args.sensor) if args.orders else None
        default = file_orders("default", args.default_orders, args.sensor) if args.default_orders else None
        if args.sensor == "perfect":
            measured |= {"file_orders_by_domain"} | ({"file_orders"} if shifted is not None else set())
            if shifted is not None:
                result["file_orders"] = shifted
                result.setdefault("file_orders_by_domain", {})["shifted"] = shifted
            if default is not None:
                result.setdefault("file_orders_by_domain", {})["default"] = default
        if default is not None:
            by_sensor[args.sensor] = default
        if shifted is not None:
            by_sensor["shifted" if args.sensor == "perfect" else f"shifted_{args.sensor}"] = shifted
    elif args.stage == "sim":
        options = {"verifier": None if args.verifier == "none" else args.verifier, "photos": args.photos,
                   "copies_from_match": args.copies_from_match, "check": args.check}
        label = f"{args.domain}_{args.sensor}_{args.verifier}_{args.photos}" + (
            f"_copies{args.copies_from_match:g}" if args.copies_from_match is not None else "") + (
            f"_check{args.check:g}" if args.check is not None else "")
        result.setdefault("sim_orders", {})[label] = sim_orders(args.domain, args.orders, args.sensor, **options)
        measured.add("sim_orders")
    elif args.stage == "single":
        result.setdefault("single_copy_by_sensor", {})[args.sensor] = single_copy(args.orders, args.sensor)
        result["single_copy"] = result["single_copy_by_sensor"].get("realistic") or result["single_copy_by_sensor"][args.sensor]
        measured |= {"single_copy_by_sensor"} | ({"single_copy"} if args.sensor == "realistic" or "realistic" not in
                                                  result["single_copy_by_sensor"] else set())
    else:
        result["latency_ms"] = {"api": api_latency(args.frames, args.sensor), "ros1": ros_latency(1, args.ros_orders),
                                "ros2": ros_latency(2, args.ros_orders)}
        measured.add("latency_ms")
    result[f"peak_rss_mib_{args.stage}"] = round(_common.peak_rss_mib(), 1)
    result = changes_onto_latest(started_with, result)
    write(result, measured)
    print(json.dumps({k: result[k] for k in result if k in ("file_orders", "file_orders_by_sensor", "single_copy", "latency_ms")}, indent=1))


if __name__ == "__main__":
    main()

"""Orders and plans: `binpick pick`, `binpick plan`, `binpick demo`."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table
from rich.text import Text

from binpick.cli.app import (
    DEFAULT_GRIPPER,
    CellOption,
    DEFAULT_POLICY,
    GripperOption,
    PlanRobotOption,
    RerunOption,
    RobotOption,
    RuntimeOption,
    app,
    check_png_path,
    console,
    load_cell,
    output_folder,
    parse_dimensions,
    product_library,
    progress,
    save_png,
    seed_option,
    warn,
)
from binpick.core.errors import ConfigError
from binpick.core.files import check_output_file, ensure_dir


@app.command("pick")
def pick(
    product: Annotated[str, typer.Option(help="Product(s) to order: ids, unique short names or categories, comma-separated "
                                              "(orders cycle through them); `binpick products list` shows them")],
    products_file: Annotated[Path | None, typer.Option("--products", help="YAML of your own products (as for data generate)")] = None,
    photo: Annotated[list[Path] | None, typer.Option(metavar="PNG", help="Your own shop photo of the product; repeat for several views "
                                                        "(default: rendered catalogue views)")] = None,
    orders: Annotated[int, typer.Option(help="Orders to fulfil (one new bin each)")] = 5,
    weights: Annotated[Path | None, typer.Option(help="Photo-conditioned detector: run folder or .safetensors (default: shipped)")] = None,
    grasp: Annotated[str, typer.Option(help="Grasp policy: learnt (grasp-quality model), analytic (across the "
                                            "principal minor axis) or fixed (jaws along y, as before)")] = DEFAULT_POLICY,
    grasp_weights: Annotated[Path | None, typer.Option(help="Grasp-quality weights for --grasp learnt (default: shipped)")] = None,
    out: Annotated[Path | None, typer.Option(help="Folder for per-order GIFs, overlays, results.json and report.html "
                                                  "(default: runs/pick/<time>)")] = None,
    seed: Annotated[int, seed_option("Seed of the first order's bin")] = 0,
    robot: RobotOption = "floating",
    gripper: GripperOption = DEFAULT_GRIPPER,
    cell: CellOption = None,
    runtime: RuntimeOption = "torch",
    rerun: RerunOption = False,
) -> None:
    """Fulfil orders end to end: shop photo -> ROD -> grasp chosen from depth -> grasp -> order tote."""
    from binpick.core.config import check_range
    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.grasping import GraspPlanner
    from binpick.warehouse.pipeline import PickPipeline

    check_range("orders", orders, 1, 100_000, integer=True)
    the_cell = load_cell(cell)
    if the_cell is not None:
        the_cell.check_arm(robot)  # another arm than the file's, or a tool point the arm's hand cannot have: one line, now
    if the_cell is not None:  # its hand: the tools, the jaws' stroke and fingers, the cup (the simulator builds the same)
        gripper = the_cell.tools
        planner = GraspPlanner.load(grasp, grasp_weights, hand=gripper, gripper=the_cell.jaws, cup=the_cell.cup)
    else:
        planner = GraspPlanner.load(grasp, grasp_weights, hand=gripper)  # a bad policy or weights file: one line, before any work
    run_dir = ensure_dir(out or Path("runs/pick") / time.strftime("%Y%m%d-%H%M%S"), "--out")
    library = product_library(products_file)
    products = [pid for name in product.split(",") if name.strip() for pid in library.resolve(name.strip())]
    if not products:
        raise ConfigError(f"--product {product!r} names no product: give ids or categories, e.g. robosuite/milk,can")
    if photo:
        if len(products) != 1:
            raise ConfigError("--photo is the photo of one product: give exactly one product id with it")
        from dataclasses import replace

        from binpick.detection.data import read_image

        for path in photo:
            read_image(path)  # unreadable -> one line now, not mid-run
        library.add(replace(library[products[0]], photos=tuple(photo)))
    model = Detector.load(weights or PICKING, runtime=runtime).inference_network
    tcp = the_cell.tcp if the_cell is not None else None  # the arm carries the cell's hand at its tool point
    mount = the_cell.base if the_cell is not None else None
    _fulfil(PickPipeline(model, library, grasp=planner, robot=robot, gripper=gripper, tcp=tcp, mount=mount), products, orders, seed,
            run_dir, rerun)


@app.command("cell")
def cell(
    frame: Annotated[Path, typer.Option(help="A frame folder: rgb.png, depth.png and camera.yaml (with camera_to_base), "
                                             "the tote in view with its walls")],
    wall_above: Annotated[float, typer.Option(help="The tote's walls stand at least this far above its floor (m)")] = 0.06,
    above: Annotated[float, typer.Option(help="The workspace reaches this far above the tote's floor (m)")] = 0.45,
) -> None:
    """Find the tote in one depth frame (its floor, the rim of its walls, the rectangle inside them, in
    the robot's base frame) and write the workspace round it into the frame's camera.yaml."""
    import yaml

    from binpick.core.config import check_range
    from binpick.core.files import atomic_write_text, read_yaml
    from binpick.picking.frames import read_frame
    from binpick.picking.tote import tote_in_frame

    check_range("--wall-above", wall_above, 0.01, 1.0)
    check_range("--above", above, 0.05, 2.0)
    files = {name: frame / name for name in ("rgb.png", "depth.png", "camera.yaml")}
    missing = [name for name, path in files.items() if not path.is_file()]
    if missing:
        raise ConfigError(f"--frame {str(frame)!r} has no {', '.join(missing)} (a frame folder as `binpick data export` writes)")
    rgb, depth, info = read_frame(files["rgb.png"], files["depth.png"], files["camera.yaml"])
    tote = tote_in_frame(rgb, depth, info, wall_above)
    workspace = tote.workspace(above)
    camera = read_yaml(files["camera.yaml"], "camera file")
    camera["workspace"] = {key: [round(v, 4) for v in value] for key, value in workspace.to_mapping().items()}
    atomic_write_text(files["camera.yaml"], yaml.safe_dump(camera, sort_keys=False, default_flow_style=None))
    atomic_write_text(frame / "tote.yaml", yaml.safe_dump(tote.to_mapping(), sort_keys=False, default_flow_style=None))
    (x, y), (length, width) = tote.centre, tote.size
    console.print(f"tote: inside {length * 100:.1f} x {width * 100:.1f} cm, centre ({x:.3f}, {y:.3f}) m, turned "
                  f"{tote.to_mapping()['yaw_degrees']:g} deg, floor at z = {tote.floor_z:.3f} m, walls {tote.wall_height * 100:.1f} cm")
    console.print(f"workspace written to {files['camera.yaml']}: min {camera['workspace']['min']} max {camera['workspace']['max']}")


@app.command("calibrate")
def calibrate_camera(
    folder: Annotated[Path, typer.Argument(help="Board pictures and poses.yaml: mount (eye-to-hand or eye-in-hand), board "
                                                "(squares, square, marker in metres, dictionary) and each picture's flange_to_base")],
    camera: Annotated[Path, typer.Option(help="camera.yaml (ROS camera_info layout): its K and distortion are used, and the "
                                              "solved pose is written into it")],
    intrinsics: Annotated[bool, typer.Option(help="Also solve K and distortion from the pictures (a camera without factory "
                                                  "intrinsics; 10 or more pictures at different angles)")] = False,
    flange_mm: Annotated[float, typer.Option(help="How far the robot's reported flange positions may be off (mm)")] = 1.0,
    flange_degrees: Annotated[float, typer.Option(help="... and its orientations (degrees)")] = 0.1,
) -> None:
    """Hand-eye calibration: the camera's pose from pictures of a ChArUco board at 15 or more flange
    poses (turned about different axes, over the whole working volume), written into camera.yaml:
    camera_to_base (eye-to-hand) or camera_to_flange (eye-in-hand), with the residual to check it by."""
    from binpick.core.config import check_range
    from binpick.picking.calibration_session import calibrate_folder, read_session

    check_range("--flange-mm", flange_mm, 0.01, 50.0)
    check_range("--flange-degrees", flange_degrees, 0.001, 10.0)
    if not folder.is_dir():
        raise ConfigError(f"{str(folder)!r} is not a folder of board pictures with poses.yaml")
    if not intrinsics and not camera.is_file():
        raise ConfigError(f"--camera {str(camera)!r} does not exist: give the camera's camera_info YAML, or --intrinsics to solve it")
    pictures = len(read_session(folder)[2])
    with progress() as callback, callback.task("board pictures read", pictures) as task:
        solved, record = calibrate_folder(folder, camera, intrinsics, (flange_mm, flange_degrees),
                                          on_picture=lambda picture, seen: task.update(advance=1))
    name = "camera_to_base" if solved.mount == "eye-to-hand" else "camera_to_flange"
    x, y, z = solved.transform[:3, 3]
    dropped = f"dropped {', '.join(record['dropped_pictures'])}" if record["dropped_pictures"] else "none dropped"
    console.print(f"{solved.mount}: {name} = ({x:.4f}, {y:.4f}, {z:.4f}) m written to {camera}; residual "
                  f"{solved.residual_mm:.2f} mm / {solved.residual_degrees:.3f} deg, corners reproject at {solved.reprojection_px:.2f} px; "
                  f"board seen in {record['board_seen']} of {record['pictures']} pictures, {len(solved.used)} used ({dropped})",
                  soft_wrap=True)


@app.command("plan")
def plan(
    rgb: Annotated[Path | None, typer.Option(help="Colour image (PNG/JPEG), registered with the depth image")] = None,
    depth: Annotated[Path | None, typer.Option(help="Depth image: 16-bit PNG in millimetres or .npy in metres (0: no reading), "
                                                    "at the colour's size or one of the same aspect")] = None,
    camera: Annotated[Path | None, typer.Option(help="camera.yaml: ROS camera_info layout, plus camera_to_base (the camera's pose in the robot's base frame)")] = None,
    sample: Annotated[bool, typer.Option("--sample", help="Plan on the sample frame that ships with binpick (a bin seen by a realistic "
                                              "RGB-D sensor, tilted; its shop photo unless --query-box)")] = False,
    photo: Annotated[list[Path] | None, typer.Option(metavar="PNG", help="Shop photo of the ordered product (a transparent PNG's alpha marks the "
                                                        "product); repeat for several photos of it (the best match counts)")] = None,
    query_box: Annotated[str | None, typer.Option(help="Or: x,y,w,h of the instance to pick in the colour image (planned "
                                                       "first, then the copies of it that the detector finds)")] = None,
    copies_only: Annotated[bool, typer.Option("--copies-only", help="With --query-box: plan on the other copies only, not the instance "
                                                   "pointed at (repeated-object evaluation)")] = False,
    out: Annotated[Path | None, typer.Option(help="Folder for plan.json (grasps: position, quaternion x,y,z,w in the base frame, "
                                                  "scores, boxes) and overlay.png (default: runs/plan/<time>)")] = None,
    weights: Annotated[Path | None, typer.Option(help="Detector: run folder or .safetensors (default: the shipped one for the query)")] = None,
    grasp: Annotated[str, typer.Option(help="Grasp policy: learnt, analytic or fixed")] = DEFAULT_POLICY,
    grasp_weights: Annotated[Path | None, typer.Option(help="Grasp-quality weights for --grasp learnt (default: shipped)")] = None,
    max_grasps: Annotated[int, typer.Option(help="Plan grasps for this many detections (best first)")] = 3,
    product_size: Annotated[str | None, typer.Option(help="The product's catalogue dimensions L,W,H in metres: instances "
                                                          "clearly bigger are not grasped")] = None,
    robot: PlanRobotOption = "floating",
    gripper: GripperOption = DEFAULT_GRIPPER,
    cell: CellOption = None,
    flange_pose: Annotated[str | None, typer.Option(help="A camera on the wrist (camera.yaml with camera_to_flange, from binpick "
                                                         "calibrate): the flange's pose when the frame was taken, "
                                                         "x,y,z,qx,qy,qz,qw in the base frame")] = None,
    runtime: RuntimeOption = "torch",
    rerun: RerunOption = False,
) -> None:
    """Plan grasps from one real RGB-D frame: no simulator. Prints the best grasp; writes plan.json and overlay.png."""
    from binpick.core.config import check_range
    from binpick.core.files import atomic_write_text
    from binpick.detection.predict import parse_box
    from binpick.picking import Picker
    from binpick.picking.frames import read_frame, read_photo

    check_range("--max-grasps", max_grasps, 1, 100, integer=True)
    the_cell = load_cell(cell)
    if the_cell is not None:
        the_cell.check_arm(robot)  # before any output folder is made
    gripper = the_cell.tools if the_cell is not None else gripper
    rgb, depth, camera, photo = _frame_files(rgb, depth, camera, photo, query_box, sample)
    box = parse_box(query_box) if query_box is not None else None
    dimensions = parse_dimensions(product_size, "--product-size") if product_size is not None else None
    colour, metres, info = read_frame(rgb, depth, camera, parse_flange_pose(flange_pose))
    query = [read_photo(path) for path in photo] if photo else None
    if box is not None and (box[0] < 0 or box[1] < 0 or box[0] + box[2] > colour.shape[1] or box[1] + box[3] > colour.shape[0]):
        raise ConfigError(f"--query-box {query_box!r} lies outside the {colour.shape[1]}x{colour.shape[0]} colour image")
    if copies_only and box is None:
        raise ConfigError("--copies-only goes with --query-box (the instance whose copies to plan on)")
    folder = output_folder(out or Path("runs/plan") / time.strftime("%Y%m%d-%H%M%S"))  # inputs read: now the outputs
    plan_path, overlay = check_output_file(folder / "plan.json", "--out"), check_png_path(folder / "overlay.png", "--out")
    if metres.shape != colour.shape[:2]:  # registered at another resolution: planned, but said so
        warn(f"depth is {metres.shape[1]}x{metres.shape[0]}, the colour {colour.shape[1]}x{colour.shape[0]}: depth is resampled to "
             "the colour's pixels (nearest reading); check it is registered to the colour camera")
    crop = weights if box is not None else None
    reach = None
    if robot != "floating":
        from binpick.arm import MotionPlanner

        reach = MotionPlanner.for_cell(the_cell, gripper, arm=robot).reach_check
    picker = Picker.load(None if box is not None else weights, grasp, grasp_weights, crop_detector=crop, max_grasps=max_grasps,
                         runtime=runtime, reach=reach, gripper=gripper, cell=the_cell)
    plans = picker.plan(colour, metres, info, photo=query, query_box=box, size=dimensions, copies_only=copies_only)
    result = {"inputs": {"rgb": str(rgb), "depth": str(depth), "camera": str(camera),
                         "photo": [str(path) for path in photo] if photo else None, "query_box": query_box, "copies_only": copies_only,
                         "size": dimensions},
              "grasp_policy": picker.grasp.policy.value, "robot": robot, "gripper": gripper, **plans.to_json()}
    atomic_write_text(plan_path, json.dumps(result, indent=1))
    if rerun:
        _record_plan(folder / "plan.rrd", colour, metres, info, plans, str(photo[0].name if photo else f"query box {query_box}"))
    save_png(plans.plot(colour, info.camera, picker.grasp.gripper.opening, query, box), overlay, "--out")
    check_stroke(plans, picker.grasp)  # (after plan.json and the overlay are written: they show why)
    _say_plans(plans, folder, plan_path, overlay)


def _frame_files(rgb: Path | None, depth: Path | None, camera: Path | None, photo: list[Path] | None, query_box: str | None,
                 sample: bool) -> tuple[Path, Path, Path, list[Path] | None]:
    """The frame's files (the sample frame's where ``--sample`` leaves them out) and the photos; one line
    when one is missing or both a photo and a query box are given."""
    if sample:
        from binpick.samples import SAMPLE_FRAME

        rgb, depth, camera = rgb or SAMPLE_FRAME / "rgb.png", depth or SAMPLE_FRAME / "depth.png", camera or SAMPLE_FRAME / "camera.yaml"
        photo = photo if photo or query_box is not None else [SAMPLE_FRAME / "photo.png"]
    if rgb is None or depth is None or camera is None:
        raise ConfigError("give the frame's --rgb, --depth and --camera (or --sample for the frame that ships with binpick)")
    if (not photo) == (query_box is None):
        raise ConfigError("give exactly one of --photo (the product's shop photo; repeatable) or --query-box x,y,w,h")
    return rgb, depth, camera, photo


def _record_plan(path: Path, colour, metres, info, plans, label: str) -> None:
    """The frame as the picker saw it and its plans, as a Rerun recording."""
    from binpick.picking.inputs import register_depth
    from binpick.viz.recording import OrderRecording

    seen, depth_seen = info.rectify(colour, register_depth(metres, colour.shape[:2]))
    with OrderRecording(path) as recording:
        recording.frame(0, label, seen, depth_seen, info.camera, plans)


def _say_plans(plans, folder: Path, plan_path: Path, overlay: Path) -> None:
    """The plan in one line: the best grasp and where the files are, or why there is none."""
    import numpy as np

    best = plans.grasps[0] if plans.grasps else None
    if best is None:
        reasons: dict[str, int] = {}
        for p in plans:
            for k, n in p.rejected.items():
                reasons[k] = reasons.get(k, 0) + n
        why = [f"{plans.not_the_product} failed the product check"] if plans.not_the_product else []
        why += [f"{k} x{n}" for k, n in reasons.items()]
        console.print(f"no feasible grasp: {plans.detections} detection(s){': ' + '; '.join(why) if why else ''} -> {folder}", soft_wrap=True)
        _say_push(plans)
    else:
        x, y, z = best.position
        how = (f"jaws at yaw {np.degrees(best.yaw):.0f} deg, {100 * best.width:.1f} cm across" if best.tool == "jaws"
               else "suction cup on the surface")
        quality = "" if best.quality is None else f", predicted success {best.quality:.2f}"
        console.print(f"{len(plans.grasps)} grasp(s) from {len(plans)} planned of {plans.detections} detections in "
                      f"{plans.timing_ms['total']:.0f} ms; best: "
                      f"({x:.3f}, {y:.3f}, {z:.3f}) m in {plans.frame}, {how}{quality}, detector score {best.score:.2f} "
                      f"-> {plan_path}, {overlay}", soft_wrap=True)
        if best.push is not None:
            _say_push([best])


def parse_flange_pose(text: str | None):
    """--flange-pose x,y,z,qx,qy,qz,qw -> 4x4 (None: not given); malformed: one line."""
    if text is None:
        return None
    import numpy as np

    from binpick.picking.camera_info import quaternion_to_matrix

    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 7 or not all(np.isfinite(values)):
        raise ConfigError(f"--flange-pose {text!r}: give x,y,z,qx,qy,qz,qw (metres, then the quaternion in ROS's order)")
    pose = np.eye(4)
    pose[:3, 3] = values[:3]
    pose[:3, :3] = quaternion_to_matrix(values[3:])
    return pose


def check_stroke(plans, planner) -> None:
    """A hand with jaws alone, no grasp, and (nearly) every candidate on every detection wider than the
    jaws open: the cell's stroke is wrong (mm for m?) or the products are too big for it. One line, not
    an empty plan. Nearly: a sliver of an instance at a box's edge may be narrow and blocked."""
    from binpick.grasping.candidates import TOO_WIDE

    if plans.grasps or planner.tools != ("jaws",) or not len(plans):
        return
    counts = [(plan.rejected.get(TOO_WIDE, 0), sum(plan.rejected.values())) for plan in plans]
    wide, every = sum(c[0] for c in counts), sum(c[1] for c in counts)
    if every and wide >= 0.9 * every:
        widest = planner.gripper.opening - planner.gripper.margin
        raise ConfigError(f"{wide} of {every} grasp candidates are wider than the jaws take ({100 * widest:.1f} cm: stroke "
                          f"{100 * planner.gripper.opening:.1f} cm less the margin): check the cell's gripper.jaws.stroke "
                          "(metres), or this product needs a wider gripper or a cup")


def _say_push(plans) -> None:
    """The push the first plan offers, where no grasp fits it well (the closed jaws' path in the base frame)."""
    push = next((p.push for p in plans if p.push is not None), None)
    if push is not None:
        (x0, y0, z0), (x1, y1, _) = push["start"], push["end"]
        console.print(f"a push would give the fingers room: the closed jaws down onto ({x0:.3f}, {y0:.3f}, {z0:.3f}) m, "
                      f"along to ({x1:.3f}, {y1:.3f}) (the plan's push)", soft_wrap=True)


def _fulfil(pipeline, products: list[str], orders: int, seed: int, run_dir: Path, rerun: bool = False) -> dict:
    """Run the orders with a progress bar, then print their table and the summary (and, with
    ``rerun``, record each order to run_dir/orders.rrd)."""
    if rerun:
        from binpick.viz.recording import OrderRecording

        with OrderRecording(run_dir / "orders.rrd") as recording:
            pipeline.recording = recording
            summary = _fulfil(pipeline, products, orders, seed, run_dir)
        console.print(f"3D recording: {run_dir / 'orders.rrd'} (rerun {run_dir / 'orders.rrd'})", soft_wrap=True)
        return summary
    from binpick.warehouse.orders import fulfil

    table = Table(title=f"{orders} order{'s' if orders > 1 else ''}")
    from binpick.warehouse.orders import results_json
    from binpick.warehouse.report import COLUMNS, order_outcome

    for column in COLUMNS:
        table.add_column(column, no_wrap=column != "result")  # long failure reasons wrap; the rest stays whole
    with progress() as callback, callback.task("orders done", orders) as task:

        def row(result) -> None:
            seen = "?" if result.seen is None else "yes" if result.seen else "no"
            words = order_outcome(results_json([result])[0])  # as the report says it: a wrong product is named
            outcome = Text(words, style="green" if result.success else "red")
            table.add_row(str(result.order), result.product, seen, outcome,
                          str(result.grasps), str(result.detections), f"{result.seconds:.1f}")
            task.update(advance=1)

        summary, _ = fulfil(pipeline, products, orders, seed, run_dir, on_order=row)
    console.print(table)
    right = "n/a" if summary["right_product"] is None else format(summary["right_product"], ".0%")
    console.print(f"pick success {summary['pick_success']:.0%}, right product {right}, {summary['picks_per_min']} picks/min, "
                  f"{summary['orders']} orders in {summary['wall_s']} s")
    if "arm" in summary:
        arm = summary["arm"]
        cycle = "—" if arm["cycle_s_median"] is None else f"{arm['cycle_s_median']:.2f} s"
        console.print(f"arm: cycle {cycle} per placed pick (median, robot time), {arm['picks_per_hour']:.0f} picks/h "
                      f"of robot time, {arm['collisions']} collision(s), {sum(arm['dropped_for_reach'].values())} grasp(s) "
                      "dropped for reach", soft_wrap=True)
    console.print(f"report: {run_dir / 'report.html'} (GIFs and results.json beside it)", soft_wrap=True)
    return summary


# The demo's orders, in turn: four products the shipped detector was trained on, two held out (duck, can).
DEMO_PRODUCTS = ("robosuite/milk", "robosuite/cereal", "pybullet/duck", "procedural/box_03", "robosuite/bottle", "robosuite/can")


@app.command("demo")
def demo(
    orders: Annotated[int, typer.Option(help="Orders to fulfil (products cycle through the demo's list)")] = 6,
    out: Annotated[Path | None, typer.Option(help="Folder for the report, GIFs and results.json (default: runs/demo/<time>)")] = None,
    seed: Annotated[int, seed_option("Seed of the first order's bin")] = 0,
    robot: RobotOption = "floating",
    gripper: GripperOption = DEFAULT_GRIPPER,
    rerun: RerunOption = False,
) -> None:
    """The main job: fulfil a handful of orders end to end with the shipped detector, products seen in
    its training and zero-shot ones, and write an HTML report with each order's detections and GIF."""
    from binpick.core.config import check_range
    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.grasping import GraspPlanner
    from binpick.sim import default_library
    from binpick.warehouse.pipeline import PickPipeline

    check_range("orders", orders, 1, 1000, integer=True)
    run_dir = ensure_dir(out or Path("runs/demo") / time.strftime("%Y%m%d-%H%M%S"), "--out")
    model = Detector.load(PICKING).inference_network
    _fulfil(PickPipeline(model, default_library(), grasp=GraspPlanner.load(DEFAULT_POLICY, hand=gripper), robot=robot,
                         gripper=gripper), list(DEMO_PRODUCTS), orders, seed, run_dir, rerun)

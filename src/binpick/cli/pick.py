"""Orders: `binpick pick`, `binpick demo`; a cell: `binpick cell`, `binpick calibrate`."""

from __future__ import annotations

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
    RerunOption,
    RobotOption,
    RuntimeOption,
    app,
    console,
    load_cell,
    product_library,
    progress,
    seed_option,
)
from binpick.core.errors import ConfigError
from binpick.core.files import ensure_dir


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
    the_cell = load_cell(cell, robot)  # another arm than the file's, or a tool point the arm's hand cannot have: one line, now
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

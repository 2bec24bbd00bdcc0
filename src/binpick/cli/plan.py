"""`binpick plan`: grasps from one real RGB-D frame (files), no simulator."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import typer

from binpick.cli.app import (
    DEFAULT_GRIPPER,
    DEFAULT_POLICY,
    CellOption,
    GripperOption,
    PlanRobotOption,
    RerunOption,
    RuntimeOption,
    app,
    check_png_path,
    console,
    load_cell,
    output_folder,
    parse_dimensions,
    save_png,
    warn,
)
from binpick.core.errors import ConfigError
from binpick.core.files import check_output_file


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
    the_cell = load_cell(cell, robot)  # checked against the arm before any output folder is made
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

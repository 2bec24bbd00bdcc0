"""Planning latency per frame as a warm ``Picker`` caller sees it, at several camera resolutions.

    python benchmarks/plan_latency.py [--frames 12] [--repeats 3] [--gripper both]

Frames: the sample frame that ships with binpick and bins rendered with the realistic depth sensor
(holes, noise, a tilted camera), each cropped to the target's aspect and resized to 640x480,
1920x1080 and 4000x3000 (the camera's intrinsics scaled with it), as from cameras of those
resolutions. Per frame, ``Picker.plan`` with the product's shop photo is timed in this process after
two warm-up frames (file reading and decoding excluded: a camera driver hands frames over in memory).
Writes ``planning_latency`` to results/plan.json: median and p95 per resolution, the planner's stages,
peak RSS. Run it on an idle machine: on 2 shared cores a second job doubles every figure.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))

import _common  # noqa: E402
import numpy as np  # noqa: E402

SIZES = ((640, 480), (1920, 1080), (4000, 3000))
TARGETS_MS = {"640x480": 100.0, "1920x1080": 150.0, "4000x3000": 300.0}


def simulated_frames(count: int) -> list[tuple[np.ndarray, np.ndarray, object, np.ndarray]]:
    """(rgb, depth m, CameraInfo, shop photo) of ``count`` bins seen by the realistic sensor."""
    from binpick.core.depth import as_camera_depth
    from binpick.grasping import PinholeCamera
    from binpick.picking.camera_info import CameraInfo
    from binpick.sim import default_library
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.mjcf import CameraSpec
    from binpick.sim.photos import catalogue_photos
    from binpick.sim.sensor import load_sensor

    library = default_library()
    products = sorted(library.products)
    frames = []
    for index in range(count):
        rng = np.random.default_rng([7, index])
        target = library[products[int(rng.integers(len(products)))]]
        others = [library[products[i]] for i in rng.choice(len(products), 3, replace=False) if products[i] != target.id]
        world = BinWorld(target, others, max_copies=6, camera=CameraSpec(size=480), sensor=load_sensor("realistic"), seed=index)
        try:
            scene = world.scene(int(rng.integers(3, 7)), int(rng.integers(1, 4)), seed=index)
        finally:
            world.close()
        camera = PinholeCamera.from_record(scene.camera)
        info = CameraInfo(camera, base_frame="world")
        frames.append((scene.rgb, as_camera_depth(scene.depth), info, catalogue_photos(target)[0][0]))
    return frames


def measure(picker, frames, repeats: int, label: str = "") -> dict:
    """Median and p95 wall time of ``picker.plan`` per frame at each size, after two warm-up frames."""
    rows = {}
    for width, height in SIZES:
        sized = [(*at_size(r, d, i, width, height), photo) for r, d, i, photo in frames]
        for colour, metres, camera, photo in sized[:2]:  # warm-up: the first plans at a size allocate
            picker.plan(colour, metres, camera, photo=photo)
        times, stages = [], []
        for _ in range(repeats):
            for colour, metres, camera, photo in sized:
                tick = time.perf_counter()
                plans = picker.plan(colour, metres, camera, photo=photo)
                times.append(1000 * (time.perf_counter() - tick))
                stages.append(plans.timing_ms)
        key = f"{width}x{height}"
        rows[key] = {"median": round(float(np.median(times)), 1), "p95": round(float(np.percentile(times, 95)), 1),
                     "plans": len(times), "target_median": TARGETS_MS[key],
                     "stages_median": {k: round(float(np.median([s.get(k, 0.0) for s in stages])), 1) for k in stages[0]}}
        print(key, label, json.dumps(rows[key]), flush=True)
    return rows


def at_size(rgb: np.ndarray, depth: np.ndarray, info, width: int, height: int):
    """The frame cropped to ``width``:``height`` about its centre and resized to it, intrinsics to match."""
    import cv2

    from binpick.picking.camera_info import CameraInfo
    from binpick.grasping import PinholeCamera

    h0, w0 = rgb.shape[:2]
    aspect = width / height
    crop_w, crop_h = (w0, int(round(w0 / aspect))) if w0 / aspect <= h0 else (int(round(h0 * aspect)), h0)
    x0, y0 = (w0 - crop_w) // 2, (h0 - crop_h) // 2
    colour = cv2.resize(rgb[y0:y0 + crop_h, x0:x0 + crop_w], (width, height), interpolation=cv2.INTER_LINEAR)
    metres = cv2.resize(depth[y0:y0 + crop_h, x0:x0 + crop_w], (width, height), interpolation=cv2.INTER_NEAREST)
    K = np.array(info.camera.K, dtype=float)
    scale = width / crop_w
    K[0, 2], K[1, 2] = (K[0, 2] - x0 + 0.5) * scale - 0.5, (K[1, 2] - y0 + 0.5) * scale - 0.5
    K[0, 0], K[1, 1], K[0, 1] = K[0, 0] * scale, K[1, 1] * scale, K[0, 1] * scale
    camera = PinholeCamera(K, width, height, info.camera.camera_to_world)
    return colour, metres, CameraInfo(camera, info.D, info.distortion_model, info.base_frame, info.workspace)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=12, help="simulated bins besides the sample frame")
    parser.add_argument("--repeats", type=int, default=3, help="times each frame is planned")
    parser.add_argument("--gripper", default="both", choices=("jaws", "suction", "both"))
    args = parser.parse_args()

    import torch

    from binpick.picking import Picker
    from binpick.picking.frames import read_frame, read_photo
    from binpick.samples import SAMPLE_FRAME

    torch.set_num_threads(2)
    rgb, depth, info = read_frame(SAMPLE_FRAME / "rgb.png", SAMPLE_FRAME / "depth.png", SAMPLE_FRAME / "camera.yaml")
    frames = [(rgb, depth, info, read_photo(SAMPLE_FRAME / "photo.png"))] + simulated_frames(args.frames)
    picker = Picker.load(gripper=args.gripper)
    rows = measure(picker, frames, args.repeats)
    # the same frames with three plans per frame (Picker(max_grasps=3), as `binpick plan` makes by default)
    three = measure(Picker.load(gripper=args.gripper, max_grasps=3), frames, args.repeats, label="3 plans")
    path = _common.RESULTS / "plan.json"
    result = json.loads(path.read_text()) if path.is_file() else {}
    for key in ("benchmark", "machine", "provenance"):
        result.pop(key, None)
    result["planning_latency"] = {
        "gripper": args.gripper, "frames": len(frames), "repeats": args.repeats, "max_grasps": picker.max_grasps,
        "by_size": rows, "by_size_three_plans": three,
        "measured": ("benchmarks/plan_latency.py: Picker.plan wall time per frame in a warm process (file reading excluded), "
                     "2 threads, the Picker's default (the best feasible plan; by_size_three_plans: max_grasps=3); frames over 640x480 are planned at 640x480 pixels (binpick.picking.inputs.WORKING_PIXELS)"),
        "peak_rss_mib": round(_common.peak_rss_mib(), 1), "load_average_start": round(_common.LOAD_AT_START, 2),
        "load_average_end": round(os.getloadavg()[0], 2)}
    _common.write_result("plan", result)


if __name__ == "__main__":
    main()

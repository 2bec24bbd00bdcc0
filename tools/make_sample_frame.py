"""Make the sample camera frame that ships with binpick (``binpick/samples/bin_frame``), so that
``binpick plan`` runs straight after install on a frame as a real RGB-D camera gives it.

    python tools/make_sample_frame.py [--seed 0] [--product robosuite/can]

One order's bin of binpick's default set-up, seen by the ``realistic`` sensor (holes in shadows and
on dark surfaces, noise, a camera tilted from straight down over a tote a little off level) through
a 640x480 colour camera whose depth arrives at 320x240 (registered to colour, as a RealSense's
aligned depth at a lower resolution): ``rgb.png``, ``depth.png`` (16-bit millimetres, 0: no reading),
``camera.yaml`` (ROS camera_info plus the camera's tilted pose in the base frame), ``photo.png`` (the
product's cut-out shop photo) and ``truth.json`` (what the simulator knows; never read by the planner).
Seeds from ``--seed`` on are tried until the shipped planner finds the product and plans a grasp on
the frame's files (the seed used is in truth.json): a sample, not a benchmark.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

OUT = Path(__file__).resolve().parents[1] / "src" / "binpick" / "samples" / "bin_frame"
COLOUR, DEPTH = (640, 480), (320, 240)


def crop(rgb: np.ndarray, depth: np.ndarray, camera: dict, width: int, height: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """The centre ``width`` x ``height`` of a square render, the camera's principal point moved with it."""
    top, left = (rgb.shape[0] - height) // 2, (rgb.shape[1] - width) // 2
    K = np.array(camera["K"], dtype=float)
    K[0, 2] -= left
    K[1, 2] -= top
    return (rgb[top:top + height, left:left + width], depth[top:top + height, left:left + width],
            {**camera, "K": K.tolist(), "width": width, "height": height})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--product", default="robosuite/can")
    parser.add_argument("--tries", type=int, default=20)
    args = parser.parse_args()

    import cv2

    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.picking import Picker
    from binpick.picking.frames import read_frame, read_photo
    from binpick.sim import default_library
    from binpick.sim.mjcf import CameraSpec
    from binpick.sim.sensor import load_sensor
    from binpick.warehouse.export import cut_out, export_frame
    from binpick.warehouse.pipeline import PickPipeline

    pipeline = PickPipeline(Detector.load(PICKING).network, default_library(), camera=CameraSpec(size=COLOUR[0]),
                            sensor=load_sensor("realistic"))
    picker = Picker.load()
    for seed in range(args.seed, args.seed + args.tries):
        world, rng = pipeline.build_world(args.product, seed)
        try:
            scene = pipeline.settle(world, rng, seed)
        finally:
            world.close()
        rgb, depth, camera = crop(scene.rgb, scene.depth, scene.camera, *COLOUR)
        small = cv2.resize(depth, DEPTH, interpolation=cv2.INTER_NEAREST)  # the sensor's own, lower resolution
        instances = [{"product": i.product_id, "bbox": [i.bbox[0] - (scene.rgb.shape[1] - COLOUR[0]) // 2,
                                                        i.bbox[1] - (scene.rgb.shape[0] - COLOUR[1]) // 2, i.bbox[2], i.bbox[3]]}
                     for i in scene.instances]
        truth = {"product": args.product, "seed": seed, "made_by": "tools/make_sample_frame.py", "sensor": scene.sensor,
                 "colour_size": list(COLOUR), "depth_size": list(DEPTH), "instances": instances}
        with tempfile.TemporaryDirectory() as folder:
            export_frame(Path(folder), rgb, small, camera, cut_out(*pipeline.photo_and_mask(args.product)), truth)
            frame_rgb, frame_depth, info = read_frame(Path(folder) / "rgb.png", Path(folder) / "depth.png", Path(folder) / "camera.yaml")
            plans = picker.plan(frame_rgb, frame_depth, info, photo=read_photo(Path(folder) / "photo.png"))
            print(f"seed {seed}: {plans.detections} detections, {len(plans.grasps)} grasps, "
                  f"{scene.sensor.get('missing', 0):.0%} of depth missing", flush=True)
            if plans.grasps:
                if OUT.exists():
                    shutil.rmtree(OUT)
                shutil.copytree(folder, OUT)
                OUT.chmod(0o755)
                for file in OUT.iterdir():
                    file.chmod(0o644)  # a temporary folder's files are private; the package's are for everyone
                print(f"wrote {OUT}: {json.dumps({k: truth[k] for k in ('product', 'seed')})}")
                return
    raise SystemExit(f"no seed in {args.seed}..{args.seed + args.tries - 1} gave a frame the planner found a grasp in")


if __name__ == "__main__":
    main()

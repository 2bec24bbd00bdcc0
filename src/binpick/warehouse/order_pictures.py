"""An order's pictures: the bin with its detections, the grasps tried (jaw lines and cup circles, green
where they placed the product) and the shop photo; its depth; a GIF of the picks."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from binpick.core.depth import as_camera_depth
from binpick.core.files import atomic_write
from binpick.grasping import PinholeCamera
from binpick.picking.plans import cup_pixels, jaw_pixels
from binpick.sim.bin_scene import Scene
from binpick.warehouse.grasping import Reason
from binpick.warehouse.orders import Attempt


def write_order_pictures(out: Path, name: str, scene: Scene, boxes, scores, frames, attempts: list[Attempt],
                         photo: np.ndarray, min_score: float, opening: float) -> tuple[str, str, str]:
    """``name``.png (the bin, detections above ``min_score``, the grasps tried, the photo), ``name``_depth.png
    and ``name``.gif (``frames``: (image, caption) pairs) in ``out``; their file names."""
    from PIL import Image

    from binpick.viz.detection import captioned, depth_picture, draw_cups, draw_jaws, overlay

    picture = overlay(scene.rgb, boxes, scores, None, photo, min_score=min_score)
    picture = draw_cups(draw_jaws(picture, tried_jaws(scene, attempts, opening)), tried_cups(scene, attempts))
    atomic_write(out / f"{name}.png", lambda handle: Image.fromarray(picture).save(handle, format="PNG"))
    depth = depth_picture(as_camera_depth(scene.depth))
    atomic_write(out / f"{name}_depth.png", lambda handle: Image.fromarray(depth).save(handle, format="PNG"))
    kept = [f for i, f in enumerate(frames) if i % 2 == 0 or i == len(frames) - 1 or f[1] != frames[i - 1][1]]
    images = [Image.fromarray(captioned(image, text)) for image, text in kept]
    atomic_write(out / f"{name}.gif", lambda handle: images[0].save(handle, format="GIF", save_all=True,
                                                                      append_images=images[1:], duration=[80] * (len(images) - 1) + [1500],
                                                                      loop=0))
    return f"{name}.gif", f"{name}.png", f"{name}_depth.png"


def tried_jaws(scene: Scene, attempts: list[Attempt], opening: float) -> list:
    """Each jaw grasp tried, as its open fingers' pixels: the jaw lines of the order's picture."""
    camera = PinholeCamera.from_record(scene.camera)
    tried = (a for a in attempts if a.outcome is not Reason.NO_GRASP)
    return [(*jaw_pixels(camera, attempt.grasp_point, attempt.yaw, opening), attempt.outcome is Reason.PLACED, str(number))
            for number, attempt in enumerate(tried, start=1) if attempt.tool != "suction"]


def tried_cups(scene: Scene, attempts: list[Attempt]) -> list:
    """Each suction grasp tried, as its cup's lip in pixels: the circles of the order's picture."""
    camera = PinholeCamera.from_record(scene.camera)
    tried = (a for a in attempts if a.outcome is not Reason.NO_GRASP)
    return [(*cup_pixels(camera, attempt.grasp_point), attempt.outcome is Reason.PLACED, str(number))
            for number, attempt in enumerate(tried, start=1) if attempt.tool == "suction"]

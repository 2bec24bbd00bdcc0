"""Scenes as a real RGB-D camera would hand them over, so ``binpick plan`` (and a user) can try them
at once: ``rgb.png``, ``depth.png`` (16-bit, millimetres), ``camera.yaml`` (ROS ``camera_info`` layout
plus the camera's pose in the base frame), ``photo.png`` (the ordered product's shop photo) and
``truth.json`` (what the simulator knows: the product, every instance's box, never read by the
planner)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from binpick.core.errors import ConfigError, OutputPathError
from binpick.core.files import atomic_write, atomic_write_text, ensure_dir
from binpick.grasping import PinholeCamera
from binpick.core.depth import depth_millimetres
from binpick.picking.camera_info import CameraInfo, write_camera_info

FILES = ("rgb.png", "depth.png", "camera.yaml", "photo.png", "truth.json")


def _png(path: Path, array: np.ndarray) -> None:
    from PIL import Image

    atomic_write(path, lambda handle: Image.fromarray(array).save(handle, format="PNG"))


def cut_out(photo: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """The photo as RGBA, its alpha the product mask (how shops publish cut-out product photos)."""
    if mask is None:
        return np.asarray(photo, np.uint8)
    return np.dstack([np.asarray(photo, np.uint8)[..., :3], np.where(mask, 255, 0).astype(np.uint8)])


def export_frame(out: Path, rgb: np.ndarray, depth_m: np.ndarray, camera: dict | PinholeCamera, photo: np.ndarray,
                 truth: dict[str, Any]) -> Path:
    """Write one frame's files into ``out`` (created); ``photo`` RGB or RGBA (alpha: the product)."""
    out = ensure_dir(Path(out), "export folder")
    pinhole = camera if isinstance(camera, PinholeCamera) else PinholeCamera.from_record(camera)
    _png(out / "rgb.png", np.asarray(rgb, np.uint8))
    _png(out / "depth.png", depth_millimetres(depth_m))
    write_camera_info(CameraInfo(pinhole, base_frame="world"), out / "camera.yaml")
    _png(out / "photo.png", np.asarray(photo, np.uint8))
    atomic_write_text(out / "truth.json", json.dumps(truth, indent=1))
    return out


def export_dataset_scene(data: Path, index: int, out: Path, library=None) -> Path:
    """Scene ``index`` of a generated data set in the files a real camera gives. The shop photo is
    the data set's own (randomised products) or rendered from the product library."""
    from binpick.detection.data import read_image
    from binpick.warehouse.coco import read_scene

    record, _ = read_scene(Path(data), index)
    camera = record.get("camera")
    if not camera:
        raise ConfigError(f"scene {index} of {data} has no camera record: regenerate the data set with this binpick")
    target = record["target"]
    photo_path = Path(data) / "photos" / f"{target.replace('/', '_')}.png"
    from binpick.sim import default_library
    from binpick.sim.photos import shop_photo

    library = library or default_library()
    if target in library.products:  # rendered again with its mask, as a cut-out
        photo = cut_out(*shop_photo(library[target], with_mask=True))
    elif photo_path.is_file():
        photo = read_image(photo_path)
    else:
        raise ConfigError(f"scene {index}'s product {target!r} is not in the product library and the data set has no photo of it")
    out = ensure_dir(Path(out), "--out")
    from binpick.core.files import inside, require_file

    sources = [require_file(inside(data, record[key] if key in record else fallback, what), what) for key, fallback, what in
               (("file_name", None, "scene image"), ("depth_file", f"depth/{index:06d}.png", "depth image"))]
    for source, name in zip(sources, ("rgb.png", "depth.png")):  # the depth is already 16-bit millimetres
        try:
            shutil.copyfile(source, out / name)
        except OSError as error:
            raise OutputPathError(f"cannot write {str(out / name)!r}: {error.strerror or type(error).__name__}") from None
    write_camera_info(CameraInfo(PinholeCamera.from_record(camera), base_frame="world"), out / "camera.yaml")
    _png(out / "photo.png", photo)
    truth = {"product": target, "source": {"data": str(data), "scene": index, "seed": record.get("seed")},
             "instances": [{"product": a["product"], "bbox": a["bbox"], "visible_fraction": a.get("visible_fraction"),
                            "pickable": a.get("pickable", {})} for a in record["annotations"]]}
    atomic_write_text(out / "truth.json", json.dumps(truth, indent=1))
    return out

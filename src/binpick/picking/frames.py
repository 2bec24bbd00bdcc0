"""One RGB-D frame from files, as ``binpick plan`` takes it: colour (PNG/JPEG), depth (16-bit PNG in
millimetres or ``.npy`` in metres) and the camera's ``camera_info`` YAML. Sizes are checked against
each other and the calibration before any model is run."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from binpick.core.errors import InputFileError
from binpick.core.depth import read_depth
from binpick.picking.camera_info import CameraInfo, read_camera_info
from binpick.picking.inputs import check_frame


def read_colour(path: str | Path, what: str = "colour image") -> np.ndarray:
    from binpick.detection.data import read_image

    return read_image(Path(path), what=what)


def read_frame(rgb: str | Path, depth: str | Path, camera: str | Path,
               flange_to_base: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, CameraInfo]:
    """(rgb uint8, depth metres float32, calibration); every mismatch is one line naming the files.
    ``flange_to_base``: the flange's pose when the frame was taken, for a camera on the wrist."""
    colour = read_colour(rgb)
    metres = read_depth(depth)
    info = read_camera_info(camera, flange_to_base)
    try:
        check_frame(colour, metres, info.camera)
    except InputFileError as error:
        raise InputFileError(f"{Path(rgb).name} / {Path(depth).name} / {Path(camera).name}: {error}") from None
    return colour, metres, info


def read_photo(path: str | Path) -> np.ndarray:
    """A shop photo: RGBA where the file has transparency (its alpha marks the product), else RGB."""
    from binpick.core.files import opened_image

    with opened_image(Path(path), "--photo") as image:
        transparent = image.mode in ("RGBA", "LA", "PA") or "transparency" in image.info
        array = np.asarray(image.convert("RGBA" if transparent else "RGB"))
    if array.size == 0 or min(array.shape[:2]) < 8:
        raise InputFileError(f"--photo {str(path)!r} is empty or smaller than 8 pixels")
    return array

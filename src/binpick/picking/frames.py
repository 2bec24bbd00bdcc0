"""One RGB-D frame from files, as ``binpick plan`` takes it: colour (PNG/JPEG), depth (16-bit PNG in
millimetres or ``.npy`` in metres) and the camera's ``camera_info`` YAML. Sizes are checked against
each other and the calibration before any model is run."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from binpick.errors import InputFileError
from binpick.depth import read_depth
from binpick.picking.camera_info import CameraInfo, read_camera_info
from binpick.picking.picker import check_frame


def read_colour(path: str | Path, what: str = "colour image") -> np.ndarray:
    from binpick.detection.data import read_image
    from binpick.errors import ConfigError
    from binpick.files import require_file

    path = require_file(Path(path), what)
    try:
        return read_image(path)
    except ConfigError as error:
        raise InputFileError(f"{what}: {error}") from None


def read_frame(rgb: str | Path, depth: str | Path, camera: str | Path) -> tuple[np.ndarray, np.ndarray, CameraInfo]:
    """(rgb uint8, depth metres float32, calibration); every mismatch is one line naming the files."""
    colour = read_colour(rgb)
    metres = read_depth(depth)
    info = read_camera_info(camera)
    try:
        check_frame(colour, metres, info.camera)
    except InputFileError as error:
        raise InputFileError(f"{Path(rgb).name} / {Path(depth).name} / {Path(camera).name}: {error}") from None
    return colour, metres, info


def read_photo(path: str | Path) -> np.ndarray:
    """A shop photo: RGBA where the file has transparency (its alpha marks the product), else RGB."""
    from PIL import Image, UnidentifiedImageError

    from binpick.files import require_file

    path = require_file(Path(path), "--photo")
    try:
        with Image.open(path) as image:
            transparent = image.mode in ("RGBA", "LA", "PA") or "transparency" in image.info
            array = np.asarray(image.convert("RGBA" if transparent else "RGB"))
    except (UnidentifiedImageError, OSError, ValueError) as error:
        raise InputFileError(f"--photo {str(path)!r} cannot be read ({str(error)[:80] or type(error).__name__})") from None
    if array.size == 0 or min(array.shape[:2]) < 8:
        raise InputFileError(f"--photo {str(path)!r} is empty or smaller than 8 pixels")
    return array

"""Depth images as cameras and files hold them: metres in memory, 16-bit whole millimetres in PNGs and
ROS frames (the ROS / RealSense convention).

Both grasp planning and the depth-reading detector need these, so they live below either.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


MAX_DEPTH = 10.0  # metres: anything farther is not a bin in front of a robot


def depth_problem(depth: np.ndarray) -> str | None:
    """What is wrong with a depth image in metres, or None: no valid reading, or a median beyond
    MAX_DEPTH (millimetres given as metres). Files and ROS frames are checked alike."""
    valid = depth[np.isfinite(depth) & (depth > 0)]
    if valid.size == 0:
        return "has no valid reading (all zero or not finite)"
    if float(np.median(valid)) > MAX_DEPTH:
        return f"reads {float(np.median(valid)):.0f} m at its median"
    return None


def depth_millimetres(depth: np.ndarray) -> np.ndarray:
    """Metres -> 16-bit whole millimetres (0: no reading), the ROS / RealSense convention."""
    depth = np.nan_to_num(np.asarray(depth, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(np.round(depth * 1000.0), 0, 65535).astype(np.uint16)


def millimetres_to_metres(raw: np.ndarray) -> np.ndarray:
    """16-bit millimetres -> metres (float32), exactly as :func:`read_depth` reads a PNG."""
    return np.asarray(raw).astype(np.float32) / 1000.0


def as_camera_depth(depth: np.ndarray) -> np.ndarray:
    """Depth as a real camera's 16-bit frame holds it: whole millimetres, back in metres."""
    return millimetres_to_metres(depth_millimetres(depth))


def read_depth(path: str | Path) -> np.ndarray:
    """A depth image in metres (float32): a 16-bit PNG in millimetres (the ROS / RealSense convention)
    or a ``.npy`` in metres (read without pickle). Wrong units or empty images are one clear line."""
    from binpick.core.errors import InputFileError
    from binpick.core.files import require_file

    path = require_file(Path(path), "depth image")
    if path.suffix.lower() == ".npy":
        try:
            loaded = np.load(path, allow_pickle=False)  # object arrays (pickles) are refused here
            if not isinstance(loaded, np.ndarray) or not (np.issubdtype(loaded.dtype, np.integer)
                                                          or np.issubdtype(loaded.dtype, np.floating)):
                raise ValueError(f"depth must be real numbers, got {getattr(loaded, 'dtype', type(loaded).__name__)}")
            depth = loaded.astype(np.float32)
        except (ValueError, OSError, EOFError, MemoryError) as error:
            raise InputFileError(f"depth image {str(path)!r} is not a numeric .npy array ({str(error)[:80]})") from None
    else:
        from binpick.core.files import opened_image

        with opened_image(path, "depth image") as image:
            raw = np.array(image)
        if raw.dtype not in (np.uint16, np.int32, np.uint32) or raw.ndim != 2:
            raise InputFileError(f"depth image {str(path)!r} must be a single-channel 16-bit PNG in millimetres "
                                 f"(got {raw.dtype} with shape {raw.shape})")
        depth = millimetres_to_metres(raw)
    if depth.ndim != 2:
        raise InputFileError(f"depth image {str(path)!r} must be 2-D (height x width), got shape {depth.shape}")
    problem = depth_problem(depth)
    if problem is not None:
        hint = "" if "no valid reading" in problem else ": give metres in .npy or millimetres in a 16-bit PNG"
        raise InputFileError(f"depth image {str(path)!r} {problem}{hint}")
    return depth

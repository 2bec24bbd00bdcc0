"""What a ROS node around the :class:`~binpick.picking.Picker` does, with no ROS in it, so the ROS 1
and ROS 2 nodes share every line of it: images in ROS encodings to arrays and back, colour, depth and
camera-info messages matched by time stamp, and a plan request answered from the latest matched frame.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from binpick.errors import BinpickError, InputFileError
from binpick.picking.camera_info import CameraInfo
from binpick.picking.picker import Picker, Plans

# encoding -> (dtype, channels) for the encodings cameras publish
ENCODINGS = {"rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "rgba8": (np.uint8, 4), "bgra8": (np.uint8, 4),
             "mono8": (np.uint8, 1), "16UC1": (np.uint16, 1), "mono16": (np.uint16, 1), "32FC1": (np.float32, 1)}


def image_array(encoding: str, height: int, width: int, step: int, data: bytes, bigendian: bool = False) -> np.ndarray:
    """A ``sensor_msgs/Image``'s pixels as an array (rows may be padded to ``step`` bytes)."""
    if encoding not in ENCODINGS:
        raise InputFileError(f"image encoding {encoding!r} is not supported: use one of {', '.join(ENCODINGS)}")
    dtype, channels = ENCODINGS[encoding]
    dtype = np.dtype(dtype).newbyteorder(">" if bigendian else "<")
    row = width * channels * dtype.itemsize
    buffer = np.frombuffer(bytes(data), np.uint8)
    if step < row or buffer.size < step * height:
        raise InputFileError(f"{encoding} image of {width}x{height} has {buffer.size} bytes with step {step}: too few")
    rows = buffer[:step * height].reshape(height, step)[:, :row]
    array = np.ascontiguousarray(rows).view(dtype).reshape(height, width, channels)
    return array[..., 0] if channels == 1 else array


def image_fields(array: np.ndarray, encoding: str) -> dict:
    """The fields of a ``sensor_msgs/Image`` for ``array`` (rgb8, 16UC1 or 32FC1, little-endian)."""
    dtype, channels = ENCODINGS[encoding]
    array = np.ascontiguousarray(np.asarray(array, dtype=np.dtype(dtype).newbyteorder("<")))
    height, width = array.shape[:2]
    return {"encoding": encoding, "height": int(height), "width": int(width), "is_bigendian": 0,
            "step": int(width * channels * array.itemsize), "data": array.tobytes()}


def colour_of(encoding: str, array: np.ndarray) -> np.ndarray:
    """RGB uint8 from any supported colour encoding."""
    if array.ndim == 2:
        return np.repeat(array.astype(np.uint8)[..., None], 3, axis=2)
    rgb = array[..., :3]
    return np.ascontiguousarray(rgb[..., ::-1] if encoding.startswith("bgr") else rgb)


def photo_of(encoding: str, array: np.ndarray) -> np.ndarray:
    """A shop photo from a goal: RGB, or RGBA (alpha marks the product) from rgba8/bgra8."""
    if array.ndim == 3 and array.shape[2] == 4:
        rgba = array[..., [2, 1, 0, 3]] if encoding.startswith("bgr") else array
        return np.ascontiguousarray(rgba)
    return colour_of(encoding, array)


def depth_of(encoding: str, array: np.ndarray) -> np.ndarray:
    """Metres (float32) from 16UC1 / mono16 (millimetres) or 32FC1 (metres), the ROS depth conventions."""
    if encoding in ("16UC1", "mono16"):
        return array.astype(np.float32) / 1000.0
    if encoding == "32FC1":
        return np.nan_to_num(array.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    raise InputFileError(f"depth encoding {encoding!r}: use 16UC1 (millimetres) or 32FC1 (metres)")


@dataclass(frozen=True)
class Topics:
    """A RealSense-style camera's topics (``aligned_depth_to_color``: depth registered to colour)."""

    colour: str = "/camera/color/image_raw"
    depth: str = "/camera/aligned_depth_to_color/image_raw"
    info: str = "/camera/color/camera_info"


@dataclass
class Frame:
    stamp: float  # seconds
    rgb: np.ndarray
    depth: np.ndarray  # metres
    camera: CameraInfo


class FrameSynchroniser:
    """Colour, depth and camera info matched by time stamp (within ``slop`` seconds), as
    ``message_filters.ApproximateTimeSynchronizer`` would: the latest complete triple is the frame
    a plan request uses. Thread-safe: ROS callbacks arrive on their own threads."""

    def __init__(self, slop: float = 0.05, keep: int = 10) -> None:
        self.slop, self.keep = slop, keep
        self._colour: list[tuple[float, np.ndarray]] = []
        self._depth: list[tuple[float, np.ndarray]] = []
        self._info: list[tuple[float, CameraInfo]] = []
        self._latest: Frame | None = None
        self._lock = threading.Lock()
        self._new = threading.Condition(self._lock)

    def _add(self, queue: list, stamp: float, item) -> None:
        with self._lock:
            queue.append((stamp, item))
            del queue[:-self.keep]
            self._match()

    def add_colour(self, stamp: float, rgb: np.ndarray) -> None:
        self._add(self._colour, stamp, rgb)

    def add_depth(self, stamp: float, depth: np.ndarray) -> None:
        self._add(self._depth, stamp, depth)

    def add_info(self, stamp: float, info: CameraInfo) -> None:
        self._add(self._info, stamp, info)

    def _match(self) -> None:
        for stamp, rgb in reversed(self._colour):
            depth = min(self._depth, key=lambda d: abs(d[0] - stamp), default=None)
            info = min(self._info, key=lambda d: abs(d[0] - stamp), default=None)
            if depth is not None and info is not None and abs(depth[0] - stamp) <= self.slop and abs(info[0] - stamp) <= self.slop:
                if self._latest is None or stamp > self._latest.stamp:
                    self._latest = Frame(stamp, rgb, depth[1], info[1])
                    self._new.notify_all()
                return

    def latest(self, timeout: float = 0.0, newer_than: float | None = None) -> Frame | None:
        """The latest matched frame (waiting up to ``timeout`` s for one newer than ``newer_than``)."""
        deadline = time.monotonic() + timeout
        with self._lock:
            while self._latest is None or (newer_than is not None and self._latest.stamp <= newer_than):
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._new.wait(remaining)
            return self._latest


class PlanRequests:
    """Answers ``plan(product_id | photo)`` from the latest synchronised frame. ``photo_for`` turns a
    product id into its shop photo (and the photo's product mask, or None), e.g. from a catalogue."""

    def __init__(self, picker: Picker, frames: FrameSynchroniser,
                 photo_for: Callable[[str], tuple[np.ndarray, np.ndarray | None]] | None = None, frame_timeout: float = 5.0,
                 size_for: Callable[[str], tuple[float, float, float]] | None = None) -> None:
        self.picker, self.frames, self.photo_for, self.frame_timeout = picker, frames, photo_for, frame_timeout
        self.size_for = size_for

    @classmethod
    def with_catalogue(cls, picker: Picker, library=None) -> PlanRequests:
        """Requests on a new synchroniser; product ids resolve to photos and sizes in ``library``."""
        if library is None:
            return cls(picker, FrameSynchroniser())
        return cls(picker, FrameSynchroniser(), catalogue(library), size_for=catalogue_sizes(library))

    def plan(self, product_id: str = "", photo: np.ndarray | None = None, max_grasps: int = 0, size=None,
             query_box=None, copies_only: bool = False) -> tuple[Frame, Plans]:
        """Plans on the latest frame. ``size``: the product's catalogue dimensions (m; none given: the
        catalogue's for ``product_id``, where the node has one). ``query_box`` (x, y, w, h pixels)
        points at the instance to pick instead of a product: it is planned first, then its copies
        (``copies_only``: the copies alone)."""
        if size is not None and len(size) == 0:
            size = None
        if size is None and product_id and self.size_for is not None:
            size = self.size_for(product_id)
        box = list(query_box) if query_box is not None and len(query_box) else None  # the picker checks it
        if box is None and (photo is None or photo.size == 0):
            if not product_id:
                raise BinpickError("the request names no product, photo or query box")
            if self.photo_for is None:
                raise BinpickError(f"this node has no product catalogue: send the photo of {product_id!r}")
            photo, mask = self.photo_for(product_id)
            if mask is not None:
                photo = np.dstack([photo[..., :3], np.where(mask, 255, 0).astype(np.uint8)])
        frame = self.frames.latest(timeout=self.frame_timeout)
        if frame is None:
            raise BinpickError(f"no synchronised colour + depth + camera_info frame within {self.frame_timeout:g} s")
        if box is not None:
            return frame, self.picker.plan(frame.rgb, frame.depth, frame.camera, query_box=box, max_grasps=max_grasps or None,
                                           size=size, copies_only=copies_only)
        plans = self.picker.plan(frame.rgb, frame.depth, frame.camera, photo=photo, max_grasps=max_grasps or None, size=size)
        return frame, plans


def catalogue_sizes(library):
    """A product id -> catalogue dimensions lookup over a product library."""
    def size_for(product_id: str):
        from binpick.sim.products import product_dimensions

        return product_dimensions(library[product_id])

    return size_for


def catalogue(library):
    """A product id -> (shop photo, product mask) lookup over a product library: the user's own photo
    where the product has one, else one rendered like the training data's (cached)."""
    cache: dict[str, tuple[np.ndarray, np.ndarray | None]] = {}

    def photo_for(product_id: str):
        if product_id not in cache:
            from binpick.detection.data import read_image
            from binpick.sim.photos import shop_photo

            product = library[product_id]
            cache[product_id] = (read_image(product.photo), None) if product.photo is not None else shop_photo(product, with_mask=True)
        return cache[product_id]

    return photo_for

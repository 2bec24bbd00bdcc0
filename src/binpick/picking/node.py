"""What a ROS node around the :class:`~binpick.picking.Picker` does, with no ROS in it, so the ROS 1
and ROS 2 nodes share every line of it: images in ROS encodings to arrays and back, colour, depth and
camera-info messages matched by time stamp, and a plan request answered from the latest matched frame.
"""

from __future__ import annotations

import json
import math
import numbers
import threading
import traceback
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from binpick.core.errors import BinpickError, InputFileError
from binpick.picking.camera_info import CameraInfo
from binpick.picking.picker import Picker, Plans

# encoding -> (dtype, channels) for the encodings cameras publish
ENCODINGS = {"rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "rgba8": (np.uint8, 4), "bgra8": (np.uint8, 4),
             "mono8": (np.uint8, 1), "16UC1": (np.uint16, 1), "mono16": (np.uint16, 1), "32FC1": (np.float32, 1)}


MAX_SIDE = 8192  # pixels: the largest side of an image message the node decodes (a 4K camera's is 3840)
MAX_GOAL_CHARS = 65536  # a goal is a few hundred characters of JSON
MAX_GRASPS = 100
MAX_PRODUCT_SIZE = 2.0  # metres: a catalogue dimension past this is no product a bin holds


def image_array(encoding: str, height: int, width: int, step: int, data: bytes, bigendian: bool = False) -> np.ndarray:
    """A ``sensor_msgs/Image``'s pixels as an array (rows may be padded to ``step`` bytes). A message
    whose fields disagree (too few bytes, a side of zero or past ``MAX_SIDE``) is one line."""
    if encoding not in ENCODINGS:
        raise InputFileError(f"image encoding {str(encoding)[:40]!r} is not supported: use one of {', '.join(ENCODINGS)}")
    if not (0 < height <= MAX_SIDE and 0 < width <= MAX_SIDE):
        raise InputFileError(f"image of {width}x{height} pixels: each side must be 1 to {MAX_SIDE}")
    dtype, channels = ENCODINGS[encoding]
    dtype = np.dtype(dtype).newbyteorder(">" if bigendian else "<")
    row = width * channels * dtype.itemsize
    buffer = np.frombuffer(bytes(data), np.uint8)
    if step < row or step > 4 * row + 64 or buffer.size < step * height:
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
class Goal:
    """One plan request as both nodes take it, checked: a product id, a query box or a photo (sent
    beside it), how many grasps, the catalogue size, whether only the copies are wanted."""

    id: str = ""
    product_id: str = ""
    max_grasps: int = 0  # 0: the picker's own number
    size: list[float] | None = None
    query_box: list[float] | None = None
    copies_only: bool = False
    photo: np.ndarray | None = field(default=None, repr=False)


def _text_field(goal: Mapping, key: str) -> str:
    value = goal.get(key, "")
    if not isinstance(value, str) or len(value) > 256 or any(ord(c) < 32 for c in value):
        raise InputFileError(f"goal field {key!r} must be text of at most 256 characters on one line")
    return value


def _numbers_field(goal: Mapping, key: str, count: int, positive: bool = False, most: float | None = None) -> list[float] | None:
    value = goal.get(key)
    if value is None or (isinstance(value, (list, tuple)) and len(value) == 0):
        return None
    if not isinstance(value, (list, tuple)) or len(value) != count:
        raise InputFileError(f"goal field {key!r} must be a list of {count} numbers, got {str(value)[:60]}")
    if any(isinstance(v, bool) or not isinstance(v, numbers.Real) for v in value):
        raise InputFileError(f"goal field {key!r} must hold numbers only, got {str(value)[:60]}")
    checked = [float(v) for v in value]
    if not all(math.isfinite(v) for v in checked) or (positive and min(checked) <= 0):
        raise InputFileError(f"goal field {key!r} must hold finite{' positive' if positive else ''} numbers, got {checked}")
    if most is not None and max(checked) > most:
        raise InputFileError(f"goal field {key!r} must hold numbers of at most {most:g}, got {checked}")
    return checked


def parse_goal(goal: Mapping, photo: np.ndarray | None = None) -> Goal:
    """A goal's fields checked once, for either node: every bad field is one line naming it."""
    if not isinstance(goal, Mapping):
        raise InputFileError(f"a goal must be a JSON object, got {type(goal).__name__}")
    unknown = sorted(set(goal) - {"id", "product_id", "max_grasps", "size", "query_box", "copies_only"})
    if unknown:
        raise InputFileError(f"goal has unknown fields {', '.join(map(repr, unknown))[:120]} (fields: id, product_id, "
                             "max_grasps, size, query_box, copies_only)")
    max_grasps = goal.get("max_grasps", 0)
    if isinstance(max_grasps, float) and math.isfinite(max_grasps) and max_grasps.is_integer():
        max_grasps = int(max_grasps)
    if isinstance(max_grasps, bool) or not isinstance(max_grasps, int) or not 0 <= max_grasps <= MAX_GRASPS:
        raise InputFileError(f"goal field 'max_grasps' must be a whole number from 0 (the node's default) to {MAX_GRASPS}, "
                             f"got {str(max_grasps)[:40]}")
    copies_only = goal.get("copies_only", False)
    if not isinstance(copies_only, bool):
        raise InputFileError(f"goal field 'copies_only' must be true or false, got {str(copies_only)[:40]}")
    return Goal(_text_field(goal, "id"), _text_field(goal, "product_id"), max_grasps,
                _numbers_field(goal, "size", 3, positive=True, most=MAX_PRODUCT_SIZE), _numbers_field(goal, "query_box", 4), copies_only, photo)


def request_id_of(goal) -> str:
    """A goal's id where it has a readable one (to address the answer to a goal that is otherwise bad)."""
    value = goal.get("id", "") if isinstance(goal, Mapping) else ""
    return value if isinstance(value, str) and len(value) <= 256 else ""


def json_depth(text: str) -> int:
    """How deep JSON ``text`` nests (brackets inside strings not counted), without parsing it."""
    depth = deepest = 0
    in_string = escaped = False
    for character in text:
        if in_string:
            if escaped:
                escaped = False
            elif character == "\\":
                escaped = True
            elif character == '"':
                in_string = False
        elif character == '"':
            in_string = True
        elif character in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif character in "]}":
            depth -= 1
    return deepest


def parse_goal_json(text: str) -> dict:
    """The JSON of a ROS 2 goal as a mapping: too long, nested past a few levels or not JSON is one line."""
    if not isinstance(text, str) or len(text) > MAX_GOAL_CHARS:
        raise InputFileError(f"a goal is at most {MAX_GOAL_CHARS} characters of JSON")
    deepest = json_depth(text)
    if deepest > 4:
        raise InputFileError(f"a goal's JSON nests {deepest} levels deep; a goal nests two")
    try:
        goal = json.loads(text)
    except (ValueError, RecursionError) as error:
        raise InputFileError(f"a goal must be JSON: {str(error)[:80]}") from None
    if not isinstance(goal, dict):
        raise InputFileError(f"a goal must be a JSON object, got {type(goal).__name__}")
    return goal


class Guard:
    """Runs a node's callbacks so that none can take the node down: a camera message binpick refuses
    (a bad encoding, size or stamp: a :class:`BinpickError`) is dropped with a one-line warning (at
    most one per ``every`` seconds per topic, and a count); any other exception is the node's own bug,
    counted apart as an internal error with its traceback in the node's log, so that a crash is never
    mistaken for a clean refusal. A bad goal is answered by the caller's ``on_error``."""

    def __init__(self, warn: Callable[[str], None], every: float = 5.0) -> None:
        self.warn, self.every = warn, every
        self.dropped: dict[str, int] = {}  # refused input, per topic
        self.errors: dict[str, int] = {}  # internal errors, per topic
        self._last: dict = {}  # when each topic's last warning was logged
        self._lock = threading.Lock()
        self._published = (0, 0)  # (refused, errors) the last report covered

    def drop(self, topic: str, error: BaseException) -> None:
        if not isinstance(error, BinpickError):
            with self._lock:
                self.errors[topic] = self.errors.get(topic, 0) + 1
                count = self.errors[topic]
                now, key = time.monotonic(), ("error", topic)
                if now - self._last.get(key, -math.inf) < self.every:  # a bug at the camera's rate: counted, logged
                    return  # with its traceback once per ``every`` seconds, not flooding the log
                self._last[key] = now
            trace = "".join(traceback.format_exception(type(error), error, error.__traceback__)).rstrip()
            self.warn(f"binpick: internal error on {topic} ({count} so far), the message dropped:\n{trace}")
            return
        with self._lock:
            self.dropped[topic] = self.dropped.get(topic, 0) + 1
            now = time.monotonic()
            if now - self._last.get(topic, -math.inf) < self.every:
                return
            self._last[topic] = now
            count = self.dropped[topic]
        self.warn(f"binpick: dropped a message on {topic} ({count} so far): {describe(error)}")

    def report(self) -> tuple[str, str] | None:
        """JSON of the refused and of the internal-error counts per topic (for the node's ``dropped``
        and ``errors`` topics) when either changed since the last report, else None."""
        with self._lock:
            totals = (sum(self.dropped.values()), sum(self.errors.values()))
            if totals == self._published:
                return None
            self._published = totals
            return json.dumps(dict(sorted(self.dropped.items()))), json.dumps(dict(sorted(self.errors.items())))

    def summary(self) -> str:
        """What was refused and what failed inside, per topic (a node prints it when it stops)."""
        with self._lock:
            dropped, errors = dict(self.dropped), dict(self.errors)
        lines = [f"binpick: dropped {count} messages on {topic}" for topic, count in sorted(dropped.items())]
        lines += [f"binpick: {count} internal errors on {topic} (their tracebacks above)" for topic, count in sorted(errors.items())]
        return "; ".join(lines) or "binpick: dropped no messages"

    def frames(self, topic: str, callback: Callable) -> Callable:
        """``callback`` for camera messages on ``topic``, dropping the ones it cannot take."""
        def guarded(message) -> None:
            try:
                callback(message)
            except Exception as error:  # noqa: BLE001 - a camera topic must never stop the node
                self.drop(topic, error)

        return guarded


def describe(error: BaseException) -> str:
    """One line for a result or a log: binpick's own errors as they are, others with their type."""
    text = " ".join(str(error).split())[:300]
    return text if isinstance(error, BinpickError) else f"{type(error).__name__}: {text}"


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
        if not math.isfinite(stamp) or stamp < 0:
            raise InputFileError(f"a message's time stamp must be a finite time, got {stamp}")
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
                # the newest colour to arrive that has its depth and info (not the largest stamp: one
                # message stamped far in the future must not pin the planner to its frame)
                if self._latest is None or rgb is not self._latest.rgb:
                    self._latest = Frame(stamp, rgb, depth[1], info[1])
                    self._new.notify_all()
                return

    def latest(self, timeout: float = 0.0, newer_than: float | None = None) -> Frame | None:
        """The latest matched frame (waiting up to ``timeout`` s for one stamped after ``newer_than``)."""
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
    product id into its shop photos (each with its product mask, or None), e.g. from a catalogue."""

    def __init__(self, picker: Picker, frames: FrameSynchroniser,
                 photo_for: Callable[[str], list[tuple[np.ndarray, np.ndarray | None]]] | None = None, frame_timeout: float = 5.0,
                 size_for: Callable[[str], tuple[float, float, float]] | None = None) -> None:
        self.picker, self.frames, self.photo_for, self.frame_timeout = picker, frames, photo_for, frame_timeout
        self.size_for = size_for

    @classmethod
    def with_catalogue(cls, picker: Picker, catalogue=None) -> PlanRequests:
        """Requests on a new synchroniser; product ids resolve through ``catalogue`` (``photos(id)`` and
        ``size(id)``, e.g. :class:`binpick.sim.catalogue.Catalogue`), where there is one."""
        if catalogue is None:
            return cls(picker, FrameSynchroniser())
        return cls(picker, FrameSynchroniser(), catalogue.photos, size_for=catalogue.size)

    def plan(self, product_id: str = "", photo: np.ndarray | None = None, max_grasps: int = 0, size=None,
             query_box=None, copies_only: bool = False) -> tuple[Frame, Plans]:
        """Plans on the latest frame. ``size``: the product's catalogue dimensions (m; none given: the
        catalogue's for ``product_id``, where the node has one). ``query_box`` (x, y, w, h pixels)
        points at the instance to pick instead of a product: it is planned first, then its copies
        (``copies_only``: the copies alone)."""
        checked = parse_goal({"product_id": product_id, "max_grasps": max_grasps, "copies_only": copies_only,
                              "size": None if size is None else list(size), "query_box": None if query_box is None else list(query_box)})
        size, query_box, max_grasps = checked.size, checked.query_box, checked.max_grasps
        if size is None and product_id and self.size_for is not None:
            size = self.size_for(product_id)
        box = query_box  # the picker checks it against the image
        if isinstance(photo, (list, tuple)):  # several photos of the product; none given: as no photo
            photo = [p for p in photo if p is not None and np.asarray(p).size] or None
        elif photo is not None and np.asarray(photo).size == 0:
            photo = None
        if box is not None and photo is not None:
            raise BinpickError("the request gives both a photo and a query box: give one (a box points at the instance itself)")
        if box is None and photo is None:
            if not product_id:
                raise BinpickError("the request names no product, photo or query box")
            if self.photo_for is None:
                raise BinpickError(f"this node has no product catalogue: send the photo of {product_id!r}")
            photo = [image if mask is None else np.dstack([image[..., :3], np.where(mask, 255, 0).astype(np.uint8)])
                     for image, mask in self.photo_for(product_id)]
        frame = self.frames.latest(timeout=self.frame_timeout)
        if frame is None:
            raise BinpickError(f"no synchronised colour + depth + camera_info frame within {self.frame_timeout:g} s")
        if box is not None:
            return frame, self.picker.plan(frame.rgb, frame.depth, frame.camera, query_box=box, max_grasps=max_grasps or None,
                                           size=size, copies_only=copies_only)
        plans = self.picker.plan(frame.rgb, frame.depth, frame.camera, photo=photo, max_grasps=max_grasps or None, size=size)
        return frame, plans

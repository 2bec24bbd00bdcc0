"""A pick node's parameter file: the camera, the cell, the topics and the planner in one YAML, the same
for the ROS 1 and the ROS 2 node (the launch files name it), read once and validated.

    camera: camera.yaml                    # camera_to_base (relative paths: from this file's folder)
    camera_frame: binpick_camera_optical_frame # the camera's tf frame, published from camera_to_base ("": not)
    cell: ../../configs/cells/franka_hand.yaml # your gripper (optional; else `gripper`)
    namespace: /binpick/plan_pick
    topics: {colour: /camera/color/image_raw, depth: /camera/aligned_depth_to_color/image_raw,
             info: /camera/color/camera_info}

ROS 2's own layout (``<node name or /**>: {ros__parameters: {...}}``, nested keys or dotted ones) is read
too, so a file written for ``ros2 launch`` serves as it is.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from binpick.core.errors import InputFileError

NAME = re.compile(r"/?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*/?")
FRAME = re.compile(r"[A-Za-z][A-Za-z0-9_/]*")
CHOICES = {"grasp": ("learnt", "analytic", "fixed"), "robot": ("floating", "panda", "ur5e"), "gripper": ("jaws", "suction", "both"),
           "runtime": ("torch", "onnx")}
PATHS = ("camera", "cell", "products", "weights", "grasp_weights")


@dataclass(frozen=True)
class NodeTopics:
    colour: str = "/camera/color/image_raw"
    depth: str = "/camera/aligned_depth_to_color/image_raw"
    info: str = "/camera/color/camera_info"


@dataclass(frozen=True)
class NodeParams:
    """Everything a pick node needs besides ROS itself; paths are absolute once loaded."""

    camera: Path | None = None
    camera_frame: str = "binpick_camera_optical_frame"  # not the camera driver's own frame: tf allows one parent
    cell: Path | None = None
    namespace: str = "/binpick/plan_pick"
    topics: NodeTopics = field(default_factory=NodeTopics)
    products: Path | None = None
    weights: Path | None = None
    grasp: str = "learnt"
    grasp_weights: Path | None = None
    gripper: str = "both"
    robot: str = "floating"
    runtime: str = "torch"

    @classmethod
    def load(cls, path: str | Path) -> NodeParams:
        """Every mistake is one line naming the key and the file."""
        from binpick.core.files import read_yaml

        path = Path(path)
        where = f"node parameter file {str(path)!r}"
        data = unwrap_ros2(read_yaml(path, "node parameter file"), where)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise InputFileError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})")
        values: dict[str, Any] = {}
        for key, value in data.items():
            if value is None:
                continue
            if key == "topics":
                values[key] = _topics(value, where)
            elif key in PATHS:
                if not isinstance(value, str) or not value.strip():
                    raise InputFileError(f"{where}: {key} must be a file path, got {value!r}")
                values[key] = (path.parent / Path(value).expanduser()).resolve()
            elif key in CHOICES:
                if value not in CHOICES[key]:
                    raise InputFileError(f"{where}: {key} must be one of {', '.join(CHOICES[key])}, got {value!r}")
                values[key] = value
            elif key == "namespace":
                values[key] = _name(value, key, where)
            elif key == "camera_frame":
                values[key] = check_frame_name(value, f"{where}: camera_frame")
        return cls(**values)


def check_frame_name(value: Any, what: str) -> str:
    """A tf frame name, or "" (no frame published)."""
    if not isinstance(value, str) or (value and not FRAME.fullmatch(value)):
        raise InputFileError(f"{what} must be a tf frame name like binpick_camera_optical_frame (or \"\" for none), got {value!r}")
    return value


def unwrap_ros2(data: Any, where: str) -> dict:
    """The parameters of a plain mapping, or of ROS 2's ``{node: {ros__parameters: {...}}}``: every
    section's parameters (``/**`` first, then the named nodes, which win), dotted keys nested."""
    if not isinstance(data, dict):
        raise InputFileError(f"{where} must be a mapping of parameters (camera, topics, ...)")
    sections = {k: v for k, v in data.items() if isinstance(v, dict) and "ros__parameters" in v}
    if sections:
        if len(sections) != len(data):
            other = next(k for k in data if k not in sections)
            raise InputFileError(f"{where}: {other!r} is not a node section with ros__parameters (a ROS 2 file has only those)")
        merged: dict[str, Any] = {}
        for name in sorted(sections, key=lambda k: k != "/**"):
            values = sections[name]["ros__parameters"]
            if not isinstance(values, dict):
                raise InputFileError(f"{where}: {name}.ros__parameters must be a mapping")
            _merge(merged, _nest(values, where), where)
        return merged
    return _nest(data, where)


def _nest(data: dict, where: str) -> dict:
    """``{"topics.colour": x}`` -> ``{"topics": {"colour": x}}``, merged with a ``topics:`` mapping beside it."""
    nested: dict[str, Any] = {}
    for key, value in data.items():
        head, _, rest = str(key).partition(".")
        _merge(nested, {head: {rest: value}} if rest else {head: value}, where)
    return nested


def _merge(into: dict, values: dict, where: str) -> None:
    for key, value in values.items():
        if isinstance(value, dict) and isinstance(into.get(key), dict):
            into[key] = {**into[key], **value}
        elif isinstance(value, dict) != isinstance(into.get(key, value), dict):
            raise InputFileError(f"{where}: {key} is given both as a value and as a mapping")
        else:
            into[key] = value


def _name(value: Any, key: str, where: str) -> str:
    if not isinstance(value, str) or not NAME.fullmatch(value):
        raise InputFileError(f"{where}: {key} must be a ROS graph name like /binpick/plan_pick, got {value!r}")
    return value


def _topics(value: Any, where: str) -> NodeTopics:
    if not isinstance(value, dict):
        raise InputFileError(f"{where}: topics must be a mapping of colour, depth and info")
    unknown = sorted(set(value) - {"colour", "depth", "info"})
    if unknown:
        raise InputFileError(f"{where}: unknown topic {unknown[0]!r} (colour, depth, info)")
    return NodeTopics(**{k: _name(v, f"topics.{k}", where) for k, v in value.items()})

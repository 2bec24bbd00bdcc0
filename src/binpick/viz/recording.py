"""Orders as a Rerun recording (``.rrd``): the bin in 3D as the camera saw it, the detections, the
grasp candidates and the gripper at its chosen grasp, on a timeline of orders, for the Rerun viewer
(``rerun runs/demo/<time>/orders.rrd``).

Per order (timeline ``order``), under ``world/`` (metres, the robot's base frame, z up):

- ``camera``: the camera's pose; ``camera/image``: its pinhole; ``camera/image/rgb``, ``.../depth``
  (a depth image in metres), ``.../detections`` (boxes labelled with the detector's score);
- ``bin/points``: the depth as a coloured point cloud;
- ``grasps/candidates``: each detection's chosen grasp point, labelled with its grasp quality;
- ``gripper``: the pose of the grasp tried first (translation and quaternion), ``gripper/jaws``
  the open jaws drawn in that frame, ``grasps/jaws`` every planned grasp's jaws;
- ``outcome``: a text document (product, result, attempts) and a line in the ``log``.

``pip install 'binpick[rerun]'`` brings rerun-sdk; writing a file opens no socket and starts no viewer.
"""

from __future__ import annotations

import uuid
from pathlib import Path
from typing import Any

import numpy as np

from binpick.core.errors import ConfigError

POINT_STRIDE = 2  # every second pixel of the depth image: ~20k points for a 320x240 frame
JAW_LENGTH = 0.05  # m: how far the drawn fingers reach up from the grasp point


def require_rerun():
    try:
        import rerun
    except ImportError:
        raise ConfigError("--rerun needs rerun-sdk: pip install 'binpick[rerun]'") from None
    return rerun


class OrderRecording:
    """``with OrderRecording(path) as rec: rec.frame(...)`` per order; the file is complete when the
    block ends (Rerun writes its footer then)."""

    def __init__(self, path: str | Path, name: str = "binpick") -> None:
        rr = require_rerun()
        self.rr, self.path = rr, Path(path)
        self.stream = rr.RecordingStream(name, recording_id=uuid.uuid4())
        self.stream.save(str(self.path))
        self.stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def __enter__(self) -> OrderRecording:
        self.stream.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stream.__exit__(*exc)

    def frame(self, order: int, product: str, rgb: np.ndarray, depth: np.ndarray, camera: Any, plans: Any,
              outcome: str | None = None, attempts: list[Any] | None = None) -> None:
        """One order: ``camera`` a :class:`~binpick.grasping.camera.PinholeCamera` (K, width, height,
        camera_to_world, points), ``plans`` the picker's :class:`~binpick.picking.plans.Plans` (boxes,
        scores, each plan's grasp), ``outcome`` what happened (None: planned only)."""
        rr, log = self.rr, self.stream.log
        self.stream.set_time("order", sequence=int(order))
        pose = np.asarray(camera.camera_to_world, dtype=np.float32)
        log("world/camera", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
        log("world/camera/image", rr.Pinhole(image_from_camera=np.asarray(camera.K, dtype=np.float32),
                                              width=int(camera.width), height=int(camera.height), camera_xyz=rr.ViewCoordinates.RDF))
        log("world/camera/image/rgb", rr.Image(np.ascontiguousarray(rgb[..., :3]), color_model="RGB"))
        metres = np.nan_to_num(np.asarray(depth, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        log("world/camera/image/depth", rr.DepthImage(metres, meter=1.0))
        boxes = np.asarray(plans.boxes if plans.boxes is not None else np.zeros((0, 4)), dtype=np.float32).reshape(-1, 4)
        scores = np.asarray(plans.scores if plans.scores is not None else np.zeros(0), dtype=np.float32).reshape(-1)
        log("world/camera/image/detections", rr.Boxes2D(array=boxes, array_format=rr.Box2DFormat.XYWH,
                                                        labels=[f"detector {s:.2f}" for s in scores]))
        self._points(camera, rgb, metres)
        self._grasps(plans)
        self._outcome(order, product, plans, outcome, attempts or [])

    def _points(self, camera: Any, rgb: np.ndarray, depth: np.ndarray) -> None:
        points = camera.points(depth)[::POINT_STRIDE, ::POINT_STRIDE]
        colour_rows = (np.arange(points.shape[0]) * POINT_STRIDE * rgb.shape[0] // depth.shape[0]).clip(0, rgb.shape[0] - 1)
        colour_cols = (np.arange(points.shape[1]) * POINT_STRIDE * rgb.shape[1] // depth.shape[1]).clip(0, rgb.shape[1] - 1)
        colours = rgb[colour_rows][:, colour_cols, :3]
        valid = np.isfinite(points).all(-1)
        self.stream.log("world/bin/points", self.rr.Points3D(points[valid], colors=colours[valid], radii=0.0015))

    def _grasps(self, plans: Any) -> None:
        rr, log = self.rr, self.stream.log
        feasible = [p for p in plans if p.position is not None]
        log("world/grasps/candidates", rr.Points3D(np.asarray([p.position for p in feasible], np.float32).reshape(-1, 3), radii=0.006,
                                                   labels=[f"grasp quality {p.quality:.2f}" if p.quality is not None else "grasp"
                                                           for p in feasible]))
        log("world/grasps/jaws", rr.LineStrips3D([s for p in feasible for s in _jaws_world(p)]))
        if feasible:
            best = feasible[0]
            log("world/gripper", rr.Transform3D(translation=np.asarray(best.position, np.float32),
                                                quaternion=rr.Quaternion(xyzw=np.asarray(best.orientation, np.float32))))
            half = float(best.opening or best.width or 0.08) / 2
            log("world/gripper/jaws", rr.LineStrips3D([[[-half, 0, 0], [-half, 0, JAW_LENGTH]], [[half, 0, 0], [half, 0, JAW_LENGTH]],
                                                       [[-half, 0, JAW_LENGTH], [half, 0, JAW_LENGTH]]], colors=[(40, 200, 60)]))
        else:
            log("world/gripper", rr.Clear(recursive=True))

    def _outcome(self, order: int, product: str, plans: Any, outcome: str | None, attempts: list[Any]) -> None:
        rr = self.rr
        tried = "".join(f"\n- attempt {i}: {a.outcome}" + (f" ({a.lifted_product} lifted)" if a.lifted_product else "")
                        for i, a in enumerate(attempts, 1))
        text = (f"# order {order}: {product}\n\n**{outcome or 'planned'}** — {len(plans.boxes) if plans.boxes is not None else 0} "
                f"detections, {len([p for p in plans if p.position is not None])} feasible grasps{tried}")
        self.stream.log("world/outcome", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN))
        level = rr.TextLogLevel.INFO if outcome in (None, "placed") else rr.TextLogLevel.WARN
        self.stream.log("log", rr.TextLog(f"order {order}: {product}: {outcome or 'planned'}", level=level))


def _jaws_world(plan: Any) -> list[list[list[float]]]:
    """Two fingers either side of the grasp point across the closing direction (yaw about z)."""
    half = float(plan.opening or plan.width or 0.08) / 2
    direction = np.array([np.cos(plan.yaw or 0.0), np.sin(plan.yaw or 0.0), 0.0])
    centre = np.asarray(plan.position, dtype=float)
    fingers = [centre + sign * half * direction for sign in (-1, 1)]
    return [[list(f), list(f + [0, 0, JAW_LENGTH])] for f in fingers]


def read_entities(path: str | Path) -> dict[str, set[str]]:
    """The entity paths of a recording and the archetypes logged at each (what a test checks)."""
    require_rerun()
    from rerun.chunk import RrdReader

    schema = RrdReader(str(path)).store().schema()
    found: dict[str, set[str]] = {}
    for column in schema.component_columns():
        if not column.is_property and column.archetype:
            found.setdefault(column.entity_path, set()).add(column.archetype.rsplit(".", 1)[-1])
    return found

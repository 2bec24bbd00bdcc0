"""A push that frees an instance no grasp fits: one lying against a tote wall or in a corner, or
pressed against a taller neighbour, where neither finger has room and a cup cannot seal on its curved
top (a ball, a lying can). The closed jaws press on the instance's top on the side that blocks it and
slide it away, so the next look finds room for the fingers (Danielczuk et al. 2018, linear pushes
that increase grasp access). From depth alone: what blocks it is whatever stands higher than the
instance's middle within LOOK_AROUND of its outline.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from binpick.grasping.instance import Surface
from binpick.grasping.frame import DepthFrame

PUSH_DISTANCE = 0.05  # m the closed fingertips slide the instance
PUSH_PRESS = 0.008  # m the closed fingertips go under the instance's top where they touch it
CONTACT_OFFSET = 0.6  # of the instance's radius: where the fingertips touch, from its centre towards what blocks it
LOOK_AROUND = 0.05  # m beyond the instance's outline: what stands higher there blocks the fingers
MIN_BLOCKING = 12  # pixels: fewer standing higher around it, and nothing blocks it (noise)
PUSH_WHEN_BELOW = 0.2  # a best grasp predicted to hold less often than this: push first


@dataclass(frozen=True)
class Push:
    """The closed fingertips' path in the base frame: down onto ``start``, along to ``end``, then up.
    ``yaw``: the jaws' closing direction, along the push (the closed fingers' narrow side leads)."""

    start: np.ndarray
    end: np.ndarray
    yaw: float

    def as_dict(self) -> dict:
        return {"start": [round(float(v), 4) for v in self.start], "end": [round(float(v), 4) for v in self.end],
                "yaw": round(float(self.yaw), 4)}


def plan_push(frame: DepthFrame, surface: Surface, distance: float = PUSH_DISTANCE) -> Push | None:
    """The push away from what stands around ``surface``'s instance higher than its middle (walls,
    taller neighbours), or None when nothing does: a push would not give the fingers more room."""
    centre = np.asarray(surface.centre, dtype=float)
    radius = float(np.percentile(np.linalg.norm(surface.xy - centre, axis=1), 98)) if len(surface.xy) else 0.0
    points = frame.points
    near = np.linalg.norm(points[..., :2] - centre, axis=-1) < radius + LOOK_AROUND  # NaN compares False
    v, u = np.nonzero(near)
    if not len(v):
        return None
    middle = 0.5 * (surface.top + surface.support)
    z = points[v, u, 2]
    higher = frame.valid[v, u] & (z > middle) & ~surface.on_instance(np.stack([u, v], axis=1).astype(float))
    if np.count_nonzero(higher) < MIN_BLOCKING:
        return None
    blocking = points[v[higher], u[higher], :2].astype(float)
    offsets = centre - blocking
    gaps = np.linalg.norm(offsets, axis=1)
    away = (offsets / np.maximum(gaps, 1e-6)[:, None] / (gaps[:, None] + 0.01)).sum(axis=0)  # the nearest count most
    if not np.all(np.isfinite(away)) or np.linalg.norm(away) < 1e-6:
        return None
    away /= np.linalg.norm(away)
    contact = centre - away * CONTACT_OFFSET * radius
    start_z = max(surface.top - PUSH_PRESS, surface.support + 0.005)  # (a ball's top is within 2 mm of it there)
    start = np.array([contact[0], contact[1], start_z])
    end = start + np.array([away[0], away[1], 0.0]) * distance
    return Push(start, end, float(np.arctan2(away[1], away[0])))

"""The tools a picking cell carries: parallel jaws, a suction cup, or both on one hand. Their geometry
and limits live here once, for the simulator that builds and drives them and for the planner that
judges grasps from depth (which must not import the simulator).

Both tools approach from above. A grasp's ``position`` is the tool's point: the fingertips' midpoint
for the jaws, the centre of the cup's lip for suction. On the hand that carries both (a cup on a rod
between the fingers, as hybrid warehouse grippers have), the rod pushes the cup ``cup_reach`` below the
fingertips for a suction pick, so the open fingers stay clear of the face the cup seals on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

GRIPPERS = ("jaws", "suction", "both")  # what a cell carries
TOOLS = ("jaws", "suction")  # what one grasp uses
RING = 16  # points round the cup's lip where its seal is judged
INNER = 7  # points inside it (the centre and a ring at half the radius)
TIPS_BELOW = 0.04  # the tool point below the hand's origin (the fingers' centre; the cup's lip on a suction-only hand)


@dataclass(frozen=True)
class Jaws:
    """The parallel-jaw gripper's geometry, metres (binpick's simulated one by default)."""

    opening: float = 0.11  # distance between the open fingers' inner faces
    finger_thickness: float = 0.012  # along the closing direction
    finger_width: float = 0.028  # across it
    finger_length: float = 0.08
    margin: float = 0.008  # the widest object it takes is opening - margin


@dataclass(frozen=True)
class SuctionCup:
    """A bellows suction cup and its vacuum (binpick's simulated one by default; a 30 mm cup).

    It seals where its lip's ring lies on one object's surface that is flat enough: the ring's heights
    within ``compliance`` of a plane (peak to peak), the surface inside it bulging into the cup by no
    more than ``depth``, tilted at most ``max_tilt`` degrees from the cup's axis. The seal holds while
    the load on it stays inside the wrench the vacuum resists (Dex-Net 3.0's soft ring contact): a
    pull ``f_n`` up to ``vacuum_force``, a shear up to ``friction`` times the force still pressing the
    lip (``vacuum_force - f_n``), and a moment about the lip up to that force times the radius (the
    cup peels beyond it). A heavy object held far from its centre of mass fails by the moment."""

    radius: float = 0.015  # the lip's radius (m)
    compliance: float = 0.003  # m: how far the lip's ring may leave a plane and still seal
    depth: float = 0.003  # m: how far the surface may bulge into the cup inside the ring
    max_tilt: float = 30.0  # degrees between the sealed surface's normal and the cup's axis
    vacuum_force: float = 30.0  # N: the pull the seal holds (about 60 kPa over the lip, less leakage)
    friction: float = 0.8  # the lip's rubber on the product
    cup_reach: float = 0.04  # m: the cup below the fingertips on a hand that carries both tools
    press: float = 0.006  # m: a pick drives the lip this far past the surface it aims at (the bellows give)

    @property
    def area(self) -> float:
        return math.pi * self.radius ** 2


def tools_of(gripper: str) -> tuple[str, ...]:
    """The tools a cell's ``gripper`` (jaws, suction or both) gives: ("jaws",), ("suction",) or both."""
    from binpick.core.config import check_choice

    check_choice("gripper", gripper, GRIPPERS)
    return TOOLS if gripper == "both" else (gripper,)


def tool_point_below(gripper: str, tool: str) -> float:
    """How far below the hand's origin ``tool``'s point is on a ``gripper`` hand: the fingertips and a
    suction-only hand's lip 4 cm; the cup pushed out below the fingertips on a hand with both."""
    if tool == "suction" and gripper == "both":
        return TIPS_BELOW + SuctionCup().cup_reach
    return TIPS_BELOW


def ring_offsets(radius: float) -> np.ndarray:
    """The lip's ring and the points inside it, in the cup's plane: (RING + INNER, 2)."""
    angles = np.linspace(0, 2 * np.pi, RING, endpoint=False)
    inner = np.linspace(0, 2 * np.pi, INNER - 1, endpoint=False)
    return np.concatenate([radius * np.stack([np.cos(angles), np.sin(angles)], 1), [[0.0, 0.0]],
                           radius / 2 * np.stack([np.cos(inner), np.sin(inner)], 1)])


@dataclass(frozen=True)
class Seal:
    """What a cup's lip would meet at one place (:func:`seal_geometry`): the share of the ring and the
    points inside it that lie on the product under the centre, how far the ring's heights leave their
    best plane (peak to peak, m), that plane's tilt from the cup's axis (degrees), how far the surface
    inside bulges above it towards the cup (m), and the gap from the lip to the plane (m; > 0: the
    surface lies below the lip)."""

    coverage: float
    planarity: float
    tilt: float
    bulge: float
    gap: float


def seal_geometry(heights: np.ndarray, same: np.ndarray, radius: float) -> Seal:
    """The :class:`Seal` of a surface seen at :func:`ring_offsets` (``heights`` along the cup's axis
    relative to the lip, NaN where nothing was seen; ``same``: the point lies on the product under the
    cup's centre). Points not seen or on another product leave the fit (and lower ``coverage``)."""
    return seal_geometries(np.asarray(heights, dtype=float)[None], np.asarray(same, bool)[None], radius)[0]


def seal_geometries(heights: np.ndarray, same: np.ndarray, radius: float) -> list[Seal]:
    """:func:`seal_geometry` of N places at once (``heights``, ``same``: (N, RING + INNER)): one
    weighted least-squares plane per place, solved together (a planner judges dozens per detection)."""
    heights, same = np.asarray(heights, dtype=float), np.asarray(same, bool)
    good = np.isfinite(heights) & same
    coverage = good.mean(axis=1)
    ring = good[:, :RING]
    offsets = ring_offsets(radius)
    design = np.column_stack([offsets, np.ones(len(offsets))])
    lip = design[:RING]
    weights = ring.astype(float)
    values = np.where(ring, heights[:, :RING], 0.0)
    normal = np.einsum("ri,nr,rj->nij", lip, weights, lip)  # the plane's normal equations, per place
    right = np.einsum("ri,nr->ni", lip, weights * values)
    fitted = ring.sum(axis=1) >= 4
    coefficients = np.zeros((len(heights), 3))
    if fitted.any():
        coefficients[fitted] = np.linalg.solve(normal[fitted], right[fitted][..., None])[..., 0]
    plane = coefficients @ design.T
    residual = heights[:, :RING] - plane[:, :RING]
    spread = np.where(ring, residual, -np.inf).max(axis=1) - np.where(ring, residual, np.inf).min(axis=1)
    inside = good[:, RING:]
    bulge = np.where(inside.any(axis=1), np.where(inside, heights[:, RING:] - plane[:, RING:], -np.inf).max(axis=1), 0.0)
    tilt = np.degrees(np.arctan(np.hypot(coefficients[:, 0], coefficients[:, 1])))
    return [Seal(float(coverage[i]), float(spread[i]), float(tilt[i]), float(bulge[i]), float(-coefficients[i, 2])) if fitted[i]
            else Seal(float(coverage[i]), float("inf"), 90.0, float("inf"), float("inf")) for i in range(len(heights))]


def seal_test(heights: np.ndarray, same: np.ndarray, cup: SuctionCup, touch: float = 0.002) -> str | None:
    """Whether a lip seals on a surface seen at :func:`ring_offsets` (see :func:`seal_geometry`): None
    when it does, else why not. The lip must also touch the surface's plane: its nearest point within
    ``touch`` (a cup pressed onto a tilted face meets it first with the uphill side of its lip, the
    centre ``radius * tan(tilt)`` above the plane; the bellows then tilt the lip onto the face, which is
    what ``max_tilt`` allows). The simulator's vacuum seals by this test."""
    seal = seal_geometry(heights, same, cup.radius)
    if seal.coverage < 1.0:
        return "the ring leaves the product"
    if seal.planarity > cup.compliance:
        return "the ring is not flat"
    if seal.tilt > cup.max_tilt:
        return "the surface is tilted too far"
    if seal.bulge > cup.depth:
        return "the surface bulges into the cup"
    if seal.gap - cup.radius * math.tan(math.radians(seal.tilt)) > touch:
        return "the lip does not touch"
    return None

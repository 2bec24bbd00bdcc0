"""Suction grasps from depth (no simulator), Dex-Net 3.0's seal-and-wrench idea on a depth frame.

Candidates are points on the instance's own pixels (its depth mask inside the detection box), spaced
a centimetre apart. At each, the cup's lip ring and the points inside it are laid on the surface the
depth shows (holes filled): the share of them on the instance (coverage), how far the ring's heights
leave a plane (the lip's compliance takes a few millimetres), that plane's tilt, how far the surface
bulges into the cup (:func:`binpick.grippers.seal_geometries`); then the moment of the product's
weight about the contact against what the seal resists: the weight from the visible size (a
packaged goods density), the lever from the contact to the instance's visible centre. On a hand that
carries both tools the open fingers sit ``cup_reach`` above the lip: a yaw is chosen that keeps them
clear of taller neighbours.

:func:`analytic_probability` turns these into a success probability (a prior, no data);
:class:`binpick.grasping.suction_quality.SuctionQuality` learns it from simulated trials.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from binpick.grasping.candidates import BLOCK_TOLERANCE, GraspCandidate, finger_heights
from binpick.grasping.instance import Surface, points_on_instance, surface_heights
from binpick.grasping.frame import DepthFrame
from binpick.grippers import Jaws, SuctionCup, ring_offsets, seal_geometries

SPACING = 0.01  # m between candidates on the instance
MAX_CANDIDATES = 48
DENSITY = 350.0  # kg/m^3: packaged goods, for the weight's moment (a box of cereal ~250, a full carton ~900)
FILL = 0.6  # share of the visible extent x height a product fills
GRAVITY = 9.81
MIN_COVERAGE = 0.75  # less of the ring on the instance: not tried
FINGER_YAWS = 4  # yaws tried for the open fingers on a hand with both tools
PALM_ABOVE_LIP = 0.07  # a suction-only hand's palm above its lip (m)


@dataclass(frozen=True)
class SuctionFeatures:
    """What the depth says about one suction grasp (see the module)."""

    coverage: float  # share of the lip's ring and the points inside it on the instance
    read: float  # share of them the sensor read (the rest inpainted)
    planarity: float  # m: the ring's heights from their plane, peak to peak
    tilt: float  # degrees
    bulge: float  # m
    lever: float  # m: the contact from the instance's visible centre
    mass: float  # kg: estimated from the visible size
    moment: float  # the weight's moment about the lip over what the seal resists (1: at the limit)
    clearance: float  # m: the open fingers (or the palm) above the highest surface under them

    def vector(self, cup: SuctionCup = SuctionCup()) -> np.ndarray:
        """The features a learnt model reads, scaled to about unit range."""
        values = np.array([self.coverage, self.read, min(self.planarity / cup.compliance, 5.0), self.tilt / cup.max_tilt,
                           np.clip(self.bulge / cup.depth, -3, 3), self.lever / 0.05, np.log(max(self.mass, 1e-3)),
                           np.clip(self.moment, 0, 5), np.clip(self.clearance, -0.05, 0.05) / 0.05], dtype=np.float64)
        return np.nan_to_num(values, nan=-1.0, posinf=5.0, neginf=-5.0).astype(np.float32)  # unknown: an edge case


FEATURES = 9


def estimated_mass(surface: Surface) -> float:
    """The product's weight from what depth shows of it: visible extent x height x a packaged goods
    density (a guess that ranks a long heavy box's far end below its middle; it knows no materials)."""
    major, minor = surface.extents()
    return float(np.clip(DENSITY * FILL * max(major, 0.01) * max(minor, 0.01) * max(surface.height, 0.01), 0.02, 5.0))


def moment_ratio(mass: float, lever: float, cup: SuctionCup) -> float:
    """The weight's moment about the lip over the moment the seal resists while holding that weight."""
    weight = mass * GRAVITY
    pressing = cup.vacuum_force - weight
    if pressing <= 0:
        return float("inf")
    return float(weight * lever / (pressing * cup.radius))


def suction_candidates(frame: DepthFrame, surface: Surface, cup: SuctionCup = SuctionCup(), gripper: str = "suction",
                       jaws: Jaws = Jaws()) -> list[GraspCandidate]:
    """Suction grasps on the instance whose depth ``surface`` this is (:func:`instance_surface`), each
    with its :class:`SuctionFeatures` (``seal``) and the reason it is not tried (None: feasible)."""
    return describe_suction(frame, surface, points_on_instance(surface, SPACING, MAX_CANDIDATES), cup, gripper, jaws)


def describe_suction(frame: DepthFrame, surface: Surface, centres: np.ndarray, cup: SuctionCup = SuctionCup(),
                     gripper: str = "suction", jaws: Jaws = Jaws()) -> list[GraspCandidate]:
    """Suction grasps with the cup's centre at world ``centres`` (N, 2) on the instance of ``surface``:
    the lip's height (the ring's plane at the centre), the seal's geometry, the weight's moment, the
    hand's clearance; a centre where depth shows nothing is left out."""
    centres = np.asarray(centres, dtype=float).reshape(-1, 2)
    offsets = ring_offsets(cup.radius)
    n, k = len(centres), len(offsets)
    xy = (centres[:, None, :] + offsets[None]).reshape(-1, 2)
    pixels: list = []
    heights, read = surface_heights(frame, xy, surface.top, pixels)
    heights, read = heights.reshape(n, k), read.reshape(n, k)
    same = surface.on_instance(pixels[0]).reshape(n, k)
    mass = estimated_mass(surface)
    seen = np.isfinite(heights).any(axis=1)  # a centre where depth shows nothing is left out
    centres, heights, read, same = centres[seen], heights[seen], read[seen], same[seen]
    on_product = np.where(same & np.isfinite(heights), heights, np.nan)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a row without a reading on the product: the ring's median
        levels = np.where(np.isfinite(on_product).any(axis=1), np.nanmedian(on_product, axis=1), np.nanmedian(heights, axis=1))
    seals = seal_geometries(heights - levels[:, None], same, cup.radius)
    candidates = []
    for i, seal in enumerate(seals):
        lip = float(levels[i]) - (seal.gap if np.isfinite(seal.gap) else 0.0)
        lever = float(np.linalg.norm(centres[i] - surface.centre))
        candidates.append((centres[i], lip, seal, float(read[i].mean()), lever))
    if not candidates:
        return []
    lips = np.array([c[1] for c in candidates])
    yaws_, clearances = hand_clearance(frame, np.array([c[0] for c in candidates]), lips, gripper, cup, jaws)
    result = []
    for (centre, lip, seal, read_share, lever), yaw, clearance in zip(candidates, yaws_, clearances):
        features = SuctionFeatures(seal.coverage, read_share, seal.planarity, seal.tilt, seal.bulge, lever, mass,
                                   moment_ratio(mass, lever, cup), float(clearance))
        candidate = GraspCandidate(np.array([centre[0], centre[1], lip]), float(yaw), 0.0, float(clearance), surface.top,
                                   surface.support, kind="suction", tool="suction", seal=features)
        if seal.coverage < MIN_COVERAGE:
            candidate.rejected = f"the cup's ring leaves the instance ({100 * seal.coverage:.0f}% on it)"
        elif not np.isfinite(clearance):
            candidate.rejected = "the hand outside the camera's view"
        elif clearance < -BLOCK_TOLERANCE:
            candidate.rejected = f"hand blocked ({-clearance * 100:.1f} cm into a taller neighbour)"
        result.append(candidate)
    return result


def hand_clearance(frame: DepthFrame, centres: np.ndarray, lips: np.ndarray, gripper: str, cup: SuctionCup,
                   jaws: Jaws) -> tuple[np.ndarray, np.ndarray]:
    """Per suction grasp, the hand's yaw and how far above the highest surface under it the hand's
    lowest part stays: the open fingers (``cup_reach`` above the lip) on a hand with both tools, at
    the yaw that clears most; the palm on a suction-only hand."""
    lips = lips - cup.press  # the hand goes the press lower than the lip's plan
    if gripper == "both":
        best_yaw, best = np.zeros(len(centres)), np.full(len(centres), -np.inf)
        tips = lips + cup.cup_reach
        for yaw in np.pi * np.arange(FINGER_YAWS) / FINGER_YAWS:
            under, seen = finger_heights(frame, centres, np.full(len(centres), yaw), jaws, float(np.max(lips)))
            clearance = np.where(seen, tips - under.max(axis=1), np.nan)
            better = np.nan_to_num(clearance, nan=-np.inf) > best
            best_yaw, best = np.where(better, yaw, best_yaw), np.where(better, clearance, best)
        return best_yaw, np.where(np.isfinite(best), best, np.nan)
    disc = ring_offsets(cup.radius + 0.01)
    xy = (centres[:, None, :] + disc[None]).reshape(-1, 2)
    heights, _ = surface_heights(frame, xy, float(np.max(lips)))
    highest = np.nanmax(heights.reshape(len(centres), -1), axis=1) if np.isfinite(heights).any() else np.full(len(centres), np.nan)
    return np.zeros(len(centres)), lips + PALM_ABOVE_LIP - highest


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-np.clip(x, -30, 30)))


def analytic_probability(features: SuctionFeatures, cup: SuctionCup = SuctionCup()) -> float:
    """A success probability from the seal's geometry and the weight's moment, without data: each
    limit of :class:`binpick.grippers.SuctionCup` as a soft step whose width is what a depth sensor's
    noise blurs (about a millimetre, a few degrees). Among grasps it all but certainly likes, the one
    nearer the instance's middle wins (a little less moment, and the same choice on nearly the same depth)."""
    p = (_sigmoid((features.coverage - 0.92) / 0.02) * _sigmoid((cup.compliance - features.planarity) / 0.0006)
         * _sigmoid((cup.max_tilt - features.tilt) / 3.0) * _sigmoid((cup.depth - features.bulge) / 0.0006)
         * _sigmoid((1.0 - features.moment) / 0.12) * _sigmoid((features.clearance + 0.005) / 0.004))
    return float(p * (1.0 - 0.02 * min(features.lever / 0.05, 1.0)))


__all__ = ["SuctionFeatures", "analytic_probability", "suction_candidates"]

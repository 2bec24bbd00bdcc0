"""Choosing a grasp for a detection (no simulator): candidates from depth
(:mod:`binpick.grasping.candidates`), ranked by one of three policies:

- ``fixed``: today's grasp before this module, the jaws along the robot's y-axis whatever the
  instance looks like (the policy the data set's ``pickable:y`` labels are for);
- ``analytic``: across the instance's principal minor axis where it is elongated, among candidates
  whose width fits the jaws and whose fingers have room to descend (largest clearance first);
- ``learnt``: a grasp-quality network (GQ-CNN style, :mod:`binpick.grasping.quality`) trained on
  simulated trials scores every feasible candidate.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from enum import StrEnum

import numpy as np

from binpick.errors import ConfigError
from binpick.grasping.camera import PinholeCamera
from binpick.grasping.candidates import GraspCandidate, JawGripper, Surface, grasp_candidates


class GraspPolicyName(StrEnum):
    FIXED = "fixed"
    ANALYTIC = "analytic"
    LEARNT = "learnt"


@dataclass
class GraspChoice:
    """The grasp chosen for one detection (None: nothing feasible), and every candidate considered."""

    chosen: GraspCandidate | None
    candidates: list[GraspCandidate] = field(default_factory=list)
    reason: str | None = None  # why nothing was chosen
    surface: Surface | None = None  # what depth shows of the instance (None: nothing)

    def rejections(self) -> dict[str, int]:
        """How many candidates were rejected for each reason (the reason's words before any number);
        with no candidate at all, the reason there was none."""
        if not self.candidates and self.reason:
            return {self.reason: 1}
        counts: dict[str, int] = {}
        for candidate in self.candidates:
            if candidate.rejected:
                key = candidate.rejected.split(" (")[0]
                counts[key] = counts.get(key, 0) + 1
        return counts


def analytic_score(candidate: GraspCandidate, surface: Surface) -> float:
    """Alignment with the minor axis (weighted by how elongated the surface is) plus clearance."""
    alignment = abs(np.cos(candidate.yaw - surface.minor_yaw)) * min(1.0, surface.elongation - 1.0)
    return float(alignment + 10.0 * np.clip(candidate.clearance, -0.01, 0.03))


class GraspPlanner:
    """``GraspPlanner(policy).choose(points, camera, box)``: the grasp for one detection.

    ``points`` are the frame's world xyz per pixel (:meth:`PinholeCamera.points`), computed once per
    frame and shared by every detection."""

    def __init__(self, policy: str = "analytic", quality=None, gripper: JawGripper = JawGripper(), yaw_count: int = 8) -> None:
        try:
            self.policy = GraspPolicyName(policy)
        except ValueError:
            raise ConfigError(f"unknown grasp policy {policy!r}; choose from {', '.join(p.value for p in GraspPolicyName)}") from None
        if self.policy is GraspPolicyName.LEARNT and quality is None:
            raise ConfigError("the learnt grasp policy needs a grasp-quality model (binpick.grasping.quality.GraspQuality.load)")
        self.quality, self.gripper, self.yaw_count = quality, gripper, yaw_count

    @classmethod
    def load(cls, policy: str = "learnt", weights: str | Path | None = None, **options) -> GraspPlanner:
        """A planner for ``policy``; the learnt one with ``weights`` (default: the shipped model)."""
        quality = None
        if policy == GraspPolicyName.LEARNT:
            from binpick.grasping.quality import SHIPPED, GraspQuality

            if weights is None and not SHIPPED.is_file():
                raise ConfigError(f"no grasp-quality weights shipped at {SHIPPED}: train them (python benchmarks/grasp.py train) "
                                  "or choose the analytic policy")
            quality = GraspQuality.load(weights or SHIPPED)
        elif weights is not None:
            raise ConfigError(f"grasp weights are for the learnt policy, not {policy!r}")
        return cls(policy, quality, **options)

    def choose(self, points: np.ndarray, camera: PinholeCamera, box) -> GraspChoice:
        surface, candidates = grasp_candidates(points, camera, box, self.gripper, self.yaw_count)
        if surface is None:
            return GraspChoice(None, [], "depth shows nothing standing out in the box")
        if self.policy is GraspPolicyName.FIXED:
            fixed = min(candidates[1:], key=lambda c: abs(c.yaw - np.pi / 2))  # [0] is the minor axis
            fixed.quality = None
            return GraspChoice(fixed, candidates, surface=surface)  # today's grasp: tried whatever the checks say
        feasible = [c for c in candidates if c.rejected is None]
        if not feasible:
            choice = GraspChoice(None, candidates, surface=surface)
            choice.reason = "no candidate fits: " + ", ".join(f"{n} {k}" for k, n in choice.rejections().items())
            return choice
        if self.policy is GraspPolicyName.ANALYTIC:
            for candidate in feasible:
                candidate.quality = analytic_score(candidate, surface)
        else:
            scores = self.quality.score(points, camera, feasible)
            for candidate, score in zip(feasible, scores):
                candidate.quality = float(score)
        best = max(feasible, key=lambda c: c.quality)
        return GraspChoice(best, candidates, surface=surface)

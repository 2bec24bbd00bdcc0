"""Choosing a grasp for a detection (no simulator): candidates from depth
(:mod:`binpick.grasping.candidates`), ranked by one of three policies:

- ``fixed``: today's grasp before this module, the jaws along the robot's y-axis whatever the
  instance looks like (the policy the data set's ``pickable:y`` labels are for);
- ``analytic``: across the instance's principal minor axis where it is elongated, among candidates
  whose width fits the jaws and whose fingers have room to descend (largest clearance first);
- ``learnt``: a grasp-quality network (GQ-CNN style, :mod:`binpick.grasping.quality`) trained on
  simulated trials scores every feasible candidate.

A cell whose hand carries a suction cup (``hand``: suction, or both) also gets suction candidates
(:mod:`binpick.grasping.suction`), scored by the learnt suction-quality model where one is given and
by the seal-and-wrench prior otherwise; with both tools the candidate with the highest predicted
success wins, whichever tool it is for (Dex-Net 4.0's ambidextrous policy). A grasp for a tool the
hand does not carry is never made.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from enum import StrEnum

import numpy as np

from binpick.core.config import did_you_mean
from binpick.core.errors import ConfigError
from binpick.grasping.candidates import GraspCandidate, JawGripper, YAWS, grasp_candidates
from binpick.grasping.instance import Surface, instance_surface
from binpick.grasping.frame import DepthFrame
from binpick.grippers import SuctionCup, tools_of


NOTHING_THERE = "depth shows nothing standing out in the box"
JAWS_PRIOR = 0.59  # feasible jaw grasps that held in the simulated trials the quality model learnt from
FAILED_RADIUS, FAILED_FACTOR = 0.03, 0.35  # m, and the share of its quality a candidate keeps near a failed grasp of its tool


class GraspPolicyName(StrEnum):
    FIXED = "fixed"
    ANALYTIC = "analytic"
    LEARNT = "learnt"

    @classmethod
    def _missing_(cls, value: object) -> GraspPolicyName | None:
        """Case ignored, and American spelling taken: ``Learned`` is ``learnt``."""
        text = str(value).strip().lower()
        return cls.LEARNT if text == "learned" else next((p for p in cls if p.value == text), None)


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
    """Alignment with the minor axis (weighted by how elongated the surface is) plus clearance, less
    for tips lifted above the depth the grip wants and for jaws off the instance's middle."""
    alignment = abs(np.cos(candidate.yaw - surface.minor_yaw)) * min(1.0, surface.elongation - 1.0)
    shallow = max(0.0, float(candidate.position[2]) - surface.tips_range()[1])
    return float(alignment + 10.0 * np.clip(candidate.clearance, -0.01, 0.03) - 5.0 * shallow - 0.05 * (candidate.kind == "shifted"))


class GraspPlanner:
    """``GraspPlanner(policy).choose(frame, box)``: the grasp for one detection.

    ``frame`` is the depth frame made ready once (:meth:`DepthFrame.from_depth`: holes filled, the
    support plane found) and shared by every detection."""

    def __init__(self, policy: str = "analytic", quality=None, gripper: JawGripper = JawGripper(), yaw_count: int = YAWS,
                 hand: str = "jaws", suction_quality=None, cup: SuctionCup = SuctionCup()) -> None:
        self.hand, self.tools = hand, tools_of(hand)
        try:
            self.policy = GraspPolicyName(policy)
        except ValueError:
            names = [p.value for p in GraspPolicyName]
            raise ConfigError(f"unknown grasp policy {policy!r}{did_you_mean(policy, names)}; choose from {', '.join(names)}") from None
        if self.policy is GraspPolicyName.LEARNT and quality is None:
            raise ConfigError("the learnt grasp policy needs a grasp-quality model (binpick.grasping.quality.GraspQuality.load)")
        if self.policy is GraspPolicyName.FIXED and "jaws" not in self.tools:
            raise ConfigError("the fixed grasp policy is the jaws along y: give it a hand with jaws (--gripper jaws or both)")
        self.quality, self.gripper, self.yaw_count = quality, gripper, yaw_count
        self.suction_quality, self.cup = suction_quality, cup

    @classmethod
    def load(cls, policy: str = "learnt", weights: str | Path | None = None, hand: str = "jaws", **options) -> GraspPlanner:
        """A planner for ``policy`` and a ``hand`` carrying jaws, suction or both; the learnt one with
        ``weights`` (default: the shipped model), and the shipped suction-quality model where there is one."""
        quality = None
        try:
            policy = GraspPolicyName(policy)
        except ValueError:
            names = [p.value for p in GraspPolicyName]
            raise ConfigError(f"unknown grasp policy {policy!r}{did_you_mean(policy, names)}; choose from {', '.join(names)}") from None
        if policy == GraspPolicyName.LEARNT:
            from binpick.grasping.quality import SHIPPED, GraspQuality

            if weights is None and not SHIPPED.is_file():
                raise ConfigError(f"no grasp-quality weights shipped at {SHIPPED}: train them (python experiments/grasp.py train) "
                                  "or choose the analytic policy")
            quality = GraspQuality.load(weights or SHIPPED)
        elif weights is not None:
            raise ConfigError(f"grasp weights are for the learnt policy, not {policy.value!r}")
        if "suction" in tools_of(hand) and policy == GraspPolicyName.LEARNT and "suction_quality" not in options:
            from binpick.grasping.suction_quality import SHIPPED as SUCTION_SHIPPED, SuctionQuality

            options["suction_quality"] = SuctionQuality.load(SUCTION_SHIPPED) if SUCTION_SHIPPED.is_file() else None
        return cls(policy, quality, hand=hand, **options)

    def frame(self, depth: np.ndarray, camera) -> DepthFrame:
        """A depth image (metres, 0: no reading) made ready for :meth:`choose`."""
        return DepthFrame.from_depth(depth, camera)

    def choose(self, frame: DepthFrame, box, failed=()) -> GraspChoice:
        """The best feasible candidate for the instance in ``box``. ``failed``: (base-frame position, tool)
        of grasps that failed on this bin since: a candidate of that tool within FAILED_RADIUS of one counts
        FAILED_FACTOR of its quality (what failed there once is likely to fail again: try the other tool,
        or another place)."""
        surface = instance_surface(frame, box)
        if surface is None:
            return GraspChoice(None, [], NOTHING_THERE)
        candidates: list[GraspCandidate] = []
        if "jaws" in self.tools:
            candidates += grasp_candidates(frame, box, self.gripper, self.yaw_count, surface=surface)[1]
        if self.policy is GraspPolicyName.FIXED:  # [0] is the minor axis; the jaws along y, centred
            fixed = min((c for c in candidates[1:] if c.kind == "even"), key=lambda c: abs(c.yaw - np.pi / 2))
            fixed.quality = None
            return GraspChoice(fixed, candidates, surface=surface)  # today's grasp: tried whatever the checks say
        if "suction" in self.tools:
            from binpick.grasping.suction import suction_candidates

            candidates += suction_candidates(frame, surface, self.cup, self.hand, self.gripper)
        feasible = [c for c in candidates if c.rejected is None]
        if not feasible:
            choice = GraspChoice(None, candidates, surface=surface)
            choice.reason = "no candidate fits: " + ", ".join(f"{n} {k}" for k, n in choice.rejections().items())
            return choice
        self.score(frame, surface, feasible)
        for position, tool in failed:
            for candidate in feasible:
                if candidate.tool == tool and np.linalg.norm(candidate.position[:2] - np.asarray(position)[:2]) < FAILED_RADIUS:
                    candidate.quality *= FAILED_FACTOR
        best = max(feasible, key=lambda c: c.quality)
        return GraspChoice(best, candidates, surface=surface)

    def score(self, frame: DepthFrame, surface: Surface, candidates: list[GraspCandidate]) -> None:
        """Each candidate's quality: for the jaws the policy's (the learnt one a success probability), for
        suction the learnt suction model's probability or the seal-and-wrench prior's. With both tools
        and the analytic jaws policy, whose score is no probability, a feasible jaw grasp counts as
        JAWS_PRIOR (the share of feasible jaw grasps that held in simulated trials)."""
        jaws = [c for c in candidates if c.tool == "jaws"]
        cups = [c for c in candidates if c.tool == "suction"]
        if jaws and self.policy is GraspPolicyName.ANALYTIC:
            for candidate in jaws:
                candidate.quality = analytic_score(candidate, surface)
                if cups:  # ranked against suction: a probability, the analytic order kept within the jaws
                    candidate.quality = JAWS_PRIOR + 0.01 * np.tanh(candidate.quality)
        elif jaws:
            for candidate, score in zip(jaws, self.quality.score(frame, jaws)):
                candidate.quality = float(score)
        if cups:
            if self.suction_quality is not None:
                scores = self.suction_quality.score(frame, cups)
            else:
                from binpick.grasping.suction import analytic_probability

                scores = [analytic_probability(c.seal, self.cup) for c in cups]
            for candidate, score in zip(cups, scores):
                candidate.quality = float(score)

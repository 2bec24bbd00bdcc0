"""What an order did (each grasp attempt, the outcome and why) and the figures over many orders: pick
success, the right-product rate, per tool, and an arm's cycle times and picks per hour."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from binpick.core.errors import ConfigError
from binpick.core.files import atomic_write_text, ensure_dir
from binpick.warehouse.grasping import Reason


@dataclass
class Attempt:
    box: list[float]
    score: float
    same_product: float | None  # the product check's score (None: not checked)
    grasp_point: list[float]  # the tool's point, world xyz: the fingertips' midpoint, or the cup's lip
    outcome: Reason
    lifted_product: str | None
    yaw: float = 0.0  # the jaws' closing direction, radians about z
    width: float | None = None  # the instance's width across the jaws (m)
    quality: float | None = None  # the grasp policy's score of the chosen candidate
    rejected: dict[str, int] = field(default_factory=dict)  # other candidates: reason -> count
    motion_s: dict[str, float] = field(default_factory=dict)  # the arm's segments, simulated robot seconds (empty: floating gripper)
    planning_ms: float | None = None  # the arm's motion planning (IK and timing)
    collisions: list[list[str]] = field(default_factory=list)  # the arm touching the table or a tote: [arm part, fixed part, segment]
    grasp_error_mm: float | None = None  # the arm's gripper from the planned grasp when the fingers closed
    tool: str | None = None  # the tool the grasp used: jaws or suction (None: no grasp)
    why: str | None = None  # a failed suction grasp in the vacuum's words: why it did not seal, or that it let go


@dataclass
class OrderResult:
    order: int
    product: str
    seed: int
    success: bool  # the ordered product ended in the order tote
    reason: Reason
    seen: bool | None = None  # the detector's training set had this product (None: unknown)
    attempts: list[Attempt] = field(default_factory=list)
    detections: int = 0
    seconds: float = 0.0
    gif: str | None = None
    overlay: str | None = None
    depth: str | None = None  # the depth picture beside the overlay
    timing_ms: dict[str, float] = field(default_factory=dict)  # the planner's stages (depth, detect, check, grasp) and the simulator's
    robot: str = "floating"  # what executed the picks: the floating gripper or an arm
    gripper: str = "jaws"  # the hand's tools: jaws, suction or both
    found_again: list = field(default_factory=list)  # a pointed pick's instance after each failed grasp: its box in the new frame (None: not found)
    looked_again: int = 0  # new frames taken after failed grasps (each planned anew)
    pushes: list = field(default_factory=list)  # pushes that freed the pointed instance before a grasp: {start, end, yaw, moved (m)}

    @property
    def robot_seconds(self) -> float:
        """The arm's motion time over the order's grasps (simulated robot seconds; 0 for the floating gripper)."""
        return round(sum(sum(a.motion_s.values()) for a in self.attempts), 3)

    @property
    def grasps(self) -> int:
        """Grasps executed (detections without a feasible grasp were skipped at no cost)."""
        return sum(a.outcome is not Reason.NO_GRASP for a in self.attempts)


def summarise(results: list[OrderResult], wall_seconds: float) -> dict[str, Any]:
    """Pick success rate; right-product rate: of all grasps that lifted something, the share that
    lifted the ordered product (a wrong one would go to the customer); picks per minute."""
    lifted = [a.lifted_product == r.product for r in results for a in r.attempts if a.lifted_product is not None]
    reasons: dict[str, int] = {}
    placed: dict[str, list[int]] = {}
    for r in results:
        reasons[r.reason] = reasons.get(r.reason, 0) + 1
        placed.setdefault(r.product, [0, 0])
        placed[r.product][0] += int(r.success)
        placed[r.product][1] += 1
    by_product = {product: f"{done}/{total}" for product, (done, total) in sorted(placed.items())}
    summary = {"orders": len(results), "pick_success": round(sum(r.success for r in results) / max(1, len(results)), 4),
            "right_product": round(sum(lifted) / len(lifted), 4) if lifted else None, "lifts": len(lifted),
            "picks_per_min": round(60 * sum(r.success for r in results) / max(wall_seconds, 1e-9), 2),
            "orders_per_min": round(60 * len(results) / max(wall_seconds, 1e-9), 2),
            "attempts_per_order": round(float(np.mean([r.grasps for r in results])), 2) if results else 0.0,
            "reasons": reasons, "by_product": by_product, "wall_s": round(wall_seconds, 1),
            "by_tool": tool_summary(results)}
    arm = arm_summary(results)
    return summary | ({"arm": arm} if arm else {})


def tool_summary(results: list[OrderResult]) -> dict[str, dict[str, Any]]:
    """Per tool: grasps executed with it, how many placed the ordered product, and its success rate
    (a grasp that placed another product counts as a failure)."""
    tools: dict[str, list[int]] = {}
    for r in results:
        for a in r.attempts:
            if a.outcome is Reason.NO_GRASP or a.tool is None:
                continue
            counts = tools.setdefault(a.tool, [0, 0])
            counts[0] += 1
            counts[1] += int(a.outcome is Reason.PLACED and a.lifted_product == r.product)
    return {tool: {"grasps": n, "placed": k, "success": round(k / n, 4)} for tool, (n, k) in sorted(tools.items())}


def arm_summary(results: list[OrderResult]) -> dict[str, Any] | None:
    """An arm's figures over the orders (None for the floating gripper): cycle time per placed pick
    (simulated robot seconds, every segment from home back to home; ``_all``: every executed grasp,
    misses, which go home from the lift, included), picks per hour of robot time
    (placed orders over all motion, failed grasps included), the same with the planner's wall time
    added (perception and motion planning on this machine, the arm waiting), contacts with the table
    or totes, and the grasps dropped because the arm could not take them."""
    picks = [a for r in results for a in r.attempts if a.motion_s]
    if not picks:
        return None
    from binpick.arm import REACH_REASONS

    cycles = [sum(a.motion_s.values()) for a in picks]
    placed_cycles = [sum(a.motion_s.values()) for a in picks if a.outcome is Reason.PLACED]
    errors = [a.grasp_error_mm for a in picks if a.grasp_error_mm is not None]
    robot_seconds = float(sum(cycles))
    placed = sum(r.success for r in results)
    thinking = sum(sum(v for k, v in r.timing_ms.items() if k == "total") / 1000 + sum((a.planning_ms or 0) for a in r.attempts) / 1000
                   for r in results)
    segments = sorted({name for a in picks for name in a.motion_s})
    dropped = {reason: sum(a.rejected.get(reason, 0) for r in results for a in r.attempts) for reason in REACH_REASONS}
    per_100 = 100 / max(1, len(results))
    return {"robot": results[0].robot, "picks": len(picks), "cycle_s_median": round(float(np.median(placed_cycles)), 3) if placed_cycles else None,
            "cycle_s_median_all": round(float(np.median(cycles)), 3), "cycle_s_mean_all": round(float(np.mean(cycles)), 3),
            "robot_seconds": round(robot_seconds, 2), "picks_per_hour": round(3600 * placed / robot_seconds, 1),
            "picks_per_hour_with_planning": round(3600 * placed / (robot_seconds + thinking), 1),
            "segment_s_median": {name: round(float(np.median([a.motion_s[name] for a in picks if name in a.motion_s])), 3) for name in segments},
            "planning_ms_median": round(float(np.median([a.planning_ms for a in picks if a.planning_ms is not None])), 1),
            "grasp_error_mm_median": round(float(np.median(errors)), 2) if errors else None,
            "grasp_error_mm_max": round(float(np.max(errors)), 2) if errors else None,
            "collisions": sum(len(a.collisions) for a in picks), "picks_with_collisions": sum(bool(a.collisions) for a in picks),
            "dropped_for_reach": dropped, "dropped_for_reach_per_100_orders": round(sum(dropped.values()) * per_100, 1),
            "ik_failures_per_100_orders": round(dropped["no IK solution"] * per_100, 1)}


def results_json(results: list[OrderResult]) -> list[dict[str, Any]]:
    return [asdict(r) | ({"robot_seconds": r.robot_seconds} if r.robot != "floating" else {}) for r in results]


class RunsOrders(Protocol):
    """What :func:`fulfil` needs: a :class:`binpick.warehouse.pipeline.PickPipeline`."""

    def run_order(self, product_id: str, order: int, seed: int, out: Path | None = None) -> OrderResult: ...


def fulfil(pipeline: RunsOrders, products: list[str], orders: int, seed: int, out: Path,
           on_order: Callable[[OrderResult], None] | None = None, title: str = "binpick orders") -> tuple[dict[str, Any], list[OrderResult]]:
    """Run ``orders`` orders, products taken in turn, order k in a bin seeded ``seed + k``. results.json
    and report.html in ``out`` are rewritten after every order, so a crash loses only the order in
    progress. Returns the summary (with placed/orders per product) and the per-order results."""
    from binpick.warehouse.report import write_report

    if not products:
        raise ConfigError("no product to order: give product ids or categories, e.g. robosuite/milk or can")
    ensure_dir(out, "order results folder")
    results: list[OrderResult] = []
    started = time.perf_counter()

    def write() -> dict[str, Any]:
        summary = summarise(results, time.perf_counter() - started)
        atomic_write_text(out / "results.json", json.dumps({"summary": summary, "orders": results_json(results)}, indent=2))
        write_report(out, summary, results_json(results), title=title)
        return summary

    for order in range(orders):
        results.append(pipeline.run_order(products[order % len(products)], order, seed + order, out=out))
        write()
        if on_order is not None:
            on_order(results[-1])
    return write(), results

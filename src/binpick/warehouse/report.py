"""A small HTML report of fulfilled orders: the summary, then per order its detections (the shop photo
inset) and a GIF of the pick."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import numpy as np

from binpick.core.files import atomic_write_text


def grasp_lines(attempts: list[dict[str, Any]], product: str | None = None) -> list[str]:
    """Per attempt, the grasp chosen (tool, yaw, width, predicted success) and its outcome, or why none
    was feasible; grasps are numbered as in the order's picture. A grasp that moved another product
    than the ordered ``product`` says which."""
    lines, number = [], 0
    for attempt in attempts:
        number += attempt["outcome"] != "no feasible grasp"
        lines.append(grasp_line(number, attempt, product))
    return lines


def grasp_line(number: int, attempt: dict[str, Any], product: str | None = None) -> str:
    rejected = ", ".join(f"{html.escape(str(k))} {v}" for k, v in (attempt.get("rejected") or {}).items())
    detector = "" if attempt.get("score") is None else f"detector score {attempt['score']:.2f}"
    if attempt["outcome"] == "no feasible grasp":
        return f"skipped a detection ({detector}): {rejected or 'no candidate'}"
    quality = "" if attempt.get("quality") is None else f", predicted success {attempt['quality']:.2f}"
    tool = attempt.get("tool") or "jaws"
    if tool == "suction":
        how = "suction cup"
    else:
        width = "" if attempt.get("width") is None else f", {attempt['width'] * 100:.1f} cm across"
        how = f"jaws at yaw {np.degrees(attempt.get('yaw', 0.0)):.0f}°{width}"
    lifted = attempt.get("lifted_product")
    outcome, colour = html.escape(attempt["outcome"]), ""
    if lifted is not None and product is not None and lifted != product:
        outcome, colour = f"{outcome}: {html.escape(lifted)} lifted, not the ordered product", " style='color:#cf222e'"
    elif attempt["outcome"] != "placed":
        colour = " style='color:#cf222e'"
    why = f" ({html.escape(attempt['why'])})" if attempt.get("why") else ""
    return (f"{number}: {detector}; {how}{quality} → <b{colour}>{outcome}</b>{why}"
            + (f" (not taken: {rejected})" if rejected else ""))


def arm_lines(order: dict[str, Any]) -> str:
    """An arm's motion per grasp: seconds per segment (simulated robot time), the cycle, planning time
    and any contact with the table or a tote."""
    lines, number = [], 0
    for attempt in order["attempts"]:
        number += attempt["outcome"] != "no feasible grasp"  # numbered as in the order's picture
        if not attempt.get("motion_s"):
            continue
        segments = " · ".join(f"{html.escape(name)} {seconds:.2f}" for name, seconds in attempt["motion_s"].items())
        touched = ", ".join(f"{html.escape(a)} touched {html.escape(b)} ({html.escape(segment)})"
                            for a, b, segment in attempt.get("collisions") or [])
        lines.append(f"arm, grasp {number}: cycle <b>{sum(attempt['motion_s'].values()):.2f} s</b> of robot time ({segments} s); "
                     f"motion planning {attempt.get('planning_ms') or 0:.0f} ms; gripper {attempt.get('grasp_error_mm') or 0:.1f} mm "
                     "from the planned grasp when it closed" + (f"; <b style='color:#cf222e'>{touched}</b>" if touched else ""))
    return "<br>".join(lines)


COLUMNS = ("order", "product", "trained", "result", "grasps", "detections", "seconds")  # as the terminal's table
STYLE = """body{font-family:sans-serif;margin:1.5em auto;max-width:1800px;padding:0 1em;line-height:1.4}
table.facts{border-collapse:collapse;margin:.4em 0} .facts td,.facts th{padding:3px 10px;border-bottom:1px solid #ddd;text-align:left}
.order{border:1px solid #ccc;border-radius:6px;padding:.6em 1em;margin:1.2em 0}
.pictures{display:grid;grid-template-columns:repeat(auto-fit,minmax(260px,1fr));gap:10px;margin:.6em 0}
.pictures figure{margin:0} .pictures img{width:100%;height:auto;display:block;border:1px solid #ddd}
figcaption{font-size:small;color:#555} .times{font-size:small;color:#444} .grasps{font-size:small}"""


def order_outcome(order: dict[str, Any]) -> str:
    """An order's result as the terminal table and the report show it: "placed", or why not; an order
    that put another product in the tote names it ("wrong product: lego lifted")."""
    if order["success"]:
        return "placed"
    wrong = [a.get("lifted_product") for a in order["attempts"] if a.get("lifted_product") not in (None, order["product"])]
    if order["reason"] == "wrong product" and wrong:
        return f"wrong product: {wrong[-1].split('/')[-1]} lifted"  # the short name: it fits the terminal's column
    return str(order["reason"])


def order_section(order: dict[str, Any]) -> str:
    outcome = html.escape(order_outcome(order))
    colour = "#1a7f37" if order["success"] else "#cf222e"
    seen = {True: "yes", False: "no"}.get(order.get("seen"), "?")
    grasps = sum(a["outcome"] != "no feasible grasp" for a in order["attempts"])
    cells = [str(order["order"]), html.escape(order["product"]), seen, f"<b style='color:{colour}'>{outcome}</b>", str(grasps),
             str(order["detections"]), f"{order['seconds']:.1f}"]
    captions = {"overlay": "colour: detections (orange, detector score) and the grasps tried (jaws as bars, the suction cup as a circle; green placed, red not)",
                "depth": "depth as the planner saw it", "gif": "the picks, captioned per attempt"}
    figures = "".join(f'<figure><a href="{html.escape(order[key])}"><img src="{html.escape(order[key])}" alt="{key}"></a>'
                      f"<figcaption>{captions[key]} (click: full size)</figcaption></figure>"
                      for key in ("overlay", "depth", "gif") if order.get(key))
    times = " · ".join(f"{html.escape(stage)} {ms:,.0f} ms" for stage, ms in (order.get("timing_ms") or {}).items())
    motion = arm_lines(order)
    lines = "<br>".join(grasp_lines(order["attempts"], order.get("product"))) or "no grasp tried"
    return (f"<section class='order' id='order-{order['order']}'><table class='facts'><tr>{''.join(f'<th>{c}</th>' for c in COLUMNS)}</tr>"
            f"<tr>{''.join(f'<td>{c}</td>' for c in cells)}</tr></table>"
            f"<div class='pictures'>{figures}</div>"
            + (f"<p class='times'>time per stage: {times}</p>" if times else "")
            + (f"<p class='times'>{motion}</p>" if motion else "")
            + f"<p class='grasps'>grasps tried (numbered as in the colour picture):<br>{lines}</p></section>")


def arm_summary_line(arm: dict[str, Any] | None) -> str:
    if not arm:
        return ""
    dropped = sum(arm["dropped_for_reach"].values())
    cycle = "—" if arm["cycle_s_median"] is None else f"{arm['cycle_s_median']:.2f} s"
    name = {"panda": "Panda", "ur5e": "UR5e"}.get(str(arm.get("robot")), str(arm.get("robot", "the")))
    return (f"<p>{name} arm: median cycle <b>{cycle}</b> per placed pick (simulated robot time, home to home; "
            f"{arm['cycle_s_median_all']:.2f} s over every grasp) · "
            f"<b>{arm['picks_per_hour']:.0f}</b> picks per hour of robot time ({arm['picks_per_hour_with_planning']:.0f} with this "
            f"machine's perception and planning) · {arm['collisions']} collision(s) · {dropped} grasp(s) dropped for the arm's reach</p>")


def write_report(folder: Path, summary: dict[str, Any], orders: list[dict[str, Any]], title: str = "binpick orders") -> Path:
    right = "n/a" if summary.get("right_product") is None else f"{summary['right_product']:.0%}"
    page = f"""<!doctype html><html><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
<title>{html.escape(title)}</title><style>{STYLE}</style></head><body><h1>{html.escape(title)}</h1>
<p>Pick success <b>{summary['pick_success']:.0%}</b> · right product <b>{right}</b> · {summary['picks_per_min']} picks/min ·
{summary['orders']} orders in {summary['wall_s']} s</p>{arm_summary_line(summary.get("arm"))}
<p>Each order: a new bin; the shop photo (top right of the colour picture) conditions the detector, whose detections are
drawn in orange with the <b>detector score</b>; the grasp policy scores each detection's candidates (the <b>grasp
quality</b>) and the jaws drawn across a product are the grasps tried. Beside it, the depth the grasp planner used, and the
picks as the simulator ran them. Every picture opens full size.</p>
{''.join(order_section(order) for order in orders)}</body></html>"""
    return atomic_write_text(Path(folder) / "report.html", page)

"""A small HTML report of fulfilled orders: the summary, then per order its detections (the shop photo
inset) and a GIF of the pick."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import numpy as np

from binpick.core.files import atomic_write_text


def grasp_lines(attempts: list[dict[str, Any]]) -> list[str]:
    """Per attempt, the grasp chosen (yaw, width, score) and its outcome, or why none was feasible;
    grasps are numbered as in the order's picture."""
    lines, number = [], 0
    for attempt in attempts:
        number += attempt["outcome"] != "no feasible grasp"
        lines.append(grasp_line(number, attempt))
    return lines


def grasp_line(number: int, attempt: dict[str, Any]) -> str:
    rejected = ", ".join(f"{html.escape(str(k))} {v}" for k, v in (attempt.get("rejected") or {}).items())
    if attempt["outcome"] == "no feasible grasp":
        return f"skipped a detection: {rejected or 'no candidate'}"
    quality = "" if attempt.get("quality") is None else f", score {attempt['quality']:.2f}"
    width = "" if attempt.get("width") is None else f", {attempt['width'] * 100:.1f} cm across"
    return (f"{number}: yaw {np.degrees(attempt.get('yaw', 0.0)):.0f}°{width}{quality} → {html.escape(attempt['outcome'])}"
            + (f" (not taken: {rejected})" if rejected else ""))


def write_report(folder: Path, summary: dict[str, Any], orders: list[dict[str, Any]], title: str = "binpick orders") -> Path:
    rows = []
    for order in orders:
        outcome = "placed" if order["success"] else html.escape(order["reason"])
        colour = "#1a7f37" if order["success"] else "#cf222e"
        pictures = "".join(f'<img src="{html.escape(order[key])}" width="240">' for key in ("overlay", "gif") if order.get(key))
        seen = {True: "seen", False: "held out"}.get(order.get("seen"), "?")
        grasps = "<br>".join(grasp_lines(order["attempts"]))
        rows.append(f"<tr><td>{order['order']}</td><td>{html.escape(order['product'])}</td><td>{seen}</td>"
                    f"<td style='color:{colour}'><b>{outcome}</b></td><td>{sum(a['outcome'] != 'no feasible grasp' for a in order['attempts'])}</td>"
                    f"<td>{order['detections']}</td><td>{order['seconds']:.1f}</td><td>{pictures}</td><td style='font-size:small'>{grasps}</td></tr>")
    right = "n/a" if summary.get("right_product") is None else f"{summary['right_product']:.0%}"
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;margin:2em}} td,th{{padding:4px 10px;border-bottom:1px solid #ddd;vertical-align:top}}</style>
</head><body><h1>{html.escape(title)}</h1>
<p>Pick success <b>{summary['pick_success']:.0%}</b> · right product <b>{right}</b> · {summary['picks_per_min']} picks/min ·
{summary['orders']} orders in {summary['wall_s']} s</p>
<p>Each order: a new bin; the shop photo (top right of the left picture) conditions the detector; orange boxes are its
detections with scores; lines across a product are the grasps tried (the open jaws; green: placed, red: not); the GIF
shows the grasp and the carry to the order tote. Each grasp lists the candidates the policy did not take and why.</p>
<table><tr><th>order</th><th>product</th><th>in training</th><th>result</th><th>grasps</th><th>detections</th><th>s</th><th>pictures</th><th>grasps tried (numbered as in the picture)</th></tr>
{''.join(rows)}</table></body></html>"""
    return atomic_write_text(Path(folder) / "report.html", page)

"""A small HTML report of fulfilled orders: the summary, then per order its detections (the shop photo
inset) and a GIF of the pick."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

from binpick.files import atomic_write_text


def write_report(folder: Path, summary: dict[str, Any], orders: list[dict[str, Any]], title: str = "binpick orders") -> Path:
    rows = []
    for order in orders:
        outcome = "placed" if order["success"] else html.escape(order["reason"])
        colour = "#1a7f37" if order["success"] else "#cf222e"
        pictures = "".join(f'<img src="{html.escape(order[key])}" width="240">' for key in ("overlay", "gif") if order.get(key))
        seen = {True: "seen", False: "held out"}.get(order.get("seen"), "?")
        rows.append(f"<tr><td>{order['order']}</td><td>{html.escape(order['product'])}</td><td>{seen}</td>"
                    f"<td style='color:{colour}'><b>{outcome}</b></td><td>{len(order['attempts'])}</td>"
                    f"<td>{order['detections']}</td><td>{order['seconds']:.1f}</td><td>{pictures}</td></tr>")
    right = "n/a" if summary.get("right_product") is None else f"{summary['right_product']:.0%}"
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;margin:2em}} td,th{{padding:4px 10px;border-bottom:1px solid #ddd;vertical-align:top}}</style>
</head><body><h1>{html.escape(title)}</h1>
<p>Pick success <b>{summary['pick_success']:.0%}</b> · right product <b>{right}</b> · {summary['picks_per_min']} picks/min ·
{summary['orders']} orders in {summary['wall_s']} s</p>
<p>Each order: a new bin; the shop photo (top right of the left picture) conditions the detector; orange boxes are its
detections with scores; the GIF shows the grasp and the carry to the order tote.</p>
<table><tr><th>order</th><th>product</th><th>in training</th><th>result</th><th>attempts</th><th>detections</th><th>s</th><th>pictures</th></tr>
{''.join(rows)}</table></body></html>"""
    return atomic_write_text(Path(folder) / "report.html", page)

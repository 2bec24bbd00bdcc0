"""The customer's order tote beside the bin: where picked products go (thesis Fig 1.1).

Static geoms on the table, out of the overhead camera's view; the pick executors carry products here
and the robot cell (:mod:`binpick.sim.panda`) keeps the arm clear of its walls.
"""

from __future__ import annotations

ORDER_TOTE = (0.0, 0.42)  # centre (x, y) of the customer's tote, beside the bin and out of the camera's view
ORDER_HALF, ORDER_WALL, ORDER_HEIGHT = 0.09, 0.01, 0.08


def order_tote_xml(camera: bool = True) -> str:
    """The order tote (static geoms) and, with ``camera``, an overview camera that sees both totes
    and the arm beside them, for the GIFs."""
    x, y = ORDER_TOTE
    h, t, z = ORDER_HALF, ORDER_WALL, ORDER_HEIGHT / 2
    walls = [((x + h + t / 2, y), (t / 2, h + t)), ((x - h - t / 2, y), (t / 2, h + t)),
             ((x, y + h + t / 2), (h, t / 2)), ((x, y - h - t / 2), (h, t / 2))]
    geoms = [f'<geom name="order_floor" type="box" pos="{x} {y} 0.005" size="{h + t} {h + t} 0.005" rgba="0.85 0.55 0.2 1"/>']
    geoms += [f'<geom name="order_wall{i}" type="box" pos="{px} {py} {z}" size="{sx} {sy} {z}" rgba="0.85 0.55 0.2 1"/>'
              for i, ((px, py), (sx, sy)) in enumerate(walls)]
    overview = '<camera name="overview" pos="0.9 0.21 1.0" xyaxes="0 1 0 -0.72 0 0.69" fovy="50"/>' if camera else ""
    return "".join(geoms) + overview

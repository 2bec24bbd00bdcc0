"""The customer's order tote beside the bin: where picked products go (thesis Fig 1.1).

Static geoms on the table, out of the overhead camera's view; the pick executors carry products here
and the robot cell (:mod:`binpick.sim.robot_arm`) keeps the arm clear of its walls.
"""

from __future__ import annotations

ORDER_TOTE = (0.0, 0.42)  # centre (x, y) of the customer's tote, beside the bin and out of the camera's view
ORDER_HALF, ORDER_WALL, ORDER_HEIGHT = 0.09, 0.01, 0.08
ORDER_FLOOR_TOP = 0.01  # the order tote's floor (its top face)
RELEASE_HEIGHT = 0.22  # the highest the tool's centre opens above the order tote
RELEASE_CLEARANCE = 0.03  # how far above the order tote's floor a product's lowest point is let go


def release_height(grasp_z: float, bin_floor: float) -> float:
    """How high (world z) the tool's centre lets a product go above the order tote: the product hung
    at most ``grasp_z - bin_floor`` below the tool's centre when it was grasped off the bin's floor, so
    it is lowered until that much (and RELEASE_CLEARANCE) stays above the tote's floor, never higher
    than RELEASE_HEIGHT. Dropped from higher, a soft or long product bounces or tumbles over a wall."""
    return float(min(RELEASE_HEIGHT, max(grasp_z - bin_floor, 0.0) + ORDER_FLOOR_TOP + RELEASE_CLEARANCE))


def in_order_tote(data, body: int) -> bool:
    """Whether product ``body`` lies in the order tote, judged by its centre of mass: a mesh's body
    origin may sit a hand's width off the product (a teddy's does), inside a wall or outside the tote."""
    x, y, z = data.xipos[body]
    return bool(abs(x - ORDER_TOTE[0]) < ORDER_HALF and abs(y - ORDER_TOTE[1]) < ORDER_HALF and z < ORDER_HEIGHT + 0.1)


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

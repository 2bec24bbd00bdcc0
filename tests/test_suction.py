"""The suction cup in the simulator: a seal only where the lip's ring lies flat on one product, a hold
that lets go when the vacuum's wrench limits are passed, and the hand that carries both tools."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from binpick.grippers import SuctionCup, tool_point_below, tools_of
from binpick.sim.bin_scene import BinWorld
from binpick.sim.gripper import lift_test, trial_timestep
from binpick.sim.mjcf import CameraSpec
from binpick.sim.products import Product
from binpick.grippers import RING, ring_offsets, seal_test


def surface_below(world: BinWorld, x: float, y: float) -> tuple[float, int]:
    """World z of what a ray straight down meets at (x, y), and the body it belongs to (hand ignored)."""
    geom = np.zeros((1, 1), np.int32)
    distance = mujoco.mj_ray(world.model, world.data, np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0]),
                             np.array([1, 1, 1, 0, 1, 1], np.uint8), 1, -1, geom)
    return 1.0 - distance, int(world.model.geom_bodyid[geom[0, 0]])


def suction_trial(product: Product, along: float = 0.0, gripper: str = "suction", tool: str = "suction") -> tuple[bool, str | None]:
    """One lift of ``product`` (alone in the tote) with the cup ``along`` m from its centre along the
    body's own longest horizontal axis; (lifted and carried, why the vacuum let go or never sealed)."""
    world = BinWorld(product, [], max_copies=1, camera=CameraSpec(size=48), gripper=gripper)
    try:
        scene = world.scene(1, 0, seed=0)
        world.set_guards(False)
        world.restore(scene.state)
        body = world.body_ids[0]
        rotation = world.data.xmat[body].reshape(3, 3)
        axis = rotation[:, int(np.argmax(product.size[:2]))] if product.shape == "box" else rotation[:, 0]
        axis = axis[:2] / max(np.linalg.norm(axis[:2]), 1e-9)
        x, y = world.data.xpos[body][:2] + along * axis
        z, hit = surface_below(world, x, y)
        # jaws: the tips at the product's middle, closing across its shorter side; the cup: on the top face
        yaw = float(np.arctan2(axis[0], -axis[1])) if tool == "jaws" else 0.0
        tips = (x, y, world.data.xpos[body][2] if tool == "jaws" else z)
        with trial_timestep(world.model):
            held = lift_test(world, 0, tips, yaw, z, carry=True, tool=tool)
        why = world.gripper.vacuum.why if world.gripper.vacuum is not None else None
        return held, why
    finally:
        world.close()


BOX = Product("test/box", "test", shape="box", size=(0.05, 0.04, 0.03), mass=0.3)


def test_a_cup_on_a_box_face_seals_lifts_and_carries_it():
    assert suction_trial(BOX) == (True, None)


def test_a_cup_over_a_box_edge_does_not_seal():
    held, why = suction_trial(BOX, along=0.05)  # the lip's centre on the edge: half the ring in the air
    assert not held and why in ("the ring leaves the product", "no product under the cup")


def test_a_cup_on_a_small_ball_does_not_seal():
    held, why = suction_trial(Product("test/ball", "test", shape="sphere", size=(0.03,), mass=0.2))
    assert not held and why is not None and why != "the load exceeded the vacuum's hold"


def test_a_heavy_bar_held_far_from_its_centre_peels_off_but_holds_at_its_centre():
    bar = Product("test/bar", "test", shape="box", size=(0.11, 0.025, 0.02), mass=1.0)
    assert suction_trial(bar) == (True, None)
    held, why = suction_trial(bar, along=0.08)  # 1 kg at 8 cm: 0.8 N m against about 0.3 the seal resists
    assert not held and why == "the load exceeded the vacuum's hold"


def test_the_hand_with_both_tools_picks_with_either():
    assert suction_trial(BOX, gripper="both", tool="suction") == (True, None)
    assert suction_trial(BOX, gripper="both", tool="jaws")[0]
    assert tool_point_below("both", "suction") > tool_point_below("both", "jaws") == tool_point_below("suction", "suction")
    with pytest.raises(ValueError, match="carries jaws"):
        suction_trial(BOX, gripper="jaws", tool="suction")
    assert tools_of("both") == ("jaws", "suction")


@pytest.mark.parametrize("surface, reason", [
    (lambda x, y: 0.0 * x, None),  # flat
    (lambda x, y: 0.2 * x + 0.1 * y, None),  # tilted 13 degrees: the bellows follow
    (lambda x, y: 1.0 * x, "the surface is tilted too far"),  # 45 degrees
    (lambda x, y: -(x ** 2) / (2 * 0.033), "the ring is not flat"),  # a lying can, radius 3.3 cm, axis along y
    (lambda x, y: -(x ** 2 + y ** 2) / (2 * 0.03), "the surface bulges into the cup"),  # a 3 cm ball
    (lambda x, y: 0.0 * x - 0.005, "the lip does not touch"),
])
def test_the_seal_test_on_surfaces(surface, reason):
    points = ring_offsets(SuctionCup().radius)
    heights = surface(points[:, 0], points[:, 1])
    assert seal_test(heights, np.ones(len(points), bool), SuctionCup()) == reason


def test_the_seal_test_needs_one_product_under_the_whole_ring():
    points = ring_offsets(SuctionCup().radius)
    same = np.ones(len(points), bool)
    same[3] = False  # one ray meets a neighbour: the seam between two products leaks
    assert seal_test(np.zeros(len(points)), same, SuctionCup()) == "the ring leaves the product"
    heights = np.zeros(len(points))
    heights[RING - 1] = np.nan
    assert seal_test(heights, np.ones(len(points), bool), SuctionCup()) == "the ring leaves the product"

"""The arms that execute picks (a Panda; a UR5e): Ruckig's timing within the joint limits, mink's IK in
the cell, reachability in the plan, an order picked by each arm, and a label grasp made by the Panda."""

from __future__ import annotations

import json

import numpy as np
import pytest

from binpick.arm import MotionPlanner
from binpick.arm.motion import ABOVE_WALLS, COLLIDES, NO_IK
from binpick.arm.trajectory import joint_move, path_move
from binpick.sim.robot_arm import HOME, PANDA_LIMITS

PERIOD = 0.004


@pytest.fixture(scope="module")
def planner() -> MotionPlanner:
    return MotionPlanner(period=PERIOD)


def within_limits(q: np.ndarray, start) -> None:
    """Finite differences of the sampled targets stay within the Panda's velocity and acceleration limits."""
    q = np.vstack([start, q])
    velocity = np.diff(q, axis=0) / PERIOD
    acceleration = np.diff(velocity, axis=0) / PERIOD
    assert np.all(np.abs(velocity) <= np.array(PANDA_LIMITS.velocity) * 1.01 + 1e-6)
    assert np.all(np.abs(acceleration) <= np.array(PANDA_LIMITS.acceleration) * 1.05 + 1e-3)


def test_a_free_move_ends_where_asked_at_rest_and_never_exceeds_the_panda_limits():
    start, end = np.array(HOME), np.array(HOME) + [1.2, 0.5, -0.4, 0.6, 1.0, -0.5, 2.0]
    segment = joint_move("approach", start, end, PANDA_LIMITS, PERIOD)
    assert np.allclose(segment.q[-1], end, atol=1e-9) and np.allclose(segment.qd[-1], 0.0, atol=1e-9)
    within_limits(segment.q, start)
    # joint 7 moves 2 rad: at 2.61 rad/s it cannot take less than 2 / 2.61 s
    assert segment.duration >= 2.0 / PANDA_LIMITS.velocity[6]
    slower = joint_move("approach", start, start + (end - start) * 2, PANDA_LIMITS, PERIOD)
    assert slower.duration > segment.duration


def test_the_arm_refuses_worlds_its_cell_does_not_model():
    from binpick.core.errors import ConfigError
    from binpick.detection.model import DetectorNetwork, ModelSpec
    from binpick.sim import default_library
    from binpick.sim.sensor import load_sensor
    from binpick.warehouse.generation import GenerateConfig
    from binpick.warehouse.pipeline import PickPipeline

    with pytest.raises(ConfigError, match="level tote"):
        PickPipeline(DetectorNetwork(ModelSpec(query="photo"), 64), default_library(procedural=0, shapes=0), grasp="analytic",
                     robot="panda", sensor=load_sensor("realistic"))
    with pytest.raises(ConfigError, match="grasp_trials"):
        GenerateConfig(out="x", robot="panda", grasp_trials=2)
    with pytest.raises(ConfigError, match="robot"):
        GenerateConfig(out="x", robot="ur10")


def test_a_path_move_follows_the_path_in_order_within_the_limits():
    path = np.linspace(HOME, np.array(HOME) + [0.0, 0.3, 0.0, 0.4, 0.0, -0.2, 0.0], 9)
    segment = path_move("descend", path, PANDA_LIMITS, PERIOD)
    assert np.allclose(segment.q[-1], path[-1], atol=1e-6)
    within_limits(segment.q, path[0])
    progress = (segment.q[:, 3] - path[0, 3]) / 0.4  # one joint's share of the way: never goes back
    assert np.all(np.diff(progress) >= -1e-9)


def test_ik_puts_the_gripper_on_a_top_down_grasp_in_the_bin(planner):
    kinematics = planner.kinematics
    target = np.array([0.05, -0.06, 0.09])
    solution = kinematics.solve(target, np.pi / 3)
    assert solution.ok, solution
    position, rotation = kinematics.gripper_pose(solution.q)
    assert np.linalg.norm(position - target) < 0.003
    assert rotation[2, 2] > 0.999  # palm up: the fingers point down
    yaw = np.arctan2(rotation[1, 0], rotation[0, 0])
    assert abs((yaw - np.pi / 3 + np.pi / 2) % np.pi - np.pi / 2) < 0.03  # the jaws close along the asked yaw (mod a half turn)
    lower, upper = np.array(PANDA_LIMITS.lower), np.array(PANDA_LIMITS.upper)
    assert np.all(solution.q >= lower - 1e-6) and np.all(solution.q <= upper + 1e-6)


def test_reach_says_why_a_grasp_cannot_be_taken(planner):
    assert planner.reach([0.0, 0.0, 0.09], 0.0).ok
    assert planner.reach([1.3, -0.6, 0.09], 0.0).reason == NO_IK  # beyond the arm's reach
    # jaws across the bin wall, fingertips near the floor: the gripper would go through the wall
    assert planner.reach([0.205, 0.0, 0.07], 0.0).reason == COLLIDES
    reach = planner.reach([0.0, 0.0, 0.09], 0.0)
    assert not planner._flipped(reach.descent[0])
    flipped = reach.descent[0].copy()
    flipped[4] += np.pi  # the wrist turned over
    assert planner._flipped(flipped)


def test_a_step_the_ik_cannot_take_is_an_unreached_pose_not_an_error(planner, monkeypatch):
    """DAQP finds no step that keeps every limit (a start already too near an obstacle): mink raises,
    and the solve ends there as unreached, so the reach check refuses that grasp (or push) and the
    planner goes on to the next, where a pick run once stopped with the solver's traceback."""
    import mink

    kinematics = planner.kinematics
    calls = []

    def no_step(*arguments, **keywords):
        calls.append(1)
        if len(calls) > 2:
            raise mink.exceptions.NoSolutionFound("daqp")
        return original(*arguments, **keywords)

    original = mink.solve_ik
    monkeypatch.setattr(mink, "solve_ik", no_step)
    solution = kinematics.solve(np.array([0.05, -0.06, 0.09]), 0.0)
    assert not solution.reached and solution.iterations == 3 and len(calls) == 3
    assert planner.reach([0.02, 0.03, 0.09], 0.0).reason == NO_IK  # (answers are kept per pose: one no other test asks)
    monkeypatch.setattr(mink, "solve_ik", original)
    assert planner.reach([0.02, 0.04, 0.09], 0.0).ok
    planner._answers.clear()  # the refused pose's answer is not left for the module's other tests


def test_a_grasp_whose_hand_grazes_a_tote_wall_is_refused_and_taken_ones_keep_clear(planner):
    """The arm tracks its targets within about 2 mm: a descent planned to graze the wall hits it when run."""
    import mujoco

    from binpick.arm.kinematics import CLEARANCE

    kinematics = planner.kinematics
    walls = [kinematics.model.geom(f"bin_wall{k}").id for k in range(4)]

    def nearest_wall(q) -> float:
        """With libccd: MuJoCo's native CCD returned 0 for a finger and a wall 4 cm apart at one posture (on an AMD
        EPYC; 1e-9 rad away it returned 0.041), and libccd's distance is the reference for a box pair."""
        kinematics.data.qpos[:] = kinematics.full(q)
        mujoco.mj_forward(kinematics.model, kinematics.data)
        flags = kinematics.model.opt.disableflags
        kinematics.model.opt.disableflags = flags | int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
        try:
            return min(mujoco.mj_geomDistance(kinematics.model, kinematics.data, int(g), w, 0.05, np.zeros(6))
                       for g in kinematics.robot for w in walls)
        finally:
            kinematics.model.opt.disableflags = flags

    # tips 7 cm inside the wall at x = -0.21, jaws across it at 15 degrees: the palm and a finger would come
    # within 0.3 mm of it (a pick the arm once made, hitting the wall on the lift)
    grazing = planner.reach(np.array([-0.1407, -0.0508, 0.036]) + [0, 0, planner.below("jaws")], 0.2618)
    assert grazing.reason == COLLIDES
    taken = [planner.reach(np.array([x, -0.0508, 0.036]) + [0, 0, planner.below("jaws")], 0.2618) for x in (-0.1, 0.0)]
    assert all(reach.ok for reach in taken)  # the same grasp further in is taken, every link clear of the walls
    assert min(nearest_wall(q) for reach in taken for q in reach.descent) >= CLEARANCE - 1e-4


def test_a_pick_motion_has_every_segment_and_returns_home(planner):
    motion = planner.pick(HOME, [0.02, 0.03, 0.1], 0.3)
    assert motion.reach.ok
    names = [s.name for s in motion.segments]
    for name in ("approach", "descend", "close", "lift", "carry", "lower", "release", "retreat", "return"):
        assert name in names
    assert np.allclose(motion.segments[-1].q[-1], HOME, atol=1e-6)
    kinematics = planner.kinematics
    bottom, _ = kinematics.gripper_pose(motion.segment("descend").q[-1])
    assert np.linalg.norm(bottom - [0.02, 0.03, 0.1]) < 0.004
    top, _ = kinematics.gripper_pose(motion.segment("descend").q[0])
    assert abs(top[2] - max(0.25, ABOVE_WALLS)) < 0.004 and np.linalg.norm(top[:2] - bottom[:2]) < 0.004  # straight down
    assert not any(planner.touches(s, every=5) for s in motion.segments)
    low, _ = kinematics.gripper_pose(motion.segment("retreat").q[0])
    out, _ = kinematics.gripper_pose(motion.segment("retreat").q[-1])  # straight up out of the order tote before going home
    assert np.linalg.norm(out[:2] - low[:2]) < 0.004 and out[2] - low[2] > 0.05 and np.allclose(motion.segment("return").q[0], motion.segment("retreat").q[-1], atol=0.01)
    before = np.asarray(HOME, dtype=float)
    for segment in motion.segments:  # the straight segments too (a spline through the IK postures)
        within_limits(segment.q, before)
        before = segment.q[-1]
    assert 2.0 < sum(s.duration for s in motion.segments) < 8.0


def test_the_fingertips_stop_short_of_the_bin_floor(planner):
    from binpick.arm.motion import FLOOR_MARGIN
    from binpick.sim.mjcf import FLOOR_TOP

    motion = planner.pick(HOME, [0.0, 0.0, FLOOR_TOP + 0.04], 0.0)  # tips asked onto the floor itself
    bottom, _ = planner.kinematics.gripper_pose(motion.segment("descend").q[-1])
    assert bottom[2] - 0.04 >= FLOOR_TOP + FLOOR_MARGIN - 0.002


def test_the_picker_gives_an_unreachable_grasp_way_to_the_next_candidate():
    from binpick.grasping import GraspPlanner
    from binpick.picking import Picker
    from binpick.picking.frames import read_frame
    from binpick.picking.plans import grasp_orientation
    from binpick.samples import SAMPLE_FRAME

    rgb, depth, camera = read_frame(SAMPLE_FRAME / "rgb.png", SAMPLE_FRAME / "depth.png", SAMPLE_FRAME / "camera.yaml")
    box = np.array([[392.48, 176.5, 104.46, 72.66]])  # a detection of the sample frame's product
    free = Picker(None, GraspPlanner.load("analytic"), verifier=None).plan(rgb, depth, camera, boxes=(box, np.ones(1)))
    assert free[0].feasible
    first = tuple(free[0].position)

    asked, yaws = [], []

    def reach(position, yaw):
        asked.append(tuple(np.round(position, 4)))
        yaws.append(yaw)
        return (None, yaw + np.pi) if len(asked) > 1 else (NO_IK, yaw)  # the best candidate is out of reach; the next is, jaws turned

    plans = Picker(None, GraspPlanner.load("analytic"), verifier=None, reach=reach).plan(rgb, depth, camera, boxes=(box, np.ones(1)))
    assert plans[0].feasible and plans[0].rejected.get(NO_IK) == 1 and tuple(plans[0].position) != first
    assert abs(plans[0].yaw - (yaws[1] + np.pi)) < 1e-3  # the plan's yaw is the one the arm takes
    assert np.allclose(plans[0].orientation, grasp_orientation(plans[0].yaw), atol=1e-5)
    never = Picker(None, GraspPlanner.load("analytic"), verifier=None, reach=lambda p, y, tool="jaws": (COLLIDES, y)).plan(rgb, depth, camera, boxes=(box, np.ones(1)))
    assert not never[0].feasible and never[0].rejected.get(COLLIDES, 0) >= 1
    assert json.loads(json.dumps(never.to_json()))["plans"][0]["rejected"][COLLIDES] >= 1


@pytest.mark.parametrize("robot", ["panda", "ur5e"])
def test_one_order_is_picked_and_placed_by_the_arm(tmp_path, robot):
    from binpick.detection.model import DetectorNetwork, ModelSpec
    from binpick.sim import default_library
    from binpick.sim.mjcf import CameraSpec
    from binpick.warehouse.orders import fulfil
    from binpick.warehouse.pipeline import PickPipeline

    detector = DetectorNetwork(ModelSpec(query="photo"), 128).eval()
    pipeline = PickPipeline(detector, default_library(procedural=0, shapes=0), grasp="analytic", oracle=True, max_attempts=2,
                            camera=CameraSpec(size=160), robot=robot, gripper="jaws")  # the simulator's boxes: the arm's own test
    summary, results = fulfil(pipeline, ["robosuite/can"], 1, 3, tmp_path)
    order = results[0]
    assert order.success, order
    attempt = next(a for a in order.attempts if a.motion_s)
    assert {"approach", "descend", "close", "lift", "carry", "lower", "release", "return"} <= set(attempt.motion_s)
    assert attempt.collisions == [] and attempt.planning_ms > 0
    arm = summary["arm"]
    assert arm["collisions"] == 0 and 2.0 < arm["cycle_s_median"] < 8.0 and arm["picks_per_hour"] > 300
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["orders"][0]["robot"] == robot and saved["orders"][0]["robot_seconds"] > 2.0
    assert (tmp_path / order.gif).stat().st_size > 10_000
    name = {"panda": "Panda", "ur5e": "UR5e"}[robot]
    assert f"{name} arm: median cycle" in (tmp_path / "report.html").read_text()  # the report names the arm that ran


def test_the_arm_picks_with_its_suction_cup(tmp_path):
    from binpick.detection.model import DetectorNetwork, ModelSpec
    from binpick.sim import default_library
    from binpick.sim.mjcf import CameraSpec
    from binpick.warehouse.grasping import Reason
    from binpick.warehouse.orders import fulfil
    from binpick.warehouse.pipeline import PickPipeline

    detector = DetectorNetwork(ModelSpec(query="photo"), 128).eval()
    pipeline = PickPipeline(detector, default_library(procedural=0, shapes=0), grasp="learnt", oracle=True, max_attempts=3,
                            camera=CameraSpec(size=160), robot="panda", gripper="suction")
    # two bins: a carton's cup can lose its hold (the vacuum's limits), and the simulator's contacts differ in the last
    # digits between CPUs, so one bin's outcome is not the arm's; a placed carton in neither is
    summary, results = fulfil(pipeline, ["robosuite/milk"], 2, 3, tmp_path)
    tried = [a for r in results for a in r.attempts if a.motion_s]
    assert tried and all(a.tool == "suction" and a.collisions == [] for a in tried)
    placed = [a for a in tried if a.outcome is Reason.PLACED]
    assert placed and any(r.success for r in results), results
    assert {"approach", "descend", "close", "lift", "carry", "lower", "release", "return"} <= set(placed[-1].motion_s)
    assert summary["by_tool"]["suction"]["placed"] == len(placed) >= 1


def test_the_arm_makes_label_grasps():
    from binpick.sim import default_library
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.gripper import TopDownGrasp
    from binpick.sim.mjcf import CameraSpec
    from binpick.sim.robot_arm import RobotArm
    from binpick.warehouse.grasping import arm_lift_test
    from binpick.warehouse.policies import ArmGrasp, make_policies

    library = default_library(procedural=0, shapes=0)
    world = BinWorld(library["robosuite/can"], [], max_copies=2, camera=CameraSpec(size=128), robot=RobotArm(), seed=3)
    try:
        scene = world.scene(2, 0, seed=3)
        world.set_guards(False)
        planner = MotionPlanner(period=PERIOD)
        central = min(scene.instances, key=lambda i: np.hypot(*i.position[:2]))
        outcomes = {}
        for axis in ("x", "x", "y"):  # x twice: from the same saved state, the same outcome
            world.restore(scene.state)
            outcomes.setdefault(axis, []).append(ArmGrasp(TopDownGrasp(axis), planner).attempt(world, central.slot))
        assert outcomes["x"][0] == outcomes["x"][1]
        assert outcomes["x"][0] or outcomes["y"][0]  # a lone can in the middle of the bin: one of the two grasps holds it
        world.restore(scene.state)
        assert not arm_lift_test(world, planner, central.slot, (1.4, 0.0, 0.05), 0.0)  # out of reach: not pickable by it
        assert np.allclose(world.arm.joint_positions(world.data), HOME, atol=2e-3)  # and the arm never moved
    finally:
        world.close()
    assert all(isinstance(p, ArmGrasp) for p in make_policies(["x", "y"], "panda"))


def test_the_arm_pushes_with_its_jaws_closed_and_refuses_a_push_its_palm_cannot_reach(planner):
    import mujoco

    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.mjcf import BIN_HALF, FLOOR_TOP, CameraSpec
    from binpick.sim.robot_arm import RobotArm
    from binpick.sim.products import Product
    from binpick.warehouse.grasping import execute_arm_push

    can = Product("test/can", "test", shape="cylinder", size=(0.022, 0.03), mass=0.15)
    world = BinWorld(can, [], max_copies=1, camera=CameraSpec(size=96), robot=RobotArm(), seed=1)
    try:
        world.scene(1, 0, seed=1)
        world.set_guards(False)
        lying = [np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0]  # along x
        world._place(0, [0.0, 0.0, FLOOR_TOP + 0.023], lying)
        for _ in range(300):
            mujoco.mj_step(world.model, world.data)
        top = FLOOR_TOP + 0.044
        start, end = np.array([0.0, 0.012, top - 0.008]), np.array([0.0, -0.048, top - 0.008])  # on its +y side, towards -y
        moved, why = execute_arm_push(world, planner, start, end, -np.pi / 2)
        assert why is None and moved > 0.02 and world.data.xipos[world.body_ids[0]][1] < -0.02  # it rolled the way it was pushed
        assert np.allclose(world.arm.joint_positions(world.data), HOME, atol=2e-2)  # home again, out of the camera's view
        corner = np.array([BIN_HALF[0] - 0.031, -(BIN_HALF[1] - 0.023), top - 0.008])  # the palm is wider than the gap there
        before = world.arm.joint_positions(world.data).copy()
        moved, why = execute_arm_push(world, planner, corner, corner + [-0.035, 0.035, 0.0], 3 * np.pi / 4)
        assert moved == 0.0 and why == COLLIDES and np.allclose(world.arm.joint_positions(world.data), before)
    finally:
        world.close()


def test_the_ur5e_reaches_into_the_bin_and_waits_out_of_the_cameras_view():
    import mujoco

    from binpick.sim import default_library
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.mjcf import FLOOR_TOP, CameraSpec
    from binpick.sim.robot_arm import UR5E, UR5E_LIMITS, RobotArm

    ur5e = MotionPlanner.for_cell(None, "jaws", PERIOD, arm="ur5e")
    assert ur5e.kinematics.arm.name == "ur5e" and len(ur5e.home) == 6
    for x, y in ((0.0, 0.0), (0.12, 0.08), (-0.12, -0.08), (0.12, -0.08), (-0.12, 0.08)):
        assert ur5e.reach([x, y, FLOOR_TOP + 0.06], 0.4).ok  # the fingertips 2 cm above the floor, 12 and 8 cm off its centre
    assert ur5e.reach([0.15, 0.1, FLOOR_TOP + 0.06], 0.4).reason == COLLIDES  # nearer a corner the open hand meets a wall
    motion = ur5e.pick(ur5e.home, [0.02, 0.03, FLOOR_TOP + 0.08], 0.3)
    q = np.vstack([segment.q for segment in motion.segments])
    assert np.all(q >= np.array(UR5E_LIMITS.lower) - 1e-6) and np.all(q <= np.array(UR5E_LIMITS.upper) + 1e-6)
    velocity = np.diff(q, axis=0) / PERIOD
    assert np.all(np.abs(velocity) <= np.array(UR5E_LIMITS.velocity) * 1.01 + 1e-6)
    world = BinWorld(default_library(procedural=0, shapes=0)["robosuite/can"], [], max_copies=1, camera=CameraSpec(size=96),
                     robot=RobotArm(UR5E), seed=1)
    try:
        world.arm.hold(world.model, world.data)
        mujoco.mj_forward(world.model, world.data)
        renderer = mujoco.Renderer(world.model, 96, 96)
        renderer.enable_segmentation_rendering()
        renderer.update_scene(world.data, camera="overhead")
        seen = renderer.render()[..., 0]
        renderer.close()
        assert not np.isin(seen, world.arm.geoms).any()  # at home no link is in the overhead camera's frame (as it renders)
    finally:
        world.close()

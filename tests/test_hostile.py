"""Hostile and broken input the way a robot cell meets it: camera messages and goals a bad publisher
sends, calibrations no camera has, grasp poses outside the workspace. Every one is refused in one
line (or dropped with a warning); nothing is silently accepted, nothing takes a node down."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from binpick.core.errors import BinpickError, ConfigError, InputFileError
from conftest import run_cli
from binpick.grasping import PinholeCamera
from binpick.picking.camera_info import CameraInfo, read_camera_info
from binpick.picking.node import (ENCODINGS, FrameSynchroniser, Guard, colour_of, depth_of, image_array, parse_goal,
                                  parse_goal_json)
from binpick.picking.workspace import OUTSIDE, Workspace
from binpick.samples import SAMPLE_FRAME

ROOT = Path(__file__).resolve().parents[1]
K = np.array([[400.0, 0.0, 207.5], [0.0, 400.0, 207.5], [0.0, 0.0, 1.0]])
DOWN = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, 0.8], [0, 0, 0, 1.0]])


def ros_loop():
    """The ROS loop benchmark, whose hostile corpora the running nodes are tested with."""
    spec = importlib.util.spec_from_file_location("ros_loop", ROOT / "benchmarks" / "ros_loop.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def one_line(error: BaseException) -> str:
    text = str(error)
    assert "\n" not in text and text.strip(), text
    return text


def node_conversion(topic: str, fields: dict):
    """What either node does with a camera message before it reaches the synchroniser."""
    if topic == "info":
        return CameraInfo.from_ros(fields["k"], fields["d"], fields["width"], fields["height"], DOWN,
                                   fields["distortion_model"] or "plumb_bob")
    pixels = image_array(fields["encoding"], fields["height"], fields["width"], fields["step"], fields["data"])
    return colour_of(fields["encoding"], pixels) if topic == "colour" else depth_of(fields["encoding"], pixels)


def test_every_hostile_camera_message_is_refused_in_one_line():
    cases = ros_loop().hostile_camera_messages(416, 416, K)
    assert len(cases) >= 15
    for case, topic, fields in cases:
        with pytest.raises(BinpickError) as refused:
            node_conversion(topic, fields)
        one_line(refused.value)
    good = {"width": 416, "height": 416, "distortion_model": "plumb_bob", "d": [0.0] * 5, "k": K.ravel().tolist()}
    assert node_conversion("info", good).camera.width == 416  # the corpus's good message passes


@pytest.mark.parametrize("case,fields", [c for c in ros_loop().hostile_goals(2, 416, 416) if "json" in c[1]])
def test_every_hostile_ros2_goal_is_refused_before_planning(case, fields):
    """(Photo goals are refused by the image checks; the running node's test sends them too.)"""
    if case in ("query_box off the image", "product unknown", "nothing asked"):
        goal = parse_goal(parse_goal_json(fields["json"]))  # well formed: the picker and the catalogue refuse these
        assert goal.query_box or goal.product_id or goal.id
        return
    with pytest.raises(InputFileError) as refused:
        parse_goal(parse_goal_json(fields["json"]))
    one_line(refused.value)


def test_a_good_goal_parses_and_fields_are_checked_one_by_one():
    goal = parse_goal(parse_goal_json('{"id": "a", "product_id": "robosuite/can", "max_grasps": 3, "size": [0.1, 0.07, 0.07]}'))
    assert (goal.id, goal.product_id, goal.max_grasps, goal.size) == ("a", "robosuite/can", 3, [0.1, 0.07, 0.07])
    assert parse_goal({"query_box": [1, 2, 3, 4], "max_grasps": 2.0}).max_grasps == 2
    for bad, field in (({"max_grasps": 101}, "max_grasps"), ({"size": [0.1, 0.0, 0.1]}, "size"),
                       ({"query_box": [1, 2, 3, True]}, "query_box"), ({"id": ["x"]}, "id")):
        with pytest.raises(InputFileError, match=field):
            parse_goal(bad)


@settings(max_examples=150, deadline=None)
@given(st.recursive(st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=20),
                    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=12), inner, max_size=6),
                    max_leaves=30))
def test_any_json_value_as_a_goal_parses_or_is_one_line(value):
    """Whatever a publisher sends as a goal: a checked goal, or InputFileError, never another exception."""
    try:
        text = json.dumps(value)
    except ValueError:
        return
    try:
        goal = parse_goal(parse_goal_json(text))
    except InputFileError as error:
        one_line(error)
        return
    assert 0 <= goal.max_grasps <= 100 and isinstance(goal.copies_only, bool)
    for numbers in (goal.size or [], goal.query_box or []):
        assert all(math.isfinite(v) for v in numbers)


@settings(max_examples=200, deadline=None)
@given(encoding=st.sampled_from([*ENCODINGS, "yuv422", "", "8UC3"]), height=st.integers(-2, 20_000),
       width=st.integers(-2, 20_000), step=st.integers(-8, 1 << 33), data=st.binary(max_size=600))
def test_any_image_message_gives_pixels_or_one_line(encoding, height, width, step, data):
    try:
        pixels = image_array(encoding, height, width, step, data)
    except InputFileError as error:
        one_line(error)
        return
    assert pixels.shape[:2] == (height, width)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=9, max_size=9),
       st.integers(-5, 20_000), st.integers(-5, 20_000))
def test_any_intrinsics_give_a_real_camera_or_one_line(k, width, height):
    try:
        camera = PinholeCamera(np.array(k).reshape(3, 3), width, height)
    except ConfigError as error:
        one_line(error)
        return
    fx, fy = camera.K[0, 0], camera.K[1, 1]
    assert 0 < fx < 30 * width and 0 < fy < 30 * height and 0 <= camera.K[0, 2] <= width


BAD_POSES = {
    "scaled": np.diag([2.0, 2.0, 2.0, 1.0]),
    "mirrored": np.diag([1.0, 1.0, -1.0, 1.0]),
    "sheared": np.array([[1.0, 0.5, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]),
    "projective": np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0.1, 0, 0, 1.0]]),
    "a kilometre away": np.array([[1.0, 0, 0, 1000.0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]),
}


@pytest.mark.parametrize("name", BAD_POSES)
def test_a_camera_pose_that_is_not_rigid_is_one_line(name):
    with pytest.raises(ConfigError) as refused:
        PinholeCamera(K, 416, 416, BAD_POSES[name])
    one_line(refused.value)


@pytest.mark.parametrize("k,fragment", [
    ([1e-6, 0, 207.5, 0, 1e-6, 207.5, 0, 0, 1], "focal length fx = 1e-06"),
    ([1e7, 0, 207.5, 0, 1e7, 207.5, 0, 0, 1], "focal length"),
    ([400, 0, 5000, 0, 400, 207.5, 0, 0, 1], "principal point"),
    ([400, 0, 207.5, 0, 400, 207.5, 0, 0, 2], "[0, 0, 1]"),
])
def test_intrinsics_no_camera_has_are_one_line(k, fragment):
    with pytest.raises(ConfigError) as refused:
        PinholeCamera(np.array(k, dtype=float).reshape(3, 3), 416, 416)
    assert fragment in one_line(refused.value)


@pytest.mark.parametrize("d,model,fragment", [([0.1, 0.0, 0.0], "plumb_bob", "got 3"), ([0.1] * 5, "equidistant", "not zero"),
                                              ([0.1] * 7, "equidistant", "got 7"), ([0.1] * 9, "rational_polynomial", "got 9"),
                                              ([float("inf")] * 5, "plumb_bob", "finite"), ([0.2], "none", "non-zero")])
def test_distortion_of_the_wrong_length_is_one_line(d, model, fragment):
    with pytest.raises(ConfigError, match=fragment):
        CameraInfo.from_ros(K.ravel(), d, 416, 416, DOWN, model)
    assert CameraInfo.from_ros(K.ravel(), [], 416, 416, DOWN, "plumb_bob").D.size == 0  # none given: no distortion
    for model, length in (("plumb_bob", 5), ("plumb_bob", 8), ("rational_polynomial", 14), ("equidistant", 4)):
        assert CameraInfo.from_ros(K.ravel(), [0.01] * length, 416, 416, DOWN, model).D.size == length  # what drivers publish


def sample_camera(tmp_path: Path, change) -> Path:
    data = yaml.safe_load((SAMPLE_FRAME / "camera.yaml").read_text())
    change(data)
    path = tmp_path / "camera.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_plan_with_a_focal_length_of_1e_minus_6_is_one_line_and_never_a_pose(tmp_path, monkeypatch, capsys):
    def tiny_focal(data):
        data["camera_matrix"]["data"][0] = data["camera_matrix"]["data"][4] = 1e-6

    camera = sample_camera(tmp_path, tiny_focal)
    code, err = run_cli(["plan", "--rgb", str(SAMPLE_FRAME / "rgb.png"), "--depth", str(SAMPLE_FRAME / "depth.png"),
                         "--camera", str(camera), "--photo", str(SAMPLE_FRAME / "photo.png"), "--out", str(tmp_path / "plans")],
                        capsys, monkeypatch)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "focal length fx = 1e-06" in lines[0], err
    assert not (tmp_path / "plans" / "plan.json").exists()


def test_a_workspace_in_camera_yaml_rejects_grasps_outside_it(tmp_path):
    from binpick.picking import Picker

    inside = read_camera_info(SAMPLE_FRAME / "camera.yaml")
    far_away = read_camera_info(sample_camera(tmp_path, lambda d: d.update(workspace={"min": [5.0, 5.0, 0.0], "max": [6.0, 6.0, 1.0]})))
    assert far_away.workspace == Workspace((5.0, 5.0, 0.0), (6.0, 6.0, 1.0))
    assert inside.workspace == Workspace((-0.25, -0.2, 0.0), (0.25, 0.2, 0.45))  # the sample frame's tote
    from binpick.core.depth import read_depth
    from binpick.detection.data import read_image

    rgb, depth = read_image(SAMPLE_FRAME / "rgb.png"), read_depth(SAMPLE_FRAME / "depth.png")
    box = [393, 279, 93, 59]  # the README's pointed instance
    picker = Picker.load(grasp="analytic")
    planned = picker.plan(rgb, depth, inside, query_box=box, max_grasps=1)
    assert planned.grasps and all(inside.workspace.contains(p.position) for p in planned.grasps)
    refused = picker.plan(rgb, depth, far_away, query_box=box, max_grasps=1)
    assert not refused.grasps and refused[0].rejected.get(OUTSIDE) == 1  # the reason travels with the plan
    with pytest.raises(InputFileError, match="workspace"):
        read_camera_info(sample_camera(tmp_path, lambda d: d.update(workspace={"min": [0, 0, 0], "max": [50, 1, 1]})))


def test_a_frame_stamped_in_the_future_does_not_pin_the_planner():
    frames = FrameSynchroniser()
    info = CameraInfo(PinholeCamera(np.array([[6.0, 0.0, 3.0], [0.0, 6.0, 2.0], [0.0, 0.0, 1.0]]), 7, 5))
    for stamp, value in ((1e9, 9.0), (1.0, 1.0)):  # a triple stamped 30 years ahead, then the camera's own
        frames.add_colour(stamp, np.zeros((5, 7, 3), np.uint8))
        frames.add_depth(stamp, np.full((5, 7), value))
        frames.add_info(stamp, info)
    assert frames.latest().depth[0, 0] == 1.0  # the newest frame to arrive, not the largest stamp
    with pytest.raises(InputFileError, match="time stamp"):
        frames.add_depth(float("nan"), np.ones((5, 7)))


def test_the_guard_drops_refused_camera_messages_with_throttled_warnings_and_counts_its_own_errors_apart():
    warnings: list[str] = []
    guard = Guard(warnings.append, every=60.0)
    seen: list[int] = []

    def callback(message: int) -> None:
        if message == 0:
            raise InputFileError("image of 0x0 pixels: each side must be 1 to 8192")  # refused: binpick's reason
        if message < 0:
            seen.append(1 // (message + 1))  # a bug in the node: ZeroDivisionError
        seen.append(message)

    guarded = guard.frames("/camera/color/image_raw", callback)
    for message in (0, 0, 1, 0, -1):
        guarded(message)  # never raised
    assert seen == [1] and guard.dropped == {"/camera/color/image_raw": 3} and guard.errors == {"/camera/color/image_raw": 1}
    refused = [w for w in warnings if "dropped a message" in w]
    assert len(refused) == 1 and "0x0 pixels" in refused[0]  # throttled: one line for three refusals
    internal = [w for w in warnings if "internal error" in w]
    assert len(internal) == 1 and "Traceback" in internal[0] and "ZeroDivisionError" in internal[0]  # in the node's log
    assert [json.loads(text) for text in guard.report()] == [{"/camera/color/image_raw": 3}, {"/camera/color/image_raw": 1}]
    assert guard.report() is None  # nothing new since
    assert "dropped 3 messages" in guard.summary() and "1 internal errors" in guard.summary()


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=400))
def test_any_text_as_yaml_gives_data_or_one_line(text):
    from binpick.core.files import parse_yaml

    try:
        parse_yaml(text, "settings.yaml")
    except InputFileError as error:
        one_line(error)


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=300))
def test_any_bytes_as_a_json_file_give_data_or_one_line(data):
    import tempfile

    from binpick.core.files import read_json

    with tempfile.NamedTemporaryFile(suffix=".json") as file:
        file.write(data)
        file.flush()
        try:
            read_json(file.name, "scene file")
        except InputFileError as error:
            one_line(error)


JSON_VALUES = st.recursive(st.none() | st.booleans() | st.floats() | st.integers(-10**6, 10**6) | st.text(max_size=12),
                           lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner, max_size=4),
                           max_leaves=12)


@settings(max_examples=150, deadline=None)
@given(st.dictionaries(st.sampled_from(["name", "env", "algorithm", "total_timesteps", "seed", "env_kwargs", "sac", "replay",
                                        "eval", "curriculum", "gp", "unknown"]), JSON_VALUES, max_size=5))
def test_any_mapping_as_an_rl_config_gives_a_config_or_one_line(data):
    """The config loader's one path (from_dict, then the dataclasses' own checks) on whatever a file holds."""
    from binpick.core.config import from_dict
    from binpick.rl.config import RLConfig

    try:
        from_dict(RLConfig, data, "rl.yaml")
    except BinpickError as error:
        one_line(error)


def test_json_depth_counts_brackets_outside_strings_only():
    from binpick.picking.node import json_depth

    assert json_depth('{"id": "[[[[x", "size": [1, 2, 3]}') == 2
    hidden = '{"id": "' + "]" * 30 + '", "x": ' + "[" * 30 + "]" * 30 + "}"  # closing brackets in a string hide nothing
    assert json_depth(hidden) == 31
    with pytest.raises(InputFileError, match="nests 31 levels"):
        parse_goal_json(hidden)
    assert parse_goal_json('{"id": "[[[[x", "product_id": "a"}')["id"] == "[[[[x"


def test_a_live_grpc_server_passes_the_ray_probe_and_a_silent_one_does_not():
    """Ray's head speaks gRPC: the probe's HTTP/2 greeting is answered at once (a silent peer is the
    hostile-file suite's)."""
    from concurrent import futures

    import grpc

    from binpick.core.cluster import probe_ray_address

    server = grpc.server(futures.ThreadPoolExecutor(max_workers=1))
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    try:
        probe_ray_address(f"127.0.0.1:{port}", timeout=5.0)  # no exception: a live peer
    finally:
        server.stop(0)


def test_yaml_duplicates_are_found_by_value_and_rounded_hand_eye_matrices_pass():
    from binpick.core.files import parse_yaml

    with pytest.raises(InputFileError, match="twice"):
        parse_yaml("yes: a\ntrue: b\n", "x.yaml")  # both the boolean true
    assert parse_yaml("1: a\n'1': b\n", "x.yaml") == {1: "a", "1": "b"}
    rounded = np.array([[0.47, 0.836, 0.285, 0.1], [0.814, -0.285, -0.507, 0.2], [-0.342, 0.47, -0.814, 0.9], [0, 0, 0, 1.0]])
    camera = PinholeCamera(K, 416, 416, rounded)  # printed to 3 decimals: accepted, made exactly rigid
    rotation = camera.camera_to_world[:3, :3]
    assert np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-9) and np.allclose(rotation, rounded[:3, :3], atol=0.01)


def test_the_hostile_benchmark_counts_one_error_line_as_a_refusal_and_warnings_before_it_do_not_spoil_it():
    spec = importlib.util.spec_from_file_location("hostile_benchmark", ROOT / "benchmarks" / "hostile.py")
    hostile = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hostile)
    outcome = hostile.outcome
    assert outcome(2, "error: cannot write 'plan/plan.json': File too large\n", ["File too large"]) == "one_line"
    assert outcome(2, "warning: depth is 320x240\nerror: cannot write 'x': File too large\n", ["File too large"]) == "one_line"
    assert outcome(2, "error: something else\n", ["File too large"]) == "one_line_other_reason"
    assert outcome(2, "error: one\nerror: two\n", []) == "silent_acceptance"  # two problems: not one clean line
    assert outcome(0, "warning: only a warning\n", []) == "silent_acceptance"  # exit 0 on a hostile case: accepted
    assert outcome(1, "Traceback (most recent call last):\n  ...\n", []) == "traceback"


@pytest.mark.parametrize("shape, fragment", [([10**6, 10**6], "more than"), ([3, -2], "negative side")])
def test_a_saved_policy_whose_observation_space_no_policy_reads_is_one_line(tmp_path, shape, fragment):
    from binpick.core import tensorfile
    from binpick.core.errors import InputFileError
    from binpick.rl.common.persistence import POLICY_FORMAT, load_saved_policy

    path = tmp_path / "policy.safetensors"
    tensorfile.save(path, POLICY_FORMAT, tensors={"policy.x": __import__("torch").zeros(1)},
                    meta={"family": "sac", "policy": "MultiInputPolicy", "policy_kwargs": {},
                          "observation_space": {"shape": shape, "low": -1.0, "high": 1.0, "dtype": "float32"},
                          "action_space": {"shape": [4], "low": -1.0, "high": 1.0, "dtype": "float32"}})
    with pytest.raises(InputFileError, match=fragment) as raised:
        load_saved_policy(path)
    assert "\n" not in str(raised.value) and "observation_space" in str(raised.value)


def test_a_space_of_many_boxes_too_large_together_or_nested_too_deep_is_one_line():
    from binpick.core.errors import InputFileError
    from binpick.envs.spaces import MAX_ELEMENTS, build_space, describe_space

    box = {"shape": [MAX_ELEMENTS // 2], "low": -1.0, "high": 1.0, "dtype": "float32"}
    with pytest.raises(InputFileError, match="together"):
        build_space({f"part{i}": box for i in range(3)}, "policy observation_space")
    deep = {"shape": [2], "low": 0.0, "high": 1.0, "dtype": "float32"}
    for _ in range(12):
        deep = {"inner": deep}
    with pytest.raises(InputFileError, match="nested deeper"):
        build_space(deep)
    import gymnasium as gym

    fine = gym.spaces.Dict({"observation": gym.spaces.Box(-1, 1, (10,)), "goal": gym.spaces.Box(-1, 1, (3,))})
    assert build_space(describe_space(fine)) == fine

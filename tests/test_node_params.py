"""The pick node's parameter file and what it shows beside its answers (markers, tf frames): no ROS
needed; the ROS tests run the nodes from these files."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from binpick.core.errors import InputFileError
from binpick.picking import GraspPlan
from binpick.picking.node_params import NodeParams
from binpick.picking.plans import grasp_orientation
from binpick.picking.scene_messages import camera_frame_pose, grasp_frame_poses, grasp_markers

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_CAMERA = ROOT / "src" / "binpick" / "samples" / "bin_frame" / "camera.yaml"


def test_the_shipped_parameter_files_of_both_nodes_read_the_same():
    ros1 = NodeParams.load(ROOT / "ros" / "binpick" / "config" / "pick_node.yaml")
    ros2 = NodeParams.load(ROOT / "ros" / "ros2" / "pick_node.yaml")  # ROS 2's own layout: node -> ros__parameters
    assert ros1 == ros2
    assert ros1.camera == (ROOT / "src" / "binpick" / "samples" / "bin_frame" / "camera.yaml").resolve() and ros1.camera.is_file()
    assert ros1.topics.depth == "/camera/aligned_depth_to_color/image_raw" and ros1.camera_frame == "binpick_camera_optical_frame"


def test_dotted_ros2_keys_and_relative_paths(tmp_path):
    (tmp_path / "cfg").mkdir()
    path = tmp_path / "cfg" / "params.yaml"
    path.write_text("/**:\n  ros__parameters:\n    camera: ../cam.yaml\n    topics.colour: /rgb\n    gripper: jaws\n")
    params = NodeParams.load(path)
    assert params.camera == (tmp_path / "cam.yaml").resolve() and params.topics.colour == "/rgb" and params.gripper == "jaws"
    assert params.topics.depth == "/camera/aligned_depth_to_color/image_raw"  # the rest keep their defaults


@pytest.mark.parametrize("text, named", [
    ("camera: c.yaml\ncamra_frame: x\n", "'camra_frame'"),
    ("gripper: claw\n", "gripper must be one of jaws, suction, both"),
    ("namespace: 'not a name'\n", "namespace must be a ROS graph name"),
    ("topics: {colour: /rgb, ir: /ir}\n", "unknown topic 'ir'"),
    ("topics: /rgb\n", "topics must be a mapping"),
    ("camera: 3\n", "camera must be a file path"),
    ("- a list\n", "must be a mapping of parameters"),
])
def test_a_bad_parameter_is_one_line_naming_it(tmp_path, text, named):
    path = tmp_path / "params.yaml"
    path.write_text(text)
    with pytest.raises(InputFileError, match="params.yaml") as caught:
        NodeParams.load(path)
    assert named in str(caught.value) and "\n" not in str(caught.value)


def binpick(args: list[str], capsys) -> tuple[int, str, str]:
    """The command line in this process (every case here stops before ROS or a model is loaded)."""
    from binpick.cli import main

    argv, sys.argv = sys.argv, ["binpick", *args]
    try:
        with pytest.raises(SystemExit) as exit_:
            main()
    finally:
        sys.argv = argv
    out, err = capsys.readouterr()
    return exit_.value.code or 0, out, err


def test_the_node_command_reads_its_parameter_file_and_says_what_is_wrong_in_one_line(tmp_path, capsys):
    path = tmp_path / "params.yaml"
    path.write_text(f"camera: {tmp_path / 'missing.yaml'}\n")
    code, _, err = binpick(["ros", "pick-node", "--params", str(path)], capsys)
    assert code == 2 and "missing.yaml" in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1
    path.write_text("topics: {colour: 'bad topic'}\n")
    code, _, err = binpick(["ros", "pick-node", "--params", str(path)], capsys)
    assert code == 2 and "topics.colour must be a ROS graph name" in err, err


def _grasp(x: float, yaw: float, tool: str = "jaws", width: float | None = 0.04, quality: float = 0.9) -> GraspPlan:
    return GraspPlan(box=[0, 0, 10, 10], score=0.8, same_product=None, position=[x, 0.1, 0.05], orientation=grasp_orientation(yaw), yaw=yaw,
                     width=width, quality=quality, tool=tool)


def test_markers_draw_each_grasp_where_it_is():
    grasps = [_grasp(0.1, 0.3), _grasp(-0.1, 0.0, tool="suction", width=None, quality=0.2)]
    markers = grasp_markers(grasps, opening=0.11)
    assert [m.kind for m in markers] == ["arrow", "cube", "cube", "text", "arrow", "cylinder", "text"]
    assert len({m.marker_id for m in markers}) == len(markers)
    arrow, left, right, label = markers[:4]
    # the arrow starts above the grasp and runs (its own x axis) down the approach to the grasp point
    x, y, z, w = arrow.orientation
    shaft = np.array([1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w)])
    np.testing.assert_allclose(np.asarray(arrow.position) + arrow.scale[0] * shaft, grasps[0].position, atol=1e-9)
    assert shaft[2] < -0.99  # straight down: the approach
    # the fingers sit either side of the grasp point along the closing direction (yaw), the object's width apart
    across = np.array([np.cos(0.3), np.sin(0.3), 0.0])
    gap = np.dot(np.asarray(right.position) - np.asarray(left.position), across)
    assert gap == pytest.approx(0.04 + left.scale[0])
    assert "1 jaws 0.90" == label.text and markers[-1].text == "2 suction 0.20"
    assert left.colour[1] > left.colour[0] and markers[5].colour[0] > markers[5].colour[1]  # green holds, red does not


def test_frames_of_the_camera_and_of_each_grasp():
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking straight down
    pose[:3, 3] = [0.1, 0.0, 0.9]
    camera = camera_frame_pose(pose, "world", "camera_color_optical_frame")
    assert camera.parent == "world" and camera.child == "camera_color_optical_frame" and camera.translation == (0.1, 0.0, 0.9)
    assert abs(camera.rotation[0]) == pytest.approx(1.0)  # 180 degrees about x
    frames = grasp_frame_poses([_grasp(0.1, 0.3), _grasp(0.2, 0.0)], "world")
    assert [f.child for f in frames] == ["binpick_grasp_1", "binpick_grasp_2"] and frames[1].translation == (0.2, 0.1, 0.05)


def test_an_option_on_the_command_line_wins_over_the_parameter_file(tmp_path, capsys):
    """What the ROS 2 launch file asks the command for (the camera's static transform), from the file
    alone, then with --camera-frame given: the file's frame, then the command line's."""
    path = tmp_path / "params.yaml"
    path.write_text(f"node:\n  ros__parameters:\n    camera: {SAMPLE_CAMERA}\n    camera_frame: file_frame\n")
    command = ["ros2", "pick-node", "--params", str(path), "--camera-tf"]
    code, printed, err = binpick(command, capsys)
    assert code == 0, err
    flags = printed.split()
    assert flags[flags.index("--child-frame-id") + 1] == "file_frame" and flags[flags.index("--frame-id") + 1] == "world"
    assert float(flags[flags.index("--z") + 1]) == pytest.approx(0.85) and float(flags[flags.index("--qx") + 1]) == pytest.approx(-0.99482437)
    code, printed, err = binpick(command + ["--camera-frame", "cli_frame"], capsys)
    assert code == 0 and printed.split()[-1] == "cli_frame", err
    path.write_text(f"camera: {SAMPLE_CAMERA}\ncamera_frame: world\n")  # the base frame itself: a loop in tf
    code, _, err = binpick(["ros", "pick-node", "--params", str(path)], capsys)
    assert code == 2 and "is the base frame" in err and "Traceback" not in err


def test_a_ros2_file_with_a_wildcard_and_a_node_section_and_dotted_keys_beside_a_mapping(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text("/**:\n  ros__parameters:\n    gripper: jaws\n    topics.depth: /d\n"
                    "binpick_pick_planner:\n  ros__parameters:\n    gripper: suction\n    topics: {colour: /c}\n    topics.info: /i\n")
    params = NodeParams.load(path)
    assert params.gripper == "suction"  # the named node's section wins over the wildcard's
    assert (params.topics.colour, params.topics.depth, params.topics.info) == ("/c", "/d", "/i")
    path.write_text("/**:\n  ros__parameters: {gripper: jaws}\ngripper: both\n")
    with pytest.raises(InputFileError, match="'gripper' is not a node section"):
        NodeParams.load(path)
    path.write_text("topics: /rgb\ntopics.depth: /d\n")
    with pytest.raises(InputFileError, match="topics is given both as a value and as a mapping"):
        NodeParams.load(path)

"""`binpick cell`: the tote found in one depth frame (floor, walls, the rectangle inside them) within
1 cm of the simulator's own, on the sample frame and on three simulated totes (perfect depth; a
realistic sensor with its tilted camera and tote; the shifted set-up's larger tote and other camera)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import yaml

from binpick.core.errors import InputFileError
from binpick.picking.camera_info import CameraInfo
from binpick.picking.frames import read_frame
from binpick.picking.tote import tote_in_frame
from binpick.samples import SAMPLE_FRAME
from binpick.sim.mjcf import BIN_HALF, FLOOR_TOP


def corner_error(tote, half) -> float:
    """The largest distance (m) from a found corner to the nearest corner of the true rectangle (centred at 0)."""
    truth = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * np.array(half)
    return float(max(np.min(np.linalg.norm(truth - corner, axis=1)) for corner in tote.corners()))


def test_the_sample_frame_s_tote_and_the_workspace_written_round_it(tmp_path):
    from binpick.cli import main

    rgb, depth, info = read_frame(SAMPLE_FRAME / "rgb.png", SAMPLE_FRAME / "depth.png", SAMPLE_FRAME / "camera.yaml")
    tote = tote_in_frame(rgb, depth, info)
    assert corner_error(tote, BIN_HALF) < 0.01
    assert abs(tote.floor_z - FLOOR_TOP) < 0.005 and 0.1 < tote.wall_height < 0.16
    for name in ("rgb.png", "depth.png", "camera.yaml"):
        shutil.copy(SAMPLE_FRAME / name, tmp_path / name)
    import sys

    argv, sys.argv = sys.argv, ["binpick", "cell", "--frame", str(tmp_path)]
    try:
        with pytest.raises(SystemExit) as exit_:
            main()
    finally:
        sys.argv = argv
    assert exit_.value.code in (0, None)
    written = yaml.safe_load((tmp_path / "camera.yaml").read_text())
    assert written["workspace"]["min"][:2] == pytest.approx([-0.21, -0.16], abs=0.01)
    assert written["workspace"]["max"][:2] == pytest.approx([0.21, 0.16], abs=0.01)
    assert written["camera_to_base"]["rotation"] == {"x": -0.99482437, "y": -0.00452718, "z": -0.0874863, "w": 0.05147944}
    assert yaml.safe_load((tmp_path / "tote.yaml").read_text())["size"] == pytest.approx([0.42, 0.32], abs=0.01)


@pytest.mark.parametrize("setup", ["perfect", "realistic", "shifted"])
def test_a_simulated_tote_is_found_within_a_centimetre(setup):
    from binpick.grasping import PinholeCamera
    from binpick.sim import default_library
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.domain import load_domain
    from binpick.sim.mjcf import CameraSpec
    from binpick.sim.sensor import load_sensor

    library = default_library(procedural=0, shapes=0)
    options = {"sensor": load_sensor("realistic")} if setup == "realistic" else {}
    if setup == "shifted":
        options = {"domain": load_domain("shifted")}
    world = BinWorld(library["robosuite/can"], [library["robosuite/lemon"], library["robosuite/milk"]], max_copies=3,
                     camera=CameraSpec(size=256), seed=5, **options)
    try:
        scene = world.scene(3, 2, seed=5)
        half = world.half
    finally:
        world.close()
    info = CameraInfo(PinholeCamera.from_record(scene.camera))
    tote = tote_in_frame(scene.rgb, scene.depth, info)
    assert corner_error(tote, half) < 0.01, (tote, half)


def test_a_frame_without_a_tote_is_one_line():
    from binpick.grasping import PinholeCamera

    K = np.array([[120.0, 0.0, 64.0], [0.0, 120.0, 48.0], [0.0, 0.0, 1.0]])
    down = np.diag([1.0, -1.0, -1.0, 1.0])
    down[2, 3] = 0.8
    info = CameraInfo(PinholeCamera(K, 128, 96, down))
    with pytest.raises(InputFileError, match="no tote walls"):  # a bare table: nothing stands out of it
        tote_in_frame(np.zeros((96, 128, 3), np.uint8), np.full((96, 128), 0.8, np.float32), info)

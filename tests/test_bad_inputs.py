"""Every verb given a user's mistake, a damaged file or an unreachable peer: exit code 2, one line on
stderr naming what is wrong, no traceback, no hang.

The cases run the real console entry point (``binpick.cli.main``) in this process, so ~90 cases cost
seconds; the ones that wait on a network peer run in a child process with a hard timeout instead.
Placeholders in braces are paths in a folder of prepared good and bad inputs (see ``world``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import cli_zygote
import yaml
from PIL import Image

from binpick.cli import main
from binpick.integrations.ros1.master import free_port

TINY_RL = {"name": "tiny", "env": "FetchReach", "total_timesteps": 200, "checkpoint_every": 100,
           "replay": {"capacity_episodes": 100, "her_additions": 1, "start_fraction": 0.01},
           "sac": {"batch_size": 16, "net_arch": [8, 8]}, "eval": {"every": 100, "episodes": 1}}


def _coco(images: list[dict], annotations: list[dict]) -> dict:
    return {"images": images, "annotations": annotations, "categories": [{"id": 1, "name": "thing", "supercategory": "t"}]}


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict[str, str]:
    """Good and bad inputs, made once: their paths by name."""
    root = tmp_path_factory.mktemp("bad_inputs")
    paths: dict[str, Path] = {"root": root}

    def put(name: str, content: bytes | str) -> Path:
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
        paths[name.replace("/", "_").replace(".", "_")] = path
        return path

    put("plain.txt", "just a file\n")
    put("ur5e_cell.yaml", "gripper: {tools: jaws, tcp: 0.17}\narm: {model: ur5e}\n")
    (root / "adir.png").mkdir()
    (root / "adir.json").mkdir()
    image = root / "scene.png"
    Image.fromarray(np.full((64, 64, 3), 120, np.uint8)).save(image)
    paths["scene_png"] = image
    from synthetic_coco import make_coco

    paths["toy_coco"] = make_coco(root / "toy", images=4, size=64)  # enough boxes to fit anchors
    put("fake.png", "not an image")
    put("latin1.yaml", b"name: caf\xe9\n")
    put("latin1.json", b'{"images": "caf\xe9"}')
    put("notmapping.yaml", "- a\n- b\n")
    put("rl.yaml", yaml.safe_dump(TINY_RL))
    put("grasp.yaml", yaml.safe_dump({"data": str(root), "epochs": 0}))
    put("pickability.yaml", yaml.safe_dump({"train": [str(root / "missing.json")], "val": str(root / "missing.json"), "targets": "all"}))
    put("random.safetensors", os.urandom(256))

    # COCO files: one good, the rest damaged in one field each
    good_image = {"id": 1, "file_name": "scene.png", "width": 64, "height": 64}
    box = {"id": 1, "image_id": 1, "category_id": 1, "bbox": [4, 4, 10, 10], "area": 100, "iscrowd": 0}
    two = [box, box | {"id": 2, "bbox": [30, 30, 10, 10]}]
    put("good.json", json.dumps(_coco([good_image], two)))
    put("coco_no_bbox.json", json.dumps(_coco([good_image], [{k: v for k, v in box.items() if k != "bbox"}, two[1]])))
    put("coco_nan_bbox.json", json.dumps(_coco([good_image], [box | {"bbox": [float("nan"), 4, 10, 10]}, two[1]])))
    put("coco_string_category.json", json.dumps(_coco([good_image], [box | {"category_id": "1"}, two[1]])))
    put("coco_string_bbox.json", json.dumps(_coco([good_image], [box | {"bbox": ["4", "4", "10", "10"]}, two[1]])))
    put("coco_no_file_name.json", json.dumps(_coco([{"id": 1}], two)))
    put("coco_missing_images.json", json.dumps(_coco([good_image | {"file_name": "gone.png"}], two)))
    put("coco_zero_box.json", json.dumps(_coco([good_image], [box | {"bbox": [4, 4, 0, 10]}, two[1]])))

    # detector weights: a good tiny one and damaged ones
    from binpick.core import tensorfile
    from binpick.detection.model import DetectorNetwork, ModelSpec
    from binpick.detection.weights_file import FORMAT, save_detector

    weights = root / "detector.safetensors"
    save_detector(DetectorNetwork(ModelSpec(), 64), weights)
    paths["weights"] = weights
    tensorfile.save(root / "nospec.safetensors", FORMAT, tensors={}, meta={"image_size": 64})
    paths["nospec"] = root / "nospec.safetensors"
    tensorfile.save(root / "other_format.safetensors", "binpick-perception-1", tensors={}, meta={})
    paths["other_format"] = root / "other_format.safetensors"
    (root / "empty_run").mkdir()
    paths["empty_run"] = root / "empty_run"

    # run folders with damaged checkpoints
    def run_folder(name: str, config: dict, latest: str | None, files: dict[str, bytes | str] | None = None) -> Path:
        run = root / name
        (run / "checkpoints").mkdir(parents=True)
        (run / "config.yaml").write_text(yaml.safe_dump(config))
        if latest is not None:
            (run / "checkpoints" / "latest").write_text(latest)
        for file, content in (files or {}).items():
            target = run / "checkpoints" / file
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(content if isinstance(content, bytes) else content.encode())
        paths[name] = run
        return run

    run_folder("rl_dangling", TINY_RL, "ckpt-000000100")
    run_folder("rl_escape", TINY_RL, "../../../etc")
    run_folder("rl_bad_policy", TINY_RL, "ckpt-000000100", {"ckpt-000000100/policy.safetensors": b"\x00" * 64})
    run_folder("rl_wrong_format", TINY_RL, "ckpt-000000100", {})
    import shutil

    (root / "rl_wrong_format" / "checkpoints" / "ckpt-000000100").mkdir()
    shutil.copy(weights, root / "rl_wrong_format" / "checkpoints" / "ckpt-000000100" / "policy.safetensors")
    run_folder("rl_state_not_json", TINY_RL, "ckpt-000000100",
               {"ckpt-000000100/state.json": "{not json", "ckpt-000000100/algorithm.safetensors": b""})
    run_folder("rl_bad_config", TINY_RL, None)
    (root / "rl_bad_config" / "config.yaml").write_text("- just\n- a list\n")
    a3c = {"name": "a3c", "env": "Arm2D", "algorithm": "a3c", "total_timesteps": 100}
    run_folder("a3c_no_checkpoint", a3c, None)
    detect_config = {"name": "tiny_detect", "data": {"train": str(paths["toy_coco"]), "val": str(paths["toy_coco"]),
                                                     "image_size": 64, "targets": "all"}, "train": {"epochs": 1, "batch_size": 2}}
    put("detect.yaml", yaml.safe_dump(detect_config))
    run_folder("detect_dangling", detect_config, "ckpt-000000001")
    run_folder("detect_bad_state", detect_config, "ckpt-000000001", {"ckpt-000000001/state.safetensors": b""})
    tensorfile.save(root / "detect_bad_state" / "checkpoints" / "ckpt-000000001" / "state.safetensors",
                    "binpick-detector-checkpoint-1", state={"model": {}, "optimizer": {}}, meta={"epoch": 1, "step": 2})

    # APRiL run folders
    april = {"name": "a", "env": "FetchReach", "image": "grey", "policy": {"mode": "semantic", "rl_config": str(paths["rl_yaml"])}}
    for name, stages in (("april_bad_stages", "{broken"), ("april_unknown_stage", '{"bake": {}}'),
                         ("april_no_policy", '{"collect": {"sim_episodes": 1}}')):
        folder = root / name
        folder.mkdir()
        (folder / "config.yaml").write_text(yaml.safe_dump(april))
        (folder / "stages.json").write_text(stages)
        paths[name] = folder

    # warehouse data sets: a manifest, and scenes damaged in different ways
    data = root / "bins"
    for sub in ("scenes", "images"):
        (data / sub).mkdir(parents=True)
    manifest = {"format": "binpick-bins-1", "config": {"policies": ["y"], "scenes": 3}, "products": [{"id": "p", "category": "c"}]}
    (data / "dataset.json").write_text(json.dumps(manifest))
    record = {"index": 0, "file_name": "images/000000.png", "depth_file": "depth/000000.png", "width": 64, "height": 64,
              "split": "train", "target": "p", "seed": 0, "picked_by": None,
              "annotations": [{"slot": 0, "product": "p", "is_target": True, "is_query": True, "bbox": [1, 1, 5, 5],
                               "area": 25, "visible_fraction": 1.0, "pickable": {"y": True}}]}
    (data / "scenes" / "000000.json").write_text(json.dumps(record)[:40])
    (data / "scenes" / "000001.json").write_text(json.dumps({k: v for k, v in record.items() if k != "annotations"}))
    (data / "scenes" / "000002.json").write_text(json.dumps(record | {"index": 2, "file_name": "images/000002.png"}))
    (data / "images" / "000002.png").write_text("not a png")
    paths["bins"] = data
    bad_manifest = root / "bins_bad_manifest"
    bad_manifest.mkdir()
    (bad_manifest / "dataset.json").write_text(json.dumps({"format": "binpick-bins-1"}))
    paths["bins_bad_manifest"] = bad_manifest
    not_utf8 = root / "bins_latin1"
    not_utf8.mkdir()
    (not_utf8 / "dataset.json").write_bytes(b'{"format": "caf\xe9"}')
    paths["bins_latin1"] = not_utf8

    # a data set that already holds more scenes than asked for (as `data generate` would have left it)
    from binpick.warehouse.generation import GenerateConfig

    full = root / "bins_24"
    (full / "scenes").mkdir(parents=True)
    settings = GenerateConfig(out=str(full), scenes=24, workers=1, image_size=64)
    (full / "dataset.json").write_text(json.dumps({"format": "binpick-bins-1", "config": settings.comparable(),
                                                   "products": [{"id": "p", "category": "c"}]}))
    for index in range(24):
        (full / "scenes" / f"{index:06d}.json").write_text(json.dumps(record | {"index": index}))
    paths["bins_24"] = full

    # one RGB-D frame from a "real" camera (binpick plan): 64x64 colour = scene.png
    def depth_png(name: str, array: np.ndarray) -> None:
        Image.fromarray(array.astype(np.uint16)).save(root / name)
        paths[name.replace(".", "_")] = root / name

    depth_png("depth_mm.png", np.full((64, 64), 800))
    depth_png("depth_small.png", np.full((24, 32), 800))  # another aspect than the colour's: not registered to it
    depth_png("depth_zero.png", np.zeros((64, 64)))
    np.save(root / "depth_in_mm.npy", np.full((64, 64), 800.0, np.float32))  # millimetres given as metres
    paths["depth_in_mm_npy"] = root / "depth_in_mm.npy"
    unposed = {"image_width": 64, "image_height": 64, "camera_matrix": {"rows": 3, "cols": 3, "data": [60, 0, 32, 0, 60, 32, 0, 0, 1]}}
    down = {"translation": [0, 0, 0.8], "rotation": {"x": 1, "y": 0, "z": 0, "w": 0}}  # 80 cm above the table, looking down
    camera = unposed | {"camera_to_base": down}
    put("camera.yaml", yaml.safe_dump(camera))
    put("camera_no_pose.yaml", yaml.safe_dump(unposed))
    put("camera_looking_up.yaml", yaml.safe_dump(unposed | {"camera_to_base": {"translation": [0, 0, 0.8], "rotation": [0, 0, 0, 1]}}))
    # a camera tilted 20 degrees from straight down (about its x axis) over a level floor, its quaternion
    # then written w, x, y, z: read as x, y, z, w the floor comes out steep
    tilted = [float(np.sin(np.radians(100.0))), 0.0, 0.0, float(np.cos(np.radians(100.0)))]  # x, y, z, w
    angle = np.radians(200.0)
    rotation = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)], [0, np.sin(angle), np.cos(angle)]])
    v, u = np.mgrid[0:64, 0:64]
    rays = np.stack([(u - 32) / 60, (v - 32) / 60, np.ones((64, 64))], axis=-1) @ rotation.T
    depth_png("depth_tilted.png", np.clip(1000 * 0.8 / -rays[..., 2], 0, 5000))  # mm along the optical axis
    put("camera_w_first.yaml", yaml.safe_dump(unposed | {"camera_to_base": {"translation": [0, 0, 0.8], "rotation": [tilted[3], *tilted[:3]]}}))
    put("camera_rotation_unnamed.yaml", yaml.safe_dump(unposed | {"camera_to_base": {"translation": [0, 0, 0.8], "rotation": {"a": 1, "b": 0, "c": 0, "d": 0}}}))
    put("camera_no_k.yaml", yaml.safe_dump({"image_width": 64, "image_height": 64}))
    put("camera_640.yaml", yaml.safe_dump(camera | {"image_width": 640, "image_height": 480}))
    put("camera_bad_rotation.yaml", yaml.safe_dump(unposed | {"camera_to_base": {"translation": [0, 0, 1], "rotation": [0, 0, 0, 0]}}))

    # products files
    put("products_bad_number.yaml", "products:\n  - {id: a/b, category: c, mesh: box.obj, longest_side: abc}\n")
    (root / "box.obj").write_text("v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    put("products_no_mesh.yaml", "products:\n  - {id: a/b, category: c, mesh: missing.obj}\n")
    return {key: str(value) for key, value in paths.items()}


# (arguments, fragments the one line must hold); "{name}" is a path from ``world``
CASES: list[tuple[list[str], list[str]]] = [
    # usage errors: Click's, printed as one line
    (["envs", "list", "--bogus"], ["No such option: --bogus"]),
    (["cell", "--frame", "{root}"], ["has no rgb.png, depth.png", "binpick data export"]),
    (["cell", "--frame", "{root}", "--wall-above", "5"], ["--wall-above", "5"]),
    (["calibrate", "{root}", "--camera", "{camera_yaml}"], ["has no poses.yaml"]),
    (["calibrate", "{root}/nowhere", "--camera", "{camera_yaml}"], ["is not a folder of board pictures"]),
    (["calibrate", "{root}", "--camera", "{camera_yaml}", "--flange-mm", "-1"], ["--flange-mm", "-1"]),
    (["plan", "--sample", "--cell", "{root}/no_cell.yaml", "--out", "{root}/plans"], ["no_cell.yaml"]),
    (["plan", "--sample", "--cell", "{ur5e_cell_yaml}", "--robot", "panda", "--out", "{root}/plans"],
     ["cell 'ur5e_cell' has a ur5e arm; robot panda asks for another"]),
    (["data", "generate", "--out", "{root}/gen", "--cell", "{root}/no_cell.yaml"], ["no_cell.yaml"]),
    (["plan", "--sample", "--flange-pose", "1,2,3", "--out", "{root}/plans"], ["--flange-pose", "x,y,z,qx,qy,qz,qw"]),
    (["products", "list", "--products", "{latin1_yaml}"], ["latin1.yaml", "not UTF-8"]),
    (["products", "list", "--products", "{products_no_mesh_yaml}"], ["missing.obj", "does not exist"]),
    (["pick", "--product", "sofa", "--out", "{root}/picks"], ["unknown product or category 'sofa'"]),
    (["pick", "--product", "box_0", "--out", "{root}/picks"], ["'box_0'", "did you mean", "procedural/box_00"]),
    (["envs", "show", "Arm2D", "--seed", "-1"], ["--seed", "greater than or equal to 0", "binpick envs show --help"]),
    (["envs", "rollout", "Arm2D", "--seed", "-5"], ["--seed", "greater than or equal to 0"]),
    (["envs", "rollout", "Arm2D", "--episodes", "abc"], ["--episodes", "integer"]),
    (["rl", "eval", "{rl_dangling}", "--seed", "-1"], ["--seed"]),
    (["rl", "train", "{rl_yaml}", "--seed", "-1"], ["--seed"]),
    (["rl", "distributed", "--seed", "-1"], ["--seed"]),
    (["april", "eval", "{april_no_policy}", "--seed", "-2"], ["--seed"]),
    (["data", "generate", "--out", "{root}/new", "--seed", "-1"], ["--seed"]),
    (["pick", "--product", "robosuite/milk", "--seed", "-1"], ["--seed"]),
    (["demo", "--seed", "-1"], ["--seed"]),
    (["envs", "show", "Arm2D", "--seed", "99999999999"], ["--seed"]),
    (["ros", "master", "--port", "70000"], ["--port", "less than or equal to 65535"]),
    (["rl", "eval"], ["Missing argument"]),
    (["envs", "show", "Arm2D", "--bogus"], ["No such option: --bogus"]),
    (["detect", "eval", "{weights}"], ["Missing option", "--data"]),
    # numbers out of range, bad values
    (["detect", "predict", "{scene_png}", "--weights", "{weights}", "--query-box", "4,4,10,10", "--min-score", "nan"],
     ["--min-score", "finite"]),
    (["detect", "predict", "{scene_png}", "--weights", "{weights}", "--query-box", "4,4,10,10", "--min-score", "-1"],
     ["--min-score", "[0.0, 1.0]"]),
    (["detect", "predict", "{scene_png}", "--weights", "{weights}", "--query-box", "4,4,10,10", "--min-score", "5"],
     ["--min-score", "[0.0, 1.0]"]),
    (["detect", "predict", "{scene_png}", "--weights", "{weights}", "--query-box", "4,4,10"], ["--query-box must be x,y,w,h"]),
    (["rl", "train", "{rl_yaml}", "--steps", "-1", "--runs", "{root}/runs_steps"], ["total_timesteps", "-1"]),
    (["rl", "train", "{rl_yaml}", "--steps", "0", "--runs", "{root}/runs_steps"], ["total_timesteps", "0"]),
    (["rl", "train", "{rl_yaml}", "--init-from", "{a3c_no_checkpoint}", "--runs", "{root}/runs_steps"],
     ["init_from", "sac"]),
    (["envs", "rollout", "Arm2D", "--set", "goal_area=abc"], ["goal_area", "number", "'abc'"]),
    (["envs", "rollout", "Arm2D", "--set", "goal_area=.nan"], ["goal_area", "finite"]),
    (["envs", "rollout", "Arm2D", "--set", "fixed_goal=5"], ["fixed_goal must be a list of 2 numbers"]),
    (["envs", "rollout", "Arm2D", "--set", "link_lengths=[0.3, x, 0.2]"], ["link_lengths[1]", "number"]),
    (["envs", "rollout", "Arm2D", "--set", "goal_conditioned=maybe"], ["goal_conditioned must be true or false"]),
    (["envs", "show", "FetchReach", "--set", "render_mode=human"], ["--set render_mode", "--size"]),
    (["rl", "distributed", "--algorithm", "a3c", "--env", "FetchReach"], ["a3c", "discrete actions", "Arm2D"]),
    (["envs", "rollout", "Arm2D", "--episodes", "0"], ["episodes", ">= 1"]),
    (["envs", "tour", "--episodes", "0", "--out", "{root}/tour"], ["episodes", "[1, 10000]"]),
    (["rl", "eval", "{rl_dangling}", "--episodes", "0"], ["episodes"]),
    (["pick", "--product", ",", "--out", "{root}/picks"], ["--product", "names no product"]),
    (["pick", "--product", "robosuite/milk", "--grasp", "sideways", "--out", "{root}/picks"],
     ["unknown grasp policy 'sideways'", "fixed, analytic, learnt"]),
    (["pick", "--product", "robosuite/milk", "--grasp", "analytic", "--grasp-weights", "{root}/q.safetensors", "--out", "{root}/picks"],
     ["grasp weights are for the learnt policy"]),
    (["pick", "--product", "robosuite/milk", "--grasp-weights", "{root}/missing.safetensors", "--out", "{root}/picks"],
     ["missing.safetensors", "does not exist"]),
    (["data", "generate", "--out", "{root}/gen", "--grasp-trials", "-1"], ["grasp_trials"]),
    (["data", "generate", "--out", "{root}/gen", "--set", "label_trials=0"], ["label_trials must be in [1, 25]"]),
    (["data", "generate", "--out", "{root}/gen", "--policies", "y,sideways"], ["unknown grasp policy 'sideways'", "analytic"]),
    (["grasp", "train", "--resume", "{root}"], ["is not a run folder"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_yaml}"], ["exactly one of --photo", "--query-box"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_small_png}", "--camera", "{camera_yaml}", "--photo", "{scene_png}"],
     ["depth is 32x24 but colour is 64x64", "register depth to the colour camera"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_yaml}", "--query-box", "10,10,20,20"],
     ["query box 10,10,20,20 lies on no object", "only the surface"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_yaml}", "--photo", "{scene_png}", "--copies-only"],
     ["--copies-only goes with --query-box"]),
    (["data", "generate", "--out", "{root}/gen", "--sensor", "lidar"], ["sensor 'lidar'", "perfect, realistic"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_zero_png}", "--camera", "{camera_yaml}", "--photo", "{scene_png}"],
     ["depth_zero.png", "no valid reading"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_in_mm_npy}", "--camera", "{camera_yaml}", "--photo", "{scene_png}"],
     ["reads 800 m", "metres in .npy"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_no_k_yaml}", "--photo", "{scene_png}"],
     ["camera_no_k.yaml", "has no camera_matrix"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_640_yaml}", "--photo", "{scene_png}"],
     ["calibration is for 640x480 images", "64x64"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_bad_rotation_yaml}", "--photo", "{scene_png}"],
     ["camera_to_base.rotation", "non-zero quaternion"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_no_pose_yaml}", "--photo", "{scene_png}"],
     ["camera_no_pose.yaml", "has no camera_to_base"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_looking_up_yaml}", "--photo", "{scene_png}"],
     ["optical axis up"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_tilted_png}", "--camera", "{camera_w_first_yaml}", "--photo", "{scene_png}"],
     ["degrees from level", "x, y, z, w"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_rotation_unnamed_yaml}", "--photo", "{scene_png}"],
     ["camera_to_base.rotation must name x, y, z and w"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_yaml}", "--query-box", "50,50,30,30"],
     ["--query-box", "outside the 64x64"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_yaml}", "--photo", "{scene_png}", "--product-size", "0.1,0.2"],
     ["--product-size must be three lengths in metres"]),
    (["plan", "--rgb", "{scene_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_yaml}", "--photo", "{scene_png}", "--out", "{plain_txt}"],
     ["--out", "plain.txt", "a file with that name exists"]),
    (["plan", "--rgb", "{fake_png}", "--depth", "{depth_mm_png}", "--camera", "{camera_yaml}", "--photo", "{scene_png}"],
     ["colour image", "fake.png"]),
    (["ros", "pick-node", "--colour-topic", "camera colour"], ["--colour-topic must be a ROS graph name"]),
    (["ros", "pick-node", "--camera", "{camera_no_k_yaml}", "--master", "http://127.0.0.1:0/"], ["camera_no_k.yaml", "has no camera_matrix"]),
    (["ros", "pick-node", "--master", "http://127.0.0.1:0/"], ["a pick node needs --camera camera.yaml with camera_to_base"]),
    (["ros2", "pick-node"], ["ROS 2 is not importable here", ".venv-ros2/bin/binpick"]),
    (["data", "export", "{root}", "--out", "{root}/export"], ["is not a binpick data set"]),
    (["data", "export", "{bins_24}", "--scene", "99", "--out", "{root}/export"], ["scene 99 is not in"]),
    (["grasp", "train", "{root}/missing.yaml"], ["missing.yaml"]),
    (["detect", "pickability", "{pickability_yaml}"], ["targets must be pickable"]),
    (["detect", "pickability", "{pickability_yaml}", "--set", "targets=pickable:y"], ["missing.json", "does not exist"]),
    (["detect", "pickability", "--resume", "{root}"], ["is not a run folder"]),
    (["grasp", "train", "{grasp_yaml}"], ["epochs must be in"]),
    (["grasp", "train", "{grasp_yaml}", "--set", "epochs=3"], ["is not a data set folder"]),
    (["data", "generate", "--out", "{root}/gen", "--copies", "5,2"], ["copies"]),
    (["data", "generate", "--out", "{root}/gen", "--copies", "a,b"], ["--copies", "LOW,HIGH"]),
    (["rl", "distributed", "--steps", "0", "--out", "{root}/dist"], ["total_timesteps", "0"]),
    (["rl", "distributed", "--workers", "0", "--out", "{root}/dist"], ["workers", "0"]),
    (["rl", "distributed", "--algorithm", "ppo"], ["algorithm", "'sac'", "'a3c'"]),
    (["rl", "distributed", "--address", "notanaddress"], ["--address", "HOST:PORT", "notanaddress"]),
    (["rl", "distributed", "--address", "127.0.0.1:99999"], ["--address", "127.0.0.1:99999"]),
    (["ros", "bench", "--master", "notauri", "--timeout", "1"], ["ROS master URI", "notauri"]),
    (["ros", "bench", "--master", "http://127.0.0.1:11311/", "--timeout", "0"], ["--timeout"]),
    (["ros", "serve", "Arm2D", "--master", "http://127.0.0.1:99999/"], ["ROS master URI", "99999"]),
    (["ros", "serve", "Arm2D", "--namespace", "bad name!", "--master", "http://127.0.0.1:1/"], ["--namespace"]),
    (["detect", "export", "rod_tiny_320", "--out", "{root}/exported"], ["photo-query ROD detectors"]),
    (["detect", "export", "rod_photo_tiny", "--out", "{root}/exported"], ["did you mean 'rod_photo_tiny_320'"]),
    (["detect", "export", "rod_photo_tiny_320", "--format", "openvino"], ["format must be one of 'onnx'"]),
    (["checks", "--bogus"], ["No such option: --bogus"]),
    (["plan", "--sample", "--out", "{root}/plan.json"], ["--out is a folder", "plan.json"]),
    (["envs", "show", "Arm2D", "--out", "{root}/frame.png"], ["--out is a folder", "frame.png"]),
    (["plan", "--sample", "--runtime", "tensorrt", "--out", "{root}/never"], ["--runtime must be one of 'torch', 'onnx'"]),
    # markup characters in what the user typed are printed as typed
    (["envs", "show", "x[/]y"], ["unknown env id 'x[/]y'"]),
    (["rl", "train", "{root}/cfg[/bold].yaml"], ["cfg[/bold].yaml", "does not exist"]),
    (["envs", "show", "Arm2D", "--out", "{plain_txt}/[red]x"], ["--out", "plain.txt/[red]x"]),
    (["detect", "predict", "{root}/[/]missing.png", "--weights", "{weights}", "--query-box", "1,1,5,5"],
     ["[/]missing.png"]),
    # outputs that cannot be written: checked before the work starts
    (["envs", "show", "Arm2D", "--out", "{plain_txt}"], ["--out", "plain.txt", "a file with that name exists"]),
    (["envs", "rollout", "Arm2D", "--episodes", "1", "--out", "{plain_txt}"], ["--out", "plain.txt"]),
    (["envs", "tour", "--out", "{plain_txt}"], ["--out", "plain.txt"]),
    (["detect", "eval", "{weights}", "--data", "{good_json}", "--out", "{plain_txt}"], ["--out", "plain.txt"]),
    (["rl", "train", "{rl_yaml}", "--runs", "{plain_txt}"], ["plain.txt"]),
    (["detect", "train", "{detect_yaml}", "--runs", "{plain_txt}"], ["plain.txt"]),
    (["train", "{detect_yaml}"], ["detect.yaml", "no 'task:' key"]),
    (["train", "{detect_yaml}", "--set", "task=detct"], ["task 'detct'", "did you mean 'detect'"]),
    (["train", "{detect_yaml}", "--set", "task=detect", "--set", "model.layout=RXR"], ["model.layout", "RXR"]),
    (["train", "--resume", "{plain_txt}"], ["plain.txt", "not a run folder"]),
    (["train"], ["give either a CONFIG"]),
    (["detect", "train", "{detect_yaml}", "--set", "model.layout=RXR"], ["model.layout", "RXR"]),
    (["detect", "train", "--resume", "{detect_dangling}", "--set", "train.epochs=3"], ["--set", "resumed run keeps"]),
    (["pick", "--product", "robosuite/milk", "--out", "{plain_txt}"], ["--out", "plain.txt"]),
    (["demo", "--out", "{plain_txt}"], ["--out", "plain.txt"]),
    (["data", "generate", "--out", "{plain_txt}"], ["--out", "plain.txt", "is a file"]),
    (["rl", "distributed", "--out", "{plain_txt}"], ["--out", "plain.txt"]),
    (["data", "show", "{bins}", "--scene", "2", "--out", "{plain_txt}/x"], ["--out", "plain.txt"]),
    (["detect", "predict", "{scene_png}", "--weights", "{weights}", "--query-box", "4,4,10,10",
      "--heatmap", "--out", "{plain_txt}/h"], ["--out", "plain.txt"]),
    # files that cannot be decoded
    (["rl", "train", "{latin1_yaml}"], ["latin1.yaml", "not UTF-8"]),
    (["detect", "train", "{latin1_yaml}"], ["latin1.yaml", "not UTF-8"]),
    (["april", "run", "{latin1_yaml}"], ["latin1.yaml", "not UTF-8"]),
    (["detect", "eval", "{weights}", "--data", "{latin1_json}"], ["latin1.json", "not UTF-8"]),
    (["data", "generate", "--out", "{root}/gen", "--products", "{latin1_yaml}"], ["latin1.yaml", "not UTF-8"]),
    (["data", "stats", "{bins_latin1}"], ["dataset.json", "not UTF-8"]),
    (["rl", "train", "{root}"], ["is a folder"]),
    (["rl", "train", "{notmapping_yaml}"], ["notmapping.yaml", "mapping"]),
    (["detect", "predict", "{fake_png}", "--weights", "{weights}", "--query-box", "1,1,5,5"], ["cannot read image", "fake.png"]),
    # damaged data sets
    (["detect", "eval", "{weights}", "--data", "{coco_no_bbox_json}"], ["annotations[0].bbox"]),
    (["detect", "eval", "{weights}", "--data", "{coco_nan_bbox_json}"], ["annotations[0].bbox", "finite"]),
    (["detect", "eval", "{weights}", "--data", "{coco_string_category_json}"], ["annotations[0].category_id", "integer"]),
    (["detect", "eval", "{weights}", "--data", "{coco_string_bbox_json}"], ["annotations[0].bbox"]),
    (["detect", "eval", "{weights}", "--data", "{coco_no_file_name_json}"], ["images[0]", "file_name"]),
    (["detect", "eval", "{weights}", "--data", "{coco_missing_images_json}"], ["gone.png", "do not exist"]),
    (["detect", "eval", "{weights}", "--data", "{coco_zero_box_json}"], ["annotations[0].bbox", "> 0"]),
    (["data", "show", "{bins}", "--scene", "0", "--out", "{root}/s"], ["000000.json", "not valid JSON"]),
    (["data", "show", "{bins}", "--scene", "1", "--out", "{root}/s"], ["000001.json", "damaged", "annotations"]),
    (["data", "show", "{bins}", "--scene", "2", "--out", "{root}/s"], ["cannot read scene image", "000002.png"]),
    (["data", "show", "{bins}", "--scene", "7", "--out", "{root}/s"], ["scene 7 is not in"]),
    (["data", "stats", "{bins_bad_manifest}"], ["dataset.json", "damaged", "config"]),
    (["data", "stats", "{plain_txt}"], ["not a binpick data set"]),
    (["data", "generate", "--out", "{bins_24}", "--scenes", "16", "--workers", "1", "--size", "64"],
     ["already holds 24 scenes", "--scenes 16"]),
    (["data", "generate", "--out", "{root}/gen", "--products", "{products_bad_number_yaml}"], ["longest_side", "'abc'"]),
    (["data", "generate", "--out", "{root}/gen", "--products", "{products_no_mesh_yaml}"], ["missing.obj", "does not exist"]),
    # damaged weights and checkpoints
    (["detect", "predict", "{scene_png}", "--weights", "{random_safetensors}", "--query-box", "1,1,5,5"],
     ["random.safetensors", "not a safetensors file"]),
    (["detect", "predict", "{scene_png}", "--weights", "{nospec}", "--query-box", "1,1,5,5"], ["nospec.safetensors", "damaged", "spec"]),
    (["detect", "predict", "{scene_png}", "--weights", "{other_format}", "--query-box", "1,1,5,5"],
     ["binpick-perception-1", "expected 'binpick-detector-2'"]),
    (["detect", "eval", "{empty_run}", "--data", "{good_json}"], ["no detector weights", "empty_run"]),
    (["pick", "--product", "robosuite/milk", "--weights", "{plain_txt}", "--out", "{root}/picks"], ["plain.txt"]),
    (["detect", "train", "--resume", "{detect_dangling}"], ["latest", "ckpt-000000001", "does not exist"]),
    (["detect", "train", "--resume", "{detect_bad_state}"], ["state.safetensors", "damaged", "history"]),
    (["rl", "eval", "{rl_dangling}"], ["latest", "ckpt-000000100", "does not exist"]),
    (["rl", "eval", "{rl_escape}"], ["latest", "damaged", "../../../etc"]),
    (["rl", "eval", "{rl_bad_policy}"], ["policy.safetensors", "not a safetensors file"]),
    (["rl", "eval", "{rl_wrong_format}"], ["'binpick-detector-2' file", "expected 'binpick-sb3-policy-1'"]),
    (["rl", "eval", "{rl_bad_config}"], ["config.yaml", "mapping"]),
    (["rl", "train", "--resume", "{rl_state_not_json}"], ["state.json", "not valid JSON"]),
    (["rl", "train", "--resume", "{rl_dangling}"], ["latest", "does not exist"]),
    (["april", "eval", "{april_bad_stages}"], ["stages.json", "not valid JSON"]),
    (["april", "eval", "{april_unknown_stage}"], ["stages.json", "damaged", "bake"]),
    (["april", "eval", "{april_no_policy}"], ["no trained policy yet"]),
    (["april", "run", "--resume", "{april_bad_stages}"], ["stages.json", "not valid JSON"]),
]


def _ids() -> list[str]:
    return [f"{i:02d}-" + "-".join(a.strip("{}").replace("/", "_")[:14] for a in args[:3]) for i, (args, _) in enumerate(CASES)]


@pytest.mark.timeout(60)  # a case that hangs fails here instead of blocking the suite
@pytest.mark.parametrize("args,fragments", CASES, ids=_ids())
def test_bad_input_is_one_line_and_exit_code_2(args, fragments, world, capsys, monkeypatch):
    monkeypatch.chdir(world["root"])  # nothing a case writes lands in the repository
    monkeypatch.setattr(sys, "argv", ["binpick", *[a.format(**world) for a in args]])
    with pytest.raises(SystemExit) as exit_info:
        main()
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    lines = [line for line in err.splitlines() if line.strip()]
    assert exit_info.value.code == 2 and len(lines) == 1, (exit_info.value.code, err)
    assert lines[0].startswith("error: ")
    for fragment in fragments:
        assert fragment.format(**world) in lines[0], lines[0]


def test_the_suite_covers_every_verb_and_enough_cases():
    from binpick.cli import app

    verbs = {" ".join(args[:2]) if args[0] in ("envs", "rl", "april", "data", "detect", "grasp", "ros", "ros2", "products") else args[0] for args, _ in CASES}
    groups = {group.name: group.typer_instance for group in app.registered_groups}
    every = {f"{name} {command.name or command.callback.__name__}" for name, group in groups.items()
             for command in group.registered_commands} | {command.name for command in app.registered_commands}
    assert every <= verbs, sorted(every - verbs)
    assert len(CASES) >= 60


def _free_uri() -> str:
    return f"http://127.0.0.1:{free_port()}/"


@pytest.mark.parametrize("args", [
    ["ros", "serve", "FetchReach", "--master", "{uri}", "--timeout", "2"],
    ["ros", "bench", "--master", "{uri}", "--timeout", "2", "--episodes", "1"],
], ids=["serve", "bench"])
def test_an_absent_ros_master_is_one_line_within_the_timeout(args, tmp_path):
    from binpick.integrations.ros1 import ros_missing

    if ros_missing():
        pytest.skip(ros_missing())
    uri = _free_uri()
    started = time.monotonic()
    result = cli_zygote.run([*[a.format(uri=uri) for a in args]],
                            capture_output=True, text=True, timeout=60, cwd=tmp_path,
                            env={**os.environ, "ROS_HOME": str(tmp_path), "ROS_LOG_DIR": str(tmp_path)})
    assert time.monotonic() - started < 30, "must give up near --timeout, not hang"
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.strip().count("\n") == 0 and f"no ROS master answered at {uri} within 2 s" in result.stderr


def test_ros_client_env_gives_up_on_an_absent_master(tmp_path):
    from binpick.integrations.ros1 import ros_missing

    if ros_missing():
        pytest.skip(ros_missing())
    uri = _free_uri()
    code = ("import gymnasium, binpick\n"
            "from binpick.core.errors import BinpickError\n"
            "try:\n    gymnasium.make('binpick/Ros-v0', namespace='/x', timeout=1.5)\n"
            "except BinpickError as e:\n    print('refused:', e)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                            env={**os.environ, "ROS_MASTER_URI": uri, "ROS_HOME": str(tmp_path), "ROS_LOG_DIR": str(tmp_path)})
    assert f"refused: no ROS master answered at {uri}" in result.stdout, result.stderr[-500:]


def test_ros_master_stops_its_child_on_sigterm(tmp_path):
    import signal
    import socket

    from binpick.integrations.ros1 import ros_missing

    if ros_missing():
        pytest.skip(ros_missing())
    port = free_port()
    process = cli_zygote.popen(["ros", "master", "--port", str(port)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            with socket.socket() as probe:
                if probe.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.1)
        else:
            pytest.fail("the master never listened")
        process.send_signal(signal.SIGTERM)  # often while the command still waits for rosmaster to answer
        _, stderr = process.communicate(timeout=20)
        assert process.returncode == 0, stderr[-500:]
    finally:
        if process.poll() is None:
            process.kill()
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) != 0:
                return
        time.sleep(0.1)
    pytest.fail(f"something still listens on port {port} after SIGTERM")


def test_an_unreachable_ray_address_is_one_line_quickly(tmp_path):
    started = time.monotonic()
    result = cli_zygote.run(["rl", "distributed",
                             "--address", f"127.0.0.1:{free_port()}", "--steps", "1000", "--out", str(tmp_path)],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr[-800:]
    assert "no Ray cluster answered at 127.0.0.1:" in result.stderr and result.stderr.strip().count("\n") == 0
    assert time.monotonic() - started < 60


def test_failed_starts_leave_no_run_folder(world, tmp_path, capsys, monkeypatch):
    """A bad env parameter or a damaged init_from run is found before (or undone after) the run
    folder is made: no empty folders pile up under runs/."""
    monkeypatch.chdir(tmp_path)
    bad_env = yaml.safe_dump(TINY_RL | {"env_kwargs": {"tolerance": 5.0}})
    (tmp_path / "bad_env.yaml").write_text(bad_env)
    for args in (["rl", "train", "bad_env.yaml", "--runs", "runs"],
                 ["detect", "train", world["detect_yaml"], "--set", "data.val=missing.json", "--runs", "runs"]):
        monkeypatch.setattr(sys, "argv", ["binpick", *args])
        with pytest.raises(SystemExit) as exit_info:
            main()
        assert exit_info.value.code == 2, capsys.readouterr().err
    capsys.readouterr()
    assert not any(path.is_dir() and any(path.iterdir()) for path in (tmp_path / "runs").glob("*")), \
        sorted(str(p) for p in (tmp_path / "runs").rglob("*"))

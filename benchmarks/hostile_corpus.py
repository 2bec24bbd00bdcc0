"""Hostile and broken files for every verb that reads them, the way a robot cell or an attacker
supplies them: decompression bombs, FIFOs, nesting and alias bombs, duplicate keys, names that leave
their folder, calibrations no camera has, COCO files that contradict themselves.

``make_corpus(root)`` writes the files and returns their paths by name; ``CASES`` lists
``(class, arguments, fragments)``: the command line (``{name}`` is a path from the corpus) and the
fragments its one error line must hold. ``tests/test_hostile_files.py`` runs every case in-process
(one line, exit code 2, no traceback, within a timeout); ``benchmarks/hostile.py`` counts them by class.
``peer(kind)`` is a hostile network peer on 127.0.0.1 (silent, answering garbage, or a ROS master that
answers once and then stalls); ``PEER_CASES`` are the commands pointed at one.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import struct
import threading
import zlib
from pathlib import Path
from typing import Iterator

import numpy as np

TINY_RL = {"name": "tiny", "env": "FetchReach", "total_timesteps": 200, "checkpoint_every": 100,
           "replay": {"capacity_episodes": 100, "her_additions": 1, "start_fraction": 0.01},
           "sac": {"batch_size": 16, "net_arch": [8, 8]}, "eval": {"every": 100, "episodes": 1}}


def png_header_only(width: int, height: int) -> bytes:
    """A PNG that declares ``width`` x ``height`` RGB pixels and carries almost no data: decoding it
    would allocate width * height * 3 bytes (a decompression bomb's header)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b""))


def npy_header_only(shape: tuple[int, ...], dtype: str = "<f4") -> bytes:
    """An .npy header declaring ``shape`` with no data after it."""
    header = repr({"descr": dtype, "fortran_order": False, "shape": shape}).encode() + b" "
    header += b" " * (-(len(header) + 11) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header


def alias_bomb(levels: int = 12) -> str:
    """YAML's billion laughs: each level lists the previous one 9 times (9**levels leaves)."""
    lines = ['a0: &a0 ["lol"]']
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, levels)]
    return "\n".join(lines) + "\n"


def make_corpus(root: Path) -> dict[str, str]:
    """Write every hostile file under ``root``; their paths by name (and ``root``)."""
    from PIL import Image
    import yaml

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {"root": root}

    def put(name: str, content: bytes | str) -> Path:
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
        paths[name.replace("/", "_").replace(".", "_").replace("-", "_")] = path
        return path

    # a good 64x64 frame: colour, depth (mm), calibration, photo
    Image.fromarray(np.full((64, 64, 3), 120, np.uint8)).save(root / "rgb.png")
    paths["rgb_png"] = root / "rgb.png"
    Image.fromarray(np.zeros((64, 64, 4), np.uint8)).save(root / "transparent.png")  # a cut-out with nothing cut out
    paths["transparent_png"] = root / "transparent.png"
    Image.fromarray(np.full((64, 64), 800, np.uint16)).save(root / "depth.png")
    paths["depth_png"] = root / "depth.png"
    camera = {"image_width": 64, "image_height": 64, "camera_matrix": {"rows": 3, "cols": 3, "data": [60, 0, 32, 0, 60, 32, 0, 0, 1]},
              "camera_to_base": {"translation": [0, 0, 0.8], "rotation": {"x": 1, "y": 0, "z": 0, "w": 0}}}  # 80 cm up, looking down
    put("camera.yaml", yaml.safe_dump(camera))

    # images: bombs, truncations, things that are not images
    put("bomb.png", png_header_only(30_000, 30_000))
    put("bomb_wide.png", png_header_only(1_000_000, 100))
    put("big.png", png_header_only(9_000, 9_000))  # 81 million pixels: under PIL's own guard, over binpick's
    good = (root / "rgb.png").read_bytes()
    put("truncated.png", good[: len(good) // 2])
    put("empty.png", b"")
    put("text.png", "this is not a picture\n")
    put("pdf.png", b"%PDF-1.4\n%\xe2\xe3\xcf\xd3\n1 0 obj\n<<>>\nendobj\n")
    Image.fromarray(np.full((4, 4, 3), 1, np.uint8)).save(root / "tiny.png")
    paths["tiny_png"] = root / "tiny.png"
    for name in ("fifo.png", "fifo.yaml", "fifo.json", "fifo_depth.png", "fifo_products.yaml", "fifo_camera.yaml", "fifo.npy"):
        os.mkfifo(root / name)
        paths[name.replace(".", "_")] = root / name

    # depth arrays
    np.save(root / "depth_complex.npy", np.full((64, 64), 0.8 + 0.1j, np.complex64))
    paths["depth_complex_npy"] = root / "depth_complex.npy"
    np.save(root / "depth_bool.npy", np.ones((64, 64), bool))
    paths["depth_bool_npy"] = root / "depth_bool.npy"
    put("depth_huge_header.npy", npy_header_only((200_000, 200_000)))
    put("depth_empty.npy", b"")
    put("depth_object.npy", npy_header_only((2,), "|O") + b"\x80\x04N.")
    np.save(root / "depth_3d.npy", np.full((64, 64, 3), 0.8, np.float32))
    paths["depth_3d_npy"] = root / "depth_3d.npy"
    Image.fromarray(np.full((64, 64, 3), 9, np.uint8)).save(root / "depth_rgb.png")
    paths["depth_rgb_png"] = root / "depth_rgb.png"

    # calibrations no camera has
    def camera_file(name: str, **change) -> None:
        data = json.loads(json.dumps(camera))
        data.update(change)
        put(name, yaml.safe_dump(data))

    k = camera["camera_matrix"]
    camera_file("cam_focal_tiny.yaml", camera_matrix=k | {"data": [1e-6, 0, 32, 0, 1e-6, 32, 0, 0, 1]})
    camera_file("cam_focal_huge.yaml", camera_matrix=k | {"data": [1e9, 0, 32, 0, 1e9, 32, 0, 0, 1]})
    camera_file("cam_centre_off.yaml", camera_matrix=k | {"data": [60, 0, 900, 0, 60, 32, 0, 0, 1]})
    camera_file("cam_last_row.yaml", camera_matrix=k | {"data": [60, 0, 32, 0, 60, 32, 0, 0, 2]})
    camera_file("cam_skew.yaml", camera_matrix=k | {"data": [60, 5000, 32, 0, 60, 32, 0, 0, 1]})
    camera_file("cam_d_short.yaml", distortion_model="plumb_bob", distortion_coefficients={"data": [0.1, 0.2, 0.0]})
    camera_file("cam_d_long.yaml", distortion_model="equidistant", distortion_coefficients={"data": [0.1] * 7})
    camera_file("cam_d_none.yaml", distortion_model="none", distortion_coefficients={"data": [0.3, 0, 0, 0, 0]})
    for name, matrix in (("scaled", np.diag([2.0, 2, 2, 1])), ("mirrored", np.diag([1.0, 1, -1, 1])),
                         ("sheared", np.array([[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])),
                         ("projective", np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0.2, 0, 0, 1.0]])),
                         ("far", np.array([[1, 0, 0, 5e3], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]))):
        camera_file(f"cam_{name}.yaml", camera_to_base={"matrix": matrix.ravel().tolist()})
    camera_file("cam_width_bool.yaml", image_width=True)
    put("cam_no_pose.yaml", yaml.safe_dump({k: v for k, v in camera.items() if k != "camera_to_base"}))
    camera_file("cam_looking_up.yaml", camera_to_base={"translation": [0, 0, 0.8], "rotation": [0, 0, 0, 1]})
    camera_file("cam_rotation_unnamed.yaml", camera_to_base={"translation": [0, 0, 0.8], "rotation": {"w": 1, "i": 0, "j": 0, "k": 0}})
    camera_file("cam_workspace_huge.yaml", workspace={"min": [-1e6, 0, 0], "max": [1e6, 1, 1]})
    camera_file("cam_workspace_inverted.yaml", workspace={"min": [1, 1, 1], "max": [0, 0, 0]})
    put("cam_alias_bomb.yaml", yaml.safe_dump(camera) + alias_bomb())
    put("cam_deep.yaml", "camera_matrix: " + "[" * 50_000 + "]" * 50_000 + "\n")
    put("cam_duplicate.yaml", yaml.safe_dump(camera) + "image_width: 640\n")

    # configs
    put("rl.yaml", yaml.safe_dump(TINY_RL))
    put("rl_deep.yaml", "name: x\nenv_kwargs: " + "[" * 50_000 + "]" * 50_000 + "\n")
    put("rl_alias_bomb.yaml", alias_bomb() + yaml.safe_dump(TINY_RL) + "env_kwargs: {bomb: *a11}\n")
    put("rl_duplicate.yaml", yaml.safe_dump(TINY_RL) + "name: other\n")
    put("rl_digits.yaml", yaml.safe_dump({**TINY_RL, "total_timesteps": 1}).replace("total_timesteps: 1", "total_timesteps: " + "9" * 100_000))
    put("rl_python_tag.yaml", yaml.safe_dump(TINY_RL) + "seed: !!python/object/apply:os.getcwd []\n")
    for name, value in (("dotdot", "../../escaped"), ("absolute", "/tmp/binpick-escaped-run"), ("slash", "a/b"), ("dot", ".."),
                        ("nul", "a\x00b"), ("empty", "")):
        put(f"rl_name_{name}.yaml", yaml.safe_dump({**TINY_RL, "name": value}))

    # COCO files that contradict themselves
    Image.fromarray(np.full((64, 64, 3), 120, np.uint8)).save(root / "scene.png")
    image = {"id": 1, "file_name": "scene.png", "width": 64, "height": 64}
    box = {"id": 1, "image_id": 1, "category_id": 1, "bbox": [4, 4, 10, 10], "area": 100, "iscrowd": 0}
    second = box | {"id": 2, "bbox": [30, 30, 10, 10]}
    categories = [{"id": 1, "name": "thing", "supercategory": "t"}]

    def coco(name: str, images=None, annotations=None, cats=None, text: str | None = None) -> None:
        put(name, text if text is not None else json.dumps({"images": images if images is not None else [image],
                                                            "annotations": annotations if annotations is not None else [box, second],
                                                            "categories": cats if cats is not None else categories}))

    coco("coco_dup_image.json", images=[image, image | {"file_name": "scene.png"}])
    coco("coco_dup_annotation.json", annotations=[box, second | {"id": 1}])
    coco("coco_dup_category.json", cats=categories * 2)
    coco("coco_box_outside.json", annotations=[box, second | {"bbox": [60, 60, 30, 30]}])
    coco("coco_box_negative.json", annotations=[box, second | {"bbox": [30, 30, -10, 10]}])
    coco("coco_box_infinite.json", text=json.dumps({"images": [image], "annotations": [box, second], "categories": categories})
         .replace("[30, 30, 10, 10]", "[30, 30, Infinity, 10]"))
    coco("coco_orphan.json", annotations=[box, second | {"image_id": 7}])
    coco("coco_unknown_category.json", annotations=[box, second | {"category_id": 9}])
    coco("coco_escape.json", images=[image | {"file_name": "../../../../etc/hostname"}])
    coco("coco_absolute.json", images=[image | {"file_name": "/etc/hostname"}])
    coco("coco_depth_escape.json", images=[image | {"depth_file": "../../../../etc/hostname"}])
    coco("coco_deep.json", text='{"images": ' + "[" * 100_000 + "]" * 100_000 + "}")
    coco("coco_image_size_zero.json", images=[image | {"width": 0}])

    # detector weights whose metadata asks for too much
    from binpick.core import tensorfile
    from binpick.detection.model import DetectorNetwork, ModelSpec
    from binpick.detection.weights_file import FORMAT, save_detector

    save_detector(DetectorNetwork(ModelSpec(), 64), root / "detector.safetensors")
    paths["weights"] = root / "detector.safetensors"
    from binpick.detection.weights_file import read_detector_file

    tensors, meta = read_detector_file(root / "detector.safetensors")
    tensorfile.save(root / "weights_huge_image.safetensors", FORMAT, tensors=tensors, meta={**meta, "image_size": 10_000_000})
    tensorfile.save(root / "weights_huge_channels.safetensors", FORMAT, tensors=tensors,
                    meta={**meta, "spec": {**meta["spec"], "pickability_width": 1_000_000}})
    paths["weights_huge_channels"] = root / "weights_huge_channels.safetensors"
    paths["weights_huge_image"] = root / "weights_huge_image.safetensors"

    # a warehouse data set whose records name files outside it
    data = root / "bins"
    (data / "scenes").mkdir(parents=True)
    (data / "images").mkdir()
    (data / "depth").mkdir()
    from binpick.warehouse.generation import GenerateConfig

    settings = GenerateConfig(out=str(data), scenes=2, workers=1, image_size=64)
    (data / "dataset.json").write_text(json.dumps({"format": "binpick-bins-1", "config": settings.comparable(),
                                                   "products": [{"id": "robosuite/can", "category": "can"}]}))
    record = {"index": 0, "file_name": "../../../../etc/hostname", "depth_file": "depth/000000.png", "width": 64, "height": 64,
              "split": "train", "target": "robosuite/can", "seed": 0, "picked_by": None,
              "camera": {"K": [[60, 0, 32], [0, 60, 32], [0, 0, 1]], "width": 64, "height": 64},
              "annotations": [{"slot": 0, "product": "robosuite/can", "is_target": True, "is_query": True, "bbox": [1, 1, 5, 5],
                               "area": 25, "visible_fraction": 1.0, "pickable": {"y": True}}]}
    (data / "scenes" / "000000.json").write_text(json.dumps(record))
    (data / "scenes" / "000001.json").write_text(json.dumps(record | {"index": 1, "file_name": "images/000001.png",
                                                                      "depth_file": "/etc/hostname"}))
    Image.fromarray(np.full((64, 64, 3), 120, np.uint8)).save(data / "images" / "000001.png")
    paths["bins"] = data

    # grasp-quality weights whose header lies about the network
    from binpick.grasping.quality import FORMAT as GRASP_FORMAT, SHIPPED as GRASP

    grasp_tensors, grasp_meta, _ = tensorfile.load(GRASP, GRASP_FORMAT, "grasp-quality weights")
    for name, change in (("size_text", {"size": "abc"}), ("size_null", {"size": None}), ("width_negative", {"width": -5}),
                         ("extent_nan", {"extent": float("nan")}), ("temperature_zero", {"calibration": {"temperature": 0.0}})):
        path = root / f"grasp_{name}.safetensors"
        tensorfile.save(path, GRASP_FORMAT, tensors=grasp_tensors, meta={**grasp_meta, **change})
        paths[f"grasp_{name}"] = path

    # products files
    (root / "box.obj").write_text("v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    (root / "bad_face.obj").write_text("v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nf 1 2 x\n")
    (root / "quote.obj").write_text('v 0 0 0\nv 0.05 0 0\nv 0 0.05 0"/><include file="/etc/passwd"/>\nf 1 2 3\n')
    product = "{id: mine/box, category: box, mesh: box.obj}"
    put("products_duplicate_ids.yaml", f"products:\n  - {product}\n  - {product}\n")
    put("products_empty_id.yaml", "products:\n  - {id: '', category: box, mesh: box.obj}\n")
    put("products_shadow.yaml", "products:\n  - {id: robosuite/can, category: can, mesh: box.obj}\n")
    put("products_key_twice.yaml", f"products:\n  - {product}\nproducts:\n  - {product}\n")
    put("products_bad_face.yaml", "products:\n  - {id: mine/bad, category: box, mesh: bad_face.obj}\n")
    put("products_quote.yaml", "products:\n  - {id: mine/quote, category: box, mesh: quote.obj}\n")
    put("products_deep.yaml", "products: " + "[" * 50_000 + "]" * 50_000 + "\n")
    put("products_bomb_photo.yaml", "products:\n  - {id: mine/photo, category: box, mesh: box.obj, photo: bomb.png}\n")
    put("products_alias_bomb.yaml", alias_bomb() + "products: *a11\n")
    policy_run(root / "run_huge_space")
    paths["run_huge_space"] = root / "run_huge_space"
    return {key: str(value) for key, value in paths.items()}


def policy_run(folder: Path) -> None:
    """An RL run folder whose saved policy says its observations are 10^6 x 10^6 values."""
    import torch

    from binpick.core import tensorfile
    from binpick.rl.common.persistence import POLICY_FORMAT

    checkpoint = folder / "checkpoints" / "ckpt-000000100"
    checkpoint.mkdir(parents=True, exist_ok=True)
    (folder / "config.yaml").write_text("name: tiny\nenv: FetchReach\nalgorithm: sac\ntotal_timesteps: 200\n")
    (folder / "checkpoints" / "latest").write_text("ckpt-000000100\n")
    box = {"low": -1.0, "high": 1.0, "dtype": "float32"}
    tensorfile.save(checkpoint / "policy.safetensors", POLICY_FORMAT, tensors={"policy.x": torch.zeros(1)},
                    meta={"family": "sac", "policy": "MultiInputPolicy", "policy_kwargs": {},
                          "observation_space": {"shape": [10**6, 10**6], **box}, "action_space": {"shape": [4], **box}})


PLAN = ["plan", "--rgb", "{rgb_png}", "--depth", "{depth_png}", "--camera", "{camera_yaml}"]
BOX = ["--query-box", "10,10,20,20"]


def plan_with(**replace) -> list[str]:
    args = list(PLAN)
    for option, value in replace.items():
        args[args.index(f"--{option}") + 1] = value
    return args + BOX


# (class, arguments, fragments of the one error line)
CASES: list[tuple[str, list[str], list[str]]] = [
    # images, as every verb that reads one meets them
    ("files", plan_with(rgb="{bomb_png}"), ["colour image", "bomb.png", "more pixels than binpick decodes"]),
    ("files", plan_with(rgb="{bomb_wide_png}"), ["bomb_wide.png", "more pixels than binpick decodes"]),
    ("files", plan_with(rgb="{big_png}"), ["big.png", "9000x9000", "more than binpick decodes"]),
    ("files", plan_with(depth="{bomb_png}"), ["depth image", "more pixels than binpick decodes"]),
    ("files", [*PLAN, "--photo", "{bomb_png}"], ["--photo", "more pixels than binpick decodes"]),
    ("files", [*PLAN, "--photo", "{transparent_png}"], ["transparent all over"]),
    ("files", ["detect", "predict", "{bomb_png}", "--weights", "{weights}", "--query-box", "1,1,5,5"], ["bomb.png", "more pixels"]),
    ("files", ["products", "list", "--products", "{products_bomb_photo_yaml}"], ["bomb.png", "more pixels"]),
    ("files", plan_with(rgb="{truncated_png}"), ["truncated.png"]),
    ("files", plan_with(rgb="{empty_png}"), ["empty.png"]),
    ("files", plan_with(rgb="{pdf_png}"), ["pdf.png"]),
    ("files", plan_with(rgb="{tiny_png}"), ["tiny.png", "smaller than 8 pixels"]),
    ("files", plan_with(rgb="{fifo_png}"), ["fifo.png", "not a regular file"]),
    ("files", plan_with(depth="{fifo_depth_png}"), ["fifo_depth.png", "not a regular file"]),
    ("files", plan_with(depth="{fifo_npy}"), ["fifo.npy", "not a regular file"]),
    ("files", plan_with(camera="{fifo_camera_yaml}"), ["fifo_camera.yaml", "not a regular file"]),
    ("files", [*PLAN, "--photo", "{fifo_png}"], ["fifo.png", "not a regular file"]),
    ("files", ["detect", "predict", "{fifo_png}", "--weights", "{weights}", "--query-box", "1,1,5,5"], ["not a regular file"]),
    ("files", ["detect", "predict", "{rgb_png}", "--weights", "{fifo_json}", "--query-box", "1,1,5,5"], ["fifo.json"]),
    ("files", plan_with(rgb="/dev/zero"), ["/dev/zero", "not a regular file"]),
    # depth frames and calibrations
    ("frames", plan_with(depth="{depth_complex_npy}"), ["depth_complex.npy", "real numbers"]),
    ("frames", plan_with(depth="{depth_bool_npy}"), ["depth_bool.npy"]),
    ("frames", plan_with(depth="{depth_huge_header_npy}"), ["depth_huge_header.npy"]),
    ("frames", plan_with(depth="{depth_empty_npy}"), ["depth_empty.npy"]),
    ("frames", plan_with(depth="{depth_object_npy}"), ["depth_object.npy"]),
    ("frames", plan_with(depth="{depth_3d_npy}"), ["depth_3d.npy"]),
    ("frames", plan_with(depth="{depth_rgb_png}"), ["depth_rgb.png", "16-bit"]),
    ("frames", plan_with(camera="{cam_focal_tiny_yaml}"), ["focal length fx = 1e-06"]),
    ("frames", plan_with(camera="{cam_focal_huge_yaml}"), ["focal length fx = 1e+09"]),
    ("frames", plan_with(camera="{cam_centre_off_yaml}"), ["principal point"]),
    ("frames", plan_with(camera="{cam_last_row_yaml}"), ["[0, 0, 1]"]),
    ("frames", plan_with(camera="{cam_skew_yaml}"), ["skew s = 5000"]),
    ("frames", plan_with(camera="{cam_d_short_yaml}"), ["plumb_bob takes 4 or 5 or 8 or 12 or 14 coefficients, got 3"]),
    ("frames", plan_with(camera="{cam_d_long_yaml}"), ["equidistant takes 4 or 5 or 8 coefficients, got 7"]),
    ("frames", plan_with(camera="{cam_d_none_yaml}"), ["non-zero coefficients"]),
    ("frames", plan_with(camera="{cam_scaled_yaml}"), ["not a rotation"]),
    ("frames", plan_with(camera="{cam_mirrored_yaml}"), ["not a rotation"]),
    ("frames", plan_with(camera="{cam_sheared_yaml}"), ["not a rotation"]),
    ("frames", plan_with(camera="{cam_projective_yaml}"), ["0 0 0 1"]),
    ("frames", plan_with(camera="{cam_far_yaml}"), ["5e+03 m away"]),
    ("frames", plan_with(camera="{cam_width_bool_yaml}"), ["image_width"]),
    ("frames", plan_with(camera="{cam_no_pose_yaml}"), ["cam_no_pose.yaml", "has no camera_to_base"]),
    ("frames", plan_with(camera="{cam_looking_up_yaml}"), ["optical axis up"]),
    ("frames", plan_with(camera="{cam_rotation_unnamed_yaml}"), ["rotation must name x, y, z and w"]),
    ("frames", plan_with(camera="{cam_workspace_huge_yaml}"), ["workspace spans more than"]),
    ("frames", plan_with(camera="{cam_workspace_inverted_yaml}"), ["workspace min"]),
    ("frames", plan_with(camera="{cam_alias_bomb_yaml}"), ["cam_alias_bomb.yaml", "aliases"]),
    ("frames", plan_with(camera="{cam_deep_yaml}"), ["cam_deep.yaml", "nests"]),
    ("frames", plan_with(camera="{cam_duplicate_yaml}"), ["cam_duplicate.yaml", "image_width", "twice"]),
    ("frames", [*PLAN, "--query-box", "nan,1,5,5"], ["query box", "finite"]),
    ("frames", [*PLAN, "--query-box", "1,1,inf,5"], ["--query-box"]),
    ("frames", [*PLAN, "--photo", "{rgb_png}", "--product-size", "nan,0.1,0.1"], ["--product-size"]),
    ("frames", [*PLAN, "--query-box", "1e999,1,5,5"], ["--query-box"]),
    # configs
    ("configs", ["rl", "train", "{rl_deep_yaml}"], ["rl_deep.yaml", "nests"]),
    ("configs", ["rl", "train", "{rl_alias_bomb_yaml}"], ["rl_alias_bomb.yaml", "aliases"]),
    ("configs", ["rl", "train", "{rl_duplicate_yaml}"], ["rl_duplicate.yaml", "'name'", "twice"]),
    ("configs", ["rl", "train", "{rl_digits_yaml}"], ["rl_digits.yaml"]),
    ("configs", ["rl", "train", "{rl_python_tag_yaml}"], ["rl_python_tag.yaml"]),
    ("configs", ["rl", "train", "{fifo_yaml}"], ["fifo.yaml", "not a regular file"]),
    ("configs", ["rl", "train", "{rl_yaml}", "--set", "name=[unclosed"], ["--set", "name"]),
    ("configs", [*PLAN, *BOX, "--out", ""], ["--out is empty"]),
    ("configs", ["rl", "train", "{rl_yaml}", "--set", "sac.net_arch=[8, .nan]"], ["net_arch[1]", "nan"]),
    ("configs", ["data", "generate", "--out", "{root}/nan_data", "--set", "copies=[2, .nan]"], ["copies", "nan"]),
    ("configs", ["rl", "train", "{rl_yaml}", "--runs="], ["--runs is empty"]),
    ("configs", ["rl", "train", "{rl_yaml}", "--set", "seed=!!python/object/apply:os.getcwd []"], ["--set", "seed"]),
    ("configs", ["rl", "train", "{rl_yaml}", "--set", "total_timesteps=" + "9" * 100_000], ["--set", "total_timesteps"]),
    ("configs", ["rl", "train", "{rl_yaml}", "--set", "env_kwargs=" + "[" * 20_000 + "]" * 20_000], ["--set", "env_kwargs"]),
    ("configs", ["rl", "train", "{rl_yaml}", "--set", "name=../../escaped"], ["name", "../../escaped", "folder"]),
    ("configs", ["rl", "train", "{rl_name_dotdot_yaml}", "--runs", "{root}/runs"], ["name", "../../escaped"]),
    ("configs", ["rl", "train", "{rl_name_absolute_yaml}", "--runs", "{root}/runs"], ["name", "/tmp/binpick-escaped-run"]),
    ("configs", ["rl", "train", "{rl_name_slash_yaml}", "--runs", "{root}/runs"], ["name", "a/b"]),
    ("configs", ["rl", "train", "{rl_name_dot_yaml}", "--runs", "{root}/runs"], ["name", "'..'"]),
    ("configs", ["rl", "train", "{rl_name_nul_yaml}", "--runs", "{root}/runs"], ["name"]),
    ("configs", ["rl", "train", "{rl_name_empty_yaml}", "--runs", "{root}/runs"], ["name"]),
    # data: COCO files, data sets, products, weights
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_dup_image_json}"], ["coco_dup_image.json", "image id 1", "twice"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_dup_annotation_json}"], ["annotation id 1", "twice"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_dup_category_json}"], ["category id 1", "twice"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_box_outside_json}"], ["outside", "64x64"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_box_negative_json}"], ["coco_box_negative.json", "bbox"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_box_infinite_json}"], ["coco_box_infinite.json", "bbox"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_orphan_json}"], ["image_id 7", "no image"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_unknown_category_json}"], ["category_id", "listed category"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_escape_json}"], ["lies outside"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_absolute_json}"], ["lies outside"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_depth_escape_json}"], ["lies outside"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_deep_json}"], ["coco_deep.json", "nests"]),
    ("data", ["detect", "eval", "{weights}", "--data", "{coco_image_size_zero_json}"], ["width"]),
    ("data", ["detect", "predict", "{rgb_png}", "--weights", "{weights_huge_image}", "--query-box", "1,1,5,5"], ["image_size"]),
    ("data", ["detect", "predict", "{rgb_png}", "--weights", "{weights_huge_channels}", "--query-box", "1,1,5,5"], ["past 4096"]),
    ("data", ["data", "export", "{bins}", "--scene", "0", "--out", "{root}/export0"], ["lies outside"]),
    ("data", ["data", "export", "{bins}", "--scene", "1", "--out", "{root}/export1"], ["lies outside"]),
    ("data", ["data", "show", "{bins}", "--scene", "0", "--out", "{root}/show"], ["lies outside"]),
    ("data", ["products", "list", "--products", "{products_duplicate_ids_yaml}"], ["mine/box", "twice"]),
    ("data", ["products", "list", "--products", "{products_empty_id_yaml}"], [".id must be a non-empty name"]),
    ("data", ["products", "list", "--products", "{products_shadow_yaml}"], ["robosuite/can", "built-in"]),
    ("data", ["products", "list", "--products", "{products_key_twice_yaml}"], ["'products'", "twice"]),
    ("data", ["products", "list", "--products", "{products_bad_face_yaml}"], ["bad_face.obj"]),
    ("data", ["products", "list", "--products", "{products_quote_yaml}"], ["quote.obj"]),
    ("data", ["products", "list", "--products", "{products_deep_yaml}"], ["products_deep.yaml", "nests"]),
    ("data", ["products", "list", "--products", "{products_alias_bomb_yaml}"], ["aliases"]),
    ("data", ["products", "list", "--products", "{fifo_products_yaml}"], ["not a regular file"]),
    ("data", [*PLAN, "--photo", "{rgb_png}", "--grasp-weights", "{grasp_size_text}"], ["grasp_size_text", "size", "'abc'"]),
    ("data", [*PLAN, "--photo", "{rgb_png}", "--grasp-weights", "{grasp_size_null}"], ["grasp_size_null", "size", "None"]),
    ("data", [*PLAN, "--photo", "{rgb_png}", "--grasp-weights", "{grasp_width_negative}"], ["grasp_width_negative", "width", "-5"]),
    ("data", [*PLAN, "--photo", "{rgb_png}", "--grasp-weights", "{grasp_extent_nan}"], ["grasp_extent_nan", "extent", "nan"]),
    ("data", [*PLAN, "--photo", "{rgb_png}", "--grasp-weights", "{grasp_temperature_zero}"], ["grasp_temperature_zero", "temperature"]),
    ("data", ["rl", "eval", "{run_huge_space}", "--episodes", "1"], ["observation_space", "more than"]),
]


STALLING_ANSWER = (b"HTTP/1.0 200 OK\r\nContent-Type: text/xml\r\n\r\n<?xml version='1.0'?><methodResponse><params><param><value>"
                   b"<array><data><value><int>1</int></value><value><string>ok</string></value><value><int>42</int></value>"
                   b"</data></array></value></param></params></methodResponse>")


def _silent(connection: socket.socket, held: list) -> None:
    held.append(connection)


def _garbage(connection: socket.socket, held: list) -> None:
    try:
        connection.sendall(b"\x00\xffgarbage, not a protocol\r\n" * 8)
    except OSError:
        return
    held.append(connection)


def _stalling_master(connection: socket.socket, held: list) -> None:
    """Answers getPid as a ROS master does; every later request is read and never answered."""
    request = b""
    connection.settimeout(10)
    try:
        while b"</methodCall>" not in request:
            chunk = connection.recv(4096)
            if not chunk:
                return
            request += chunk
    except OSError:
        return
    if b"getPid" in request:
        connection.sendall(STALLING_ANSWER)
        connection.close()
    else:
        held.append(connection)


PEERS = {"silent": _silent, "garbage": _garbage, "stalling_master": _stalling_master}


@contextlib.contextmanager
def peer(kind: str) -> Iterator[int]:
    """A listener on 127.0.0.1 (its port) whose every connection is handled as ``kind`` says, on a
    thread of its own: ``silent`` accepts and never sends a byte, ``garbage`` answers bytes of no
    protocol, ``stalling_master`` answers a ROS master's first call and then nothing."""
    handle = PEERS[kind]
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(16)
    held: list[socket.socket] = []

    def accept() -> None:
        while True:
            try:
                connection = server.accept()[0]
            except OSError:
                return
            threading.Thread(target=handle, args=(connection, held), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    try:
        yield server.getsockname()[1]
    finally:
        server.close()
        for connection in held:
            connection.close()


SAMPLE_CAMERA = str(Path(__file__).resolve().parents[1] / "src" / "binpick" / "samples" / "bin_frame" / "camera.yaml")
# (peer kind, arguments ({port}, {tmp}, {config}: a tiny RL YAML), fragments of the one error line)
PEER_CASES = [
    ("silent", ["rl", "distributed", "--address", "127.0.0.1:{port}", "--steps", "1000", "--out", "{tmp}/d"], ["did not answer within"]),
    ("silent", ["data", "generate", "--out", "{tmp}/g", "--address", "127.0.0.1:{port}", "--scenes", "1"], ["did not answer within"]),
    ("silent", ["ros", "pick-node", "--master", "http://127.0.0.1:{port}/", "--camera", SAMPLE_CAMERA], ["no ROS master answered"]),
    ("garbage", ["train", "{config}", "--runs", "{tmp}/runs", "--address", "127.0.0.1:{port}"], ["not as a Ray cluster does"]),
    ("garbage", ["ros", "pick-node", "--master", "http://127.0.0.1:{port}/", "--camera", SAMPLE_CAMERA], ["ROS master"]),
    ("stalling_master", ["ros", "pick-node", "--master", "http://127.0.0.1:{port}/", "--timeout", "3", "--camera", SAMPLE_CAMERA],
     ["stopped answering"]),
    ("stalling_master", ["ros", "serve", "FetchReach", "--master", "http://127.0.0.1:{port}/", "--timeout", "3"], ["stopped answering"]),
    ("stalling_master", ["ros", "bench", "--master", "http://127.0.0.1:{port}/", "--timeout", "3"], ["stopped answering"]),
]
TINY_RL_YAML = "task: rl\nname: tiny\nenv: FetchReach\nalgorithm: sac\ntotal_timesteps: 200\n"

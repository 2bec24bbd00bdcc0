"""Warehouse bin data (thesis §5.4.4, §6.3): products, settled scenes with boxes and visible fractions,
trial grasps that label pickability, a resumable COCO writer and its CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import cli_zygote

from binpick.core.errors import ConfigError, InputFileError
from binpick.sim import Product, default_library, load_products
from binpick.sim.bin_scene import BinWorld
from binpick.sim.gripper import TopDownGrasp
from binpick.sim.mjcf import CameraSpec
from binpick.sim.products import mesh_extent
from binpick.warehouse.coco import finalise
from binpick.warehouse.dataset import generate
from binpick.warehouse.generation import GenerateConfig

CUBE = """o cube
v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1
f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8
"""


def test_library_has_the_shipped_products_and_users_add_their_own(tmp_path):
    library = default_library(procedural=3)
    ids = set(library.products)
    assert {"robosuite/cereal", "robosuite/milk", "pybullet/duck", "pybullet/mug"} <= ids
    assert sum(i.startswith("procedural/") for i in ids) == 3
    (tmp_path / "soap.obj").write_text(CUBE)
    (tmp_path / "products.yaml").write_text("products:\n  - {id: acme/soap, category: soap, mesh: soap.obj, longest_side: 0.08}\n")
    library = load_products(tmp_path / "products.yaml", library)
    soap = library["acme/soap"]
    assert soap.category == "soap" and soap.scale == pytest.approx(0.04)  # the cube is 2 units across
    (tmp_path / "broken.obj").write_text("this is not a mesh\n")
    (tmp_path / "bad.yaml").write_text("products:\n  - {id: acme/bad, category: soap, mesh: broken.obj}\n")
    with pytest.raises(ConfigError, match="broken.obj"):
        load_products(tmp_path / "bad.yaml")
    with pytest.raises(ConfigError, match="unknown product 'acme/nothing'"):
        library["acme/nothing"]
    with pytest.raises(ConfigError, match="unknown product category 'furniture'"):
        library.in_categories(["furniture"])


def test_random_shapes_and_the_teddy_stay_in_the_tote_in_piles_of_eight():
    library = default_library(procedural=0, shapes=2)
    shapes = [p for p in library if p.category == "random_shape"]
    assert len(shapes) == 2 and "pybullet/teddy" in library.products
    for product in [library["pybullet/teddy"], *shapes]:
        extent = np.sort([float(v) for v in mesh_extent(product.mesh)])
        assert extent[0] / extent[-1] >= 0.35  # thin sticks, which slipped out, are skipped
        world = BinWorld(product, [], max_copies=8, camera=CameraSpec(size=64))
        try:
            world.scene(8, 0, seed=1)
            inside = [world.instance_centre_and_top(slot)[0] for slot in range(8)]
        finally:
            world.close()
        assert all(c[2] > 0.025 and abs(c[0]) < 0.22 and abs(c[1]) < 0.17 for c in inside), product.id


def test_scenes_are_deterministic_with_boxes_that_fit_the_segmentation():
    library = default_library(procedural=3)
    world = BinWorld(library["robosuite/can"], [library["pybullet/duck"]], max_copies=4, camera=CameraSpec(size=128))
    try:
        first = world.scene(4, 1, seed=7)
        other = world.scene(3, 0, seed=8)
        again = world.scene(4, 1, seed=7)
    finally:
        world.close()
    assert np.array_equal(first.rgb, again.rgb) and len(first.instances) == len(again.instances)
    assert not np.array_equal(first.rgb, other.rgb)
    assert sum(i.is_target for i in first.instances) >= 3  # at most one may hide completely
    for instance in first.instances:
        ys, xs = np.nonzero(first.segmentation == instance.slot)
        x, y, w, h = instance.bbox
        assert (x, y, x + w - 1, y + h - 1) == (xs.min(), ys.min(), xs.max(), ys.max())
        assert 0.0 < instance.visible_fraction <= 1.0 and instance.area == len(xs)
    depth_in_bin = first.depth[first.segmentation >= 0]
    assert 0.6 < depth_in_bin.min() and depth_in_bin.max() < 0.85  # objects lie between camera and floor


def test_trial_grasps_pick_a_small_box_and_fail_on_one_wider_than_the_jaws():
    small = Product("test/small", "test", shape="box", size=(0.02, 0.02, 0.02), mass=0.1)
    wide = Product("test/wide", "test", shape="box", size=(0.09, 0.09, 0.02), mass=0.1)
    outcomes = {}
    for product in (small, wide):
        world = BinWorld(product, [], max_copies=1, camera=CameraSpec(size=64), gripper=True)
        try:
            scene = world.scene(1, 0, seed=0)
            outcomes[product.id] = []
            for axis in ("x", "y"):
                world.restore(scene.state)
                outcomes[product.id].append(TopDownGrasp(axis).attempt(world, 0))
        finally:
            world.close()
    assert outcomes == {"test/small": [True, True], "test/wide": [False, False]}


def test_labelling_trials_run_without_the_drop_guards_as_the_pipeline_does():
    from binpick.warehouse.labels import label_pickability

    product = Product("test/small", "test", shape="box", size=(0.02, 0.02, 0.02), mass=0.1)
    world = BinWorld(product, [], max_copies=2, camera=CameraSpec(size=64), gripper=True)
    seen = []

    class Recorder:  # a policy that notes whether the guards would stop a carried product
        name = "recorder"

        def attempt(self, sim, slot, offset=(0.0, 0.0)):
            seen.append(bool(sim.model.geom_contype[sim.guards].any()))
            offsets.append(offset)
            return self.holds(offset)

        def __init__(self, name, holds):
            self.name, self.holds = name, holds

    offsets = []
    try:
        scene = world.scene(2, 0, seed=0)
        assert world.model.geom_contype[world.guards].all()  # on while the scene settles
        record = {"annotations": [{"is_target": True, "slot": i.slot, "pickable": {}} for i in scene.instances]}
        label_pickability(world, scene, record, [Recorder("recorder", lambda offset: True)], np.random.default_rng(0))
        assert seen == [False, False] and offsets == [(0.0, 0.0)] * 2
        assert all(a["pickable"] == {"recorder": True} and "pickable_rate" not in a for a in record["annotations"])
        # several grasps per label: the policy's own, then the jaws moved by the jitter; the majority decides
        offsets.clear()
        mostly = Recorder("mostly", lambda offset: offset[0] >= 0)  # fails only when moved to -x
        rarely = Recorder("rarely", lambda offset: offset[1] > 0)  # holds only when moved to +y
        label_pickability(world, scene, record, [mostly, rarely], np.random.default_rng(0), trials=5, jitter=0.002)
    finally:
        world.close()
    assert offsets[:5] == [(0.0, 0.0), (0.002, 0.0), (-0.002, 0.0), (0.0, 0.002), (0.0, -0.002)] and len(offsets) == 20
    for annotation in record["annotations"]:
        assert annotation["pickable"] | {} == {"recorder": True, "mostly": True, "rarely": False}
        assert annotation["pickable_rate"] == {"mostly": 0.8, "rarely": 0.2}


def _tiny(out: Path, **changes) -> GenerateConfig:
    settings = dict(out=str(out), scenes=4, policies=[], workers=1, image_size=64, copies=(2, 3), distractors=(0, 1),
                    scenes_per_world=2, photo_size=32, seed=3)
    settings.update(changes)
    return GenerateConfig(**settings)


def test_generation_resumes_without_losing_or_duplicating_scenes(tmp_path, monkeypatch):
    import binpick.warehouse.generation as generation

    monkeypatch.setattr(generation, "_LIBRARIES", {})
    monkeypatch.setattr(generation, "default_library", lambda seed=0: default_library(procedural=3, seed=seed))
    clean = generate(_tiny(tmp_path / "clean"))
    assert clean["scenes"] == 4 and clean["instances_per_image"] >= 2
    partial = tmp_path / "partial"
    generate(_tiny(partial, scenes=2))  # as if killed after two scenes ...
    (partial / "images" / "000002.png").write_bytes(b"half-written")  # ... while writing the third
    generate(_tiny(partial))
    coco = json.loads((partial / "annotations.json").read_text())
    reference = json.loads((tmp_path / "clean" / "annotations.json").read_text())
    assert [i["id"] for i in coco["images"]] == [1, 2, 3, 4]
    assert [a["bbox"] for a in coco["annotations"]] == [a["bbox"] for a in reference["annotations"]]
    assert len({a["id"] for a in coco["annotations"]}) == len(coco["annotations"])
    assert sum(1 for a in coco["annotations"] if a["is_query"]) == 4
    assert (partial / "photos" / "robosuite_can.png").is_file() and (partial / "CARD.md").is_file()
    with pytest.raises(ConfigError, match="made with other settings"):
        generate(_tiny(partial, image_size=96))
    # studio photos of a fixed library are per product: a resume may add them without touching a scene
    generate(_tiny(partial, photo_views=2))
    assert sorted(p.name for p in (partial / "photos" / "robosuite_can").iterdir()) == ["0.png", "1.png"]
    assert json.loads((partial / "dataset.json").read_text())["config"]["photo_views"] == 2
    assert json.loads((partial / "annotations.json").read_text())["annotations"] == coco["annotations"]
    generate(_tiny(partial, photo_views=1))  # asking for fewer keeps those there
    assert json.loads((partial / "dataset.json").read_text())["config"]["photo_views"] == 2
    (tmp_path / "unrelated").mkdir()
    (tmp_path / "unrelated" / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match="not empty and is not a binpick data set"):
        generate(_tiny(tmp_path / "unrelated"))
    (partial / "scenes" / "000001.json").write_text("{broken")
    with pytest.raises(InputFileError, match="000001.json' is not valid JSON.*redo that scene"):
        finalise(partial)


def test_labels_and_zero_shot_split(tmp_path, monkeypatch):
    import binpick.warehouse.generation as generation

    library = default_library(procedural=3)
    monkeypatch.setattr(generation, "_LIBRARIES", {})
    monkeypatch.setattr(generation, "default_library", lambda seed=0: library)
    config = _tiny(tmp_path / "labelled", scenes=2, scenes_per_world=1, policies=["x", "y"], copies=(2, 2), targets=["can", "toy"],
                   distractors=(0, 0), held_out_categories=["can", "bottle", "box", "carton", "bakery", "fruit", "toy", "mug",
                                                            "procedural_box", "procedural_cylinder", "procedural_sphere"])
    stats = generate(config)
    assert stats["splits"] == {"test": 2} and stats["labelled_instances"] >= 3
    coco = json.loads((tmp_path / "labelled" / "annotations_test.json").read_text())
    targets = [a for a in coco["annotations"] if a["is_target"]]
    assert all(set(a["pickable"]) == {"x", "y"} and "pickable_rate" not in a for a in targets)  # one grasp per label
    for image in coco["images"]:  # the query is the first instance policy x picked, if any was
        query = next(a for a in coco["annotations"] if a["id"] == image["query_annotation_id"])
        assert query["is_target"] and (image["picked_by"] is None or query["pickable"]["x"])
    assert {c["supercategory"] for c in coco["categories"]} >= {"can", "toy"}
    assert {i["target_product"] for i in coco["images"]} <= {"robosuite/can", "pybullet/duck", "pybullet/lego"}
    # the detector reads the warehouse COCO file like any other, with shop photos found beside it
    from binpick.detection.data import RepeatedInstances, TaskDataset

    tasks = RepeatedInstances(tmp_path / "labelled" / "annotations_test.json")
    assert 1 <= len(tasks) <= 2 and all(len(t.annotations) >= 2 for t in tasks.tasks)
    assert TaskDataset(tasks, 64, query_mode="photo")[0]["query_image"].shape == (3, 96, 96)
    if any(image["picked_by"] for image in coco["images"]):
        picking = RepeatedInstances(tmp_path / "labelled" / "annotations_test.json", targets="pickable:x")
        assert all(task.query["is_query"] for task in picking.tasks)


def test_data_cli_generates_shows_and_reports_bad_input_in_one_line(tmp_path):
    out = tmp_path / "bins"
    run = lambda *args: cli_zygote.run(["data", *args], capture_output=True, text=True, timeout=300)  # noqa: E731
    result = run("generate", "--out", str(out), "--scenes", "2", "--policies", "", "--workers", "1", "--size", "64")
    assert result.returncode == 0, result.stderr
    assert "instances per image" in result.stdout
    result = run("show", str(out), "--scene", "1", "--out", str(tmp_path))
    assert result.returncode == 0 and (tmp_path / "scene_000001.png").stat().st_size > 0
    assert run("stats", str(out)).returncode == 0
    for args, message in [(("generate", "--out", str(tmp_path / "x"), "--policies", "z"), "unknown grasp policy 'z'"),
                          (("generate", "--out", str(tmp_path / "x"), "--held-out", "furniture"), "unknown product category 'furniture'"),
                          (("generate", "--out", str(tmp_path / "x"), "--targets", "acme/nothing"), "unknown product or category 'acme/nothing'"),
                          (("show", str(tmp_path)), "not a binpick data set"),
                          (("show", str(out), "--scene", "9"), "scene 9 is not in")]:
        result = run(*args)
        assert result.returncode == 2 and message in result.stderr and "Traceback" not in result.stderr, (args, result.stderr)

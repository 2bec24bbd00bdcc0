"""Repeated object detection (thesis ch. 5): box ops against brute force, the ROD heatmap, the
losses, the COCO reader, pycocotools evaluation, training/resume, prediction and bad input."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
import torch
from conftest import binpick_here

from binpick.detection.backbone import build_backbone
from binpick.detection.baselines import histogram_matches, template_matches
from binpick.detection.config import DetectConfig
from binpick.core.config import load_config
from binpick.detection.data import RepeatedInstances, TaskDataset, collate
from binpick.detection.evaluate import coco_ap, copy_scores, first_choices
from binpick.detection.losses import LossWeights, assign, gaussian_targets, rod_loss
from binpick.detection.model import DetectorNetwork, ModelSpec
from binpick.detection.ops import box_iou, generalized_box_iou, nms
from binpick.detection.rod import RODModule
from binpick.detection.train import DetectorTrainer, evaluate_model
from binpick.detection.training_data import kmeans_anchors
from binpick.detection.weights_file import load_detector, save_detector
from binpick.core.errors import ConfigError, InputFileError
from synthetic_coco import make_coco



def _random_boxes(rng, n):
    xy = rng.uniform(0, 50, (n, 2))
    return torch.tensor(np.c_[xy, xy + rng.uniform(1, 30, (n, 2))], dtype=torch.float32)


def test_iou_giou_and_nms_match_brute_force():
    rng = np.random.default_rng(0)
    a, b = _random_boxes(rng, 7), _random_boxes(rng, 5)
    for i, j in itertools.product(range(7), range(5)):
        (ax1, ay1, ax2, ay2), (bx1, by1, bx2, by2) = a[i].tolist(), b[j].tolist()
        inter = max(0, min(ax2, bx2) - max(ax1, bx1)) * max(0, min(ay2, by2) - max(ay1, by1))
        union = (ax2 - ax1) * (ay2 - ay1) + (bx2 - bx1) * (by2 - by1) - inter
        hull = (max(ax2, bx2) - min(ax1, bx1)) * (max(ay2, by2) - min(ay1, by1))
        assert box_iou(a, b)[i, j] == pytest.approx(inter / union, abs=1e-5)
        assert generalized_box_iou(a, b)[i, j] == pytest.approx(inter / union - (hull - union) / hull, abs=1e-5)
    boxes, scores = _random_boxes(rng, 40), torch.tensor(rng.uniform(size=40), dtype=torch.float32)
    kept = nms(boxes, scores, 0.4).tolist()
    expected = []  # greedy by score, brute force
    for i in sorted(range(40), key=lambda k: -scores[k]):
        if all(box_iou(boxes[i:i + 1], boxes[k:k + 1])[0, 0] <= 0.4 for k in expected):
            expected.append(i)
    assert kept == expected


def test_backbones_give_three_feature_levels():
    for name, channels in (("tiny", (64, 128, 256)), ("darknet53", (256, 512, 1024))):
        features = build_backbone(name).eval()(torch.zeros(1, 3, 64, 64))
        assert [tuple(f.shape) for f in features] == [(1, c, 64 // s, 64 // s) for c, s in zip(channels, (8, 16, 32))]


def test_rod_heatmap_peaks_where_the_query_repeats_at_another_scale():
    torch.manual_seed(0)
    features = torch.randn(1, 16, 24, 24) * 0.3
    pattern = torch.randn(16, 4, 4)
    features[0, :, 2:6, 2:6] = pattern  # the known instance
    features[0, :, 12:20, 12:20] = torch.nn.functional.interpolate(pattern[None], size=(8, 8), mode="bilinear")[0]
    module = RODModule(16, scales=(1.0, 2.0))
    heatmap = module.heatmaps(features, [features[0, :, 2:6, 2:6]])[0, 0]
    peak = np.unravel_index(int(heatmap.argmax()), heatmap.shape)
    assert abs(peak[0] - 16) <= 1 and abs(peak[1] - 16) <= 1 or abs(peak[0] - 4) <= 1  # the copy, or the query itself
    copy_score, background = float(heatmap[15:18, 15:18].max()), float(heatmap[20:, :8].mean())
    assert copy_score > 0.6 and background < 0.2
    single = RODModule(16, scales=(1.0,)).heatmaps(features, [features[0, :, 2:6, 2:6]])[0, 0]
    assert float(single[15:18, 15:18].max()) < copy_score  # the second scale is what finds the big copy


def test_assignment_picks_the_cell_holding_the_centre_and_the_loss_falls():
    torch.manual_seed(0)
    model = DetectorNetwork(ModelSpec(), 64)
    images, boxes = torch.rand(1, 3, 64, 64), torch.tensor([[4.0, 4.0, 20.0, 20.0]])
    target = [torch.tensor([[30.0, 34.0, 50.0, 60.0]])]
    out = model(images, boxes)
    decoded, _ = model.decode(out["raw"])
    (index, level, anchor, row, col), = assign(model, out["raw"], decoded[0], target[0])
    stride = (8, 16, 32)[level]
    assert (row, col) == (int(47 // stride), int(40 // stride))
    goal = gaussian_targets(target[0], 8, 8, 8, 1.0)
    assert float(goal[5, 5]) == pytest.approx(float(goal.max())) and float(goal.max()) > 0.8
    optimiser = torch.optim.Adam(model.parameters(), lr=2e-3)
    losses = []
    for _ in range(30):
        loss = rod_loss(model, model(images, boxes), target, LossWeights())
        optimiser.zero_grad()
        loss["total"].backward()
        optimiser.step()
        losses.append(float(loss["total"].detach()))
    assert losses[-1] < 0.6 * losses[0]
    no_lh = rod_loss(model, model(images, boxes), target, LossWeights(heatmap=0.0))
    assert float(no_lh["total"].detach()) == pytest.approx(float(no_lh["bbox"] + no_lh["obj"]), rel=1e-4)


def test_coco_reader_tasks_exclusions_pickable_targets_and_bad_files(tmp_path):
    path = make_coco(tmp_path / "plain", images=6)
    source = RepeatedInstances(path)
    assert len(source) == 6 and all(len(t.annotations) >= 2 for t in source.tasks)
    fewer = RepeatedInstances(path, exclude_categories=["red_square"])
    assert all(source.categories[t.category_id]["name"] != "red_square" for t in fewer.tasks)
    dataset = TaskDataset(source, 64, augment=True)
    sample = dataset[0]
    assert sample["image"].shape == (3, 64, 64) and sample["query_image"].shape == (3, 96, 96)
    assert len(sample["targets"]) == len(source.tasks[0].annotations) - 1
    batch = collate([dataset[0], dataset[1]])
    assert batch["image"].shape == (2, 3, 64, 64) and len(batch["targets"]) == 2
    picking = RepeatedInstances(make_coco(tmp_path / "pick", images=6, pickable=True), targets="pickable:y")
    task = picking.tasks[0]
    boxes = picking.boxes(task, task.query)
    assert len(boxes["targets"]) + len(boxes["unpickable"]) == len(task.annotations) - 1
    assert np.all(boxes["targets"][:, [0, 2]].mean(1) < 64)  # pickable = left half in this toy labelling
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(InputFileError, match="not valid JSON"):
        RepeatedInstances(tmp_path / "bad.json")
    with pytest.raises(ConfigError, match="unknown category 'sofa'"):
        RepeatedInstances(path, exclude_categories=["sofa"])
    with pytest.raises(ConfigError, match="does not exist"):
        RepeatedInstances(tmp_path / "missing.json")


def test_coco_ap_is_one_for_perfect_boxes_and_falls_with_errors():
    truth = np.array([[10, 10, 40, 40], [60, 60, 90, 100]], dtype=np.float32)
    task = {"targets": truth, "all": truth, "unpickable": np.zeros((0, 4), np.float32)}
    perfect = coco_ap([task | {"boxes": truth, "scores": np.array([0.9, 0.8])}], "targets", 128, by_scale=True)
    assert perfect["ap50"] == pytest.approx(1.0) and perfect["map"] == pytest.approx(1.0)
    shifted = coco_ap([task | {"boxes": truth + 3, "scores": np.array([0.9, 0.8])}], "targets", 128)
    assert shifted["ap50"] == pytest.approx(1.0) and shifted["map"] < 0.8
    wrong = coco_ap([task | {"boxes": truth[::-1] + [0, 30, 0, 30], "scores": np.array([0.9, 0.8])}], "targets", 128)
    assert wrong["ap50"] < 0.5
    assert coco_ap([task | {"boxes": truth, "scores": np.array([0.9, 0.8])}], "unpickable", 128)["ap50"] is None


def test_copy_scores_give_each_labelled_copy_its_best_matching_detection():
    pickable, unpickable = np.array([[10, 10, 40, 40]], np.float32), np.array([[60, 60, 90, 100], [5, 80, 30, 110]], np.float32)
    boxes = np.array([[11, 11, 41, 41], [12, 10, 40, 42], [60, 62, 90, 100]], np.float32)
    task = {"targets": pickable, "unpickable": unpickable, "boxes": boxes, "scores": np.array([0.9, 0.95, 0.3])}
    labels, scores = copy_scores([task])
    assert labels.tolist() == [1, 0, 0]
    assert scores.tolist() == pytest.approx([0.95, 0.3, 0.0])  # the best of two on the first; none on the last


def test_first_choices_count_where_the_top_detection_lands_in_contested_bins():
    pickable, unpickable = np.array([[10, 10, 40, 40]], np.float32), np.array([[60, 60, 90, 100]], np.float32)
    contested = {"targets": pickable, "unpickable": unpickable}
    tasks = [contested | {"boxes": np.concatenate([unpickable, pickable]), "scores": np.array([0.9, 0.8])},  # unpickable first
             contested | {"boxes": np.concatenate([unpickable, pickable]), "scores": np.array([0.2, 0.8])},  # pickable first
             contested | {"boxes": np.array([[200, 200, 230, 230]], np.float32), "scores": np.array([0.9])},  # neither
             {"targets": pickable, "unpickable": np.zeros((0, 4), np.float32), "boxes": pickable, "scores": np.array([0.9])}]
    choices = first_choices(tasks)
    assert choices["contested_bins"] == 3  # the bin with no unpickable copy does not count
    assert choices["first_on_pickable"] == pytest.approx(1 / 3, abs=1e-4) and choices["first_on_unpickable"] == pytest.approx(1 / 3, abs=1e-4)
    assert choices["first_on_other"] == pytest.approx(1 / 3, abs=1e-4)


def test_ambiguous_instances_are_neither_hits_nor_false_positives():
    sure, unsure = np.array([[10, 10, 40, 40]], np.float32), np.array([[60, 60, 90, 100]], np.float32)
    # the detector ranks the instance whose trial grasps disagreed first
    task = {"certain": sure, "ambiguous": unsure, "boxes": np.concatenate([unsure, sure]), "scores": np.array([0.9, 0.8])}
    assert coco_ap([task], "certain", 128)["ap50"] < 0.6  # counted, it is a false positive above the target
    assert coco_ap([task], "certain", 128, ignore="ambiguous")["ap50"] == pytest.approx(1.0)
    only_unsure = {**task, "certain": np.zeros((0, 4), np.float32)}
    assert coco_ap([only_unsure], "certain", 128, ignore="ambiguous")["ap50"] is None


def test_a_shop_photo_query_must_find_the_picked_copy_too(tmp_path):
    from PIL import Image

    path = make_coco(tmp_path / "pick", images=6, pickable=True)
    coco = json.loads(path.read_text())
    for annotation in coco["annotations"][::3]:  # as in the warehouse data, the query is mostly a copy the robot held
        if annotation.get("is_query"):
            annotation["pickable"]["y"] = True
    path.write_text(json.dumps(coco))
    (tmp_path / "pick" / "photos").mkdir()
    for category in coco["categories"]:
        Image.new("RGB", (32, 32), (200, 40, 40)).save(tmp_path / "pick" / "photos" / f"{category['name']}.png")
    source = RepeatedInstances(path, targets="pickable:y")
    crop, photo = TaskDataset(source, 128, "crop"), TaskDataset(source, 128, "photo")
    assert 0 < sum(task.query["pickable"]["y"] for task in source.tasks) < len(source)
    for index, task in enumerate(source.tasks):
        picked = bool(task.query["pickable"]["y"])
        assert len(photo[index]["targets"]) == len(crop[index]["targets"]) + picked  # the crop query names its copy
        assert len(photo[index]["all"]) == len(task.annotations)


def test_pickable_rate_between_zero_and_one_marks_an_instance_ambiguous(tmp_path):
    path = make_coco(tmp_path / "pick", images=4, pickable=True)
    coco = json.loads(path.read_text())
    for number, annotation in enumerate(coco["annotations"]):
        if annotation.get("pickable"):
            annotation["pickable_rate"] = {"y": 0.6 if number % 2 else float(annotation["pickable"]["y"])}
    path.write_text(json.dumps(coco))
    source = RepeatedInstances(path, targets="pickable:y")
    counts = {"targets": 0, "certain": 0, "ambiguous": 0}
    for task in source.tasks:
        boxes = source.boxes(task, task.query)
        assert len(boxes["certain"]) <= len(boxes["targets"])
        counts = {k: v + len(boxes[k]) for k, v in counts.items()}
    assert counts["ambiguous"] > 0 and counts["certain"] < counts["targets"]
    sample = TaskDataset(source, 64, augment=True)[0]
    assert {"certain", "ambiguous"} <= set(sample)


def test_colour_histogram_finds_a_copy_of_the_same_colour():
    rng = np.random.default_rng(0)
    image = rng.integers(100, 130, (96, 96, 3)).astype(np.uint8)
    image[10:26, 10:26] = (200, 30, 30)
    image[60:76, 50:66] = (200, 30, 30)
    image[60:76, 10:26] = (30, 30, 200)  # another colour
    found = histogram_matches(image, np.array([10, 10, 26, 26], dtype=np.float32))
    assert found["boxes"].shape[0] >= 1
    assert box_iou(found["boxes"][:1], torch.tensor([[50.0, 60.0, 66.0, 76.0]]))[0, 0] > 0.5


def test_template_matching_finds_an_exact_copy():
    rng = np.random.default_rng(0)
    image = rng.integers(90, 140, (96, 96, 3)).astype(np.uint8)
    patch = rng.integers(0, 255, (14, 14, 3)).astype(np.uint8)
    image[10:24, 10:24] = patch
    image[60:74, 50:64] = patch
    found = template_matches(image, np.array([10, 10, 24, 24], dtype=np.float32))
    assert found["boxes"].shape[0] >= 1
    assert torch.allclose(found["boxes"][0], torch.tensor([50.0, 60.0, 64.0, 74.0]), atol=1.5)


def test_weights_list_the_products_of_the_runs_they_started_from(tmp_path):
    from binpick.detection.training_data import learnt_products

    path = make_coco(tmp_path / "toy", images=2)
    save_detector(DetectorNetwork(ModelSpec(), 64), tmp_path / "start.safetensors", {"trained_products": ["acme/soap"]})
    config = tmp_path / "fine.yaml"
    config.write_text(f"""name: fine
data: {{train: {path}, val: {path}, targets: all, image_size: 64}}
train: {{init_from: {tmp_path / 'start.safetensors'}}}
""")
    own = sorted(c["name"] for c in json.loads(path.read_text())["categories"])
    assert learnt_products(load_config(DetectConfig, config)) == sorted(own + ["acme/soap"])


def test_train_and_val_files_that_share_generated_scenes_are_refused(tmp_path):
    from binpick.detection.data import check_disjoint

    def with_seeds(folder, seeds):
        path = make_coco(folder, images=len(seeds))
        coco = json.loads(path.read_text())
        for image, seed in zip(coco["images"], seeds):
            image["seed"] = seed  # the generator's scene seed: one seed and world make the same scene
        path.write_text(json.dumps(coco))
        return RepeatedInstances(path)

    train = with_seeds(tmp_path / "a", [11, 12, 13, 14])
    other = with_seeds(tmp_path / "b", [21, 22, 23])
    check_disjoint(train, other)  # other scenes: fine
    check_disjoint(train, train)  # one file for both on purpose: an overfitting check
    shared = with_seeds(tmp_path / "c", [14, 31, 32])
    with pytest.raises(ConfigError, match=r"share 1 of 3 val scenes .*another --seed"):
        check_disjoint(train, shared)
    # evaluating weights on scenes their training set held says so
    from binpick.detection.detector import Detector

    save_detector(DetectorNetwork(ModelSpec(), 64), tmp_path / "w.safetensors",
                  {"config": {"data": {"train": str(train.path), "targets": "all"}}})
    assert Detector.load(tmp_path / "w.safetensors").val(shared.path)["scenes_trained_on"] == 1
    assert Detector.load(tmp_path / "w.safetensors").val(other.path)["scenes_trained_on"] == 0


def test_kmeans_anchors_recover_two_box_sizes():
    sizes = np.r_[np.tile([[10, 20]], (30, 1)), np.tile([[40, 40]], (30, 1))] + np.random.default_rng(0).normal(0, 0.5, (60, 2))
    anchors = kmeans_anchors(sizes, clusters=2)
    assert np.allclose(anchors, [[10, 20], [40, 40]], atol=1.5)


@pytest.mark.slow
def test_training_learns_the_toy_set_resumes_and_predicts(tmp_path):
    path = make_coco(tmp_path / "toy", images=16, seed=1)
    config = tmp_path / "rod.yaml"
    # fp32: in bfloat16 this 16-image toy run is chaotic (0.03 to 0.3 AP50 for numerically equal models)
    config.write_text(f"""name: toy
data: {{train: {path}, val: {path}, targets: all, image_size: 128, augment: false}}
train: {{epochs: 2, batch_size: 4, lr: 0.002, warmup_steps: 4, eval_every: 2, workers: 0, threads: 1, fast_cpu: false}}
""")
    trainer = DetectorTrainer.new(load_config(DetectConfig, config), tmp_path / "runs")
    trainer.run()
    assert (trainer.run_dir / "model.safetensors").is_file() and trainer.epoch == 2
    # resume: same run folder, more epochs, continues from epoch 2's checkpoint
    text = (trainer.run_dir / "config.yaml").read_text().replace("epochs: 2", "epochs: 25")
    (trainer.run_dir / "config.yaml").write_text(text)
    resumed = DetectorTrainer.resume(trainer.run_dir)
    assert resumed.epoch == 2 and resumed.step == trainer.step
    metrics = resumed.run()
    assert metrics["epochs"] == 25
    model = load_detector(trainer.run_dir)
    result = evaluate_model(model, TaskDataset(RepeatedInstances(path), 128))
    # learnt from 16 images in 25 short epochs: 0.30 measured on one CPU, 0.11 on an AMD EPYC (the same fp32 run
    # takes another path through this chaotic toy problem), from 0.0006 after 2 epochs on the EPYC
    first = next(record["ap50"] for record in metrics["history"] if "ap50" in record)  # after 2 epochs
    assert result["ap50"] > 0.05 and result["ap50"] > 10 * first, (result["ap50"], first)


def test_cli_predict_and_bad_input_are_one_line(tmp_path):
    make_coco(tmp_path / "toy", images=2)
    model = DetectorNetwork(ModelSpec(), 64)
    save_detector(model, tmp_path / "model.safetensors")
    image = str(tmp_path / "toy" / "images" / "0000.png")
    ok = binpick_here(["detect", "predict", image, "--weights", str(tmp_path / "model.safetensors"), "--query-box", "10,10,20,20",
                               "--min-score", "0", "--out", str(tmp_path / "predicted"), "--heatmap"])
    assert ok.returncode == 0, ok.stderr
    detections = json.loads(ok.stdout.strip().splitlines()[0])
    assert detections and set(detections[0]) == {"bbox", "score"}
    assert all((tmp_path / "predicted" / name).is_file() for name in ("overlay.png", "heatmap.png", "detections.json"))
    (tmp_path / "empty.png").write_bytes(b"")
    other = DetectorNetwork(ModelSpec(backbone="darknet53"), 64)
    torch.save({"format": "binpick-detector-1", "spec": {**ModelSpec().__dict__, "scales": [0.5, 1.0, 2.0]}, "image_size": 64,
                "weights": other.state_dict()}, tmp_path / "other.pt")
    cases = {
        ("--query-box", "10,10,0,20"): "zero area",
        ("--query-box", "100,100,90,20"): "outside",
        ("--query-box", "1,2,3"): "x,y,w,h",
    }
    for args, message in cases.items():
        bad = binpick_here(["detect", "predict", image, "--weights", str(tmp_path / "model.safetensors"), *args])
        assert bad.returncode == 2 and message in bad.stderr and "Traceback" not in bad.stderr, bad.stderr
    empty = binpick_here(["detect", "predict", str(tmp_path / "empty.png"), "--weights", str(tmp_path / "model.safetensors"),
                                  "--query-box", "1,1,5,5"])
    assert empty.returncode == 2 and "cannot read image" in empty.stderr
    foreign = binpick_here(["detect", "predict", image, "--weights", str(tmp_path / "other.pt"), "--query-box", "1,1,5,5"])
    assert foreign.returncode == 2 and "another architecture" in foreign.stderr and "Traceback" not in foreign.stderr


def test_shipped_weights_load_as_float32_and_predict(tmp_path):
    from importlib.resources import files

    from PIL import Image

    from binpick.detection.predict import predict

    path = files("binpick.detection") / "weights" / "rod_tiny_320.safetensors"
    assert path.stat().st_size < 15e6  # fp16, within the shipping budget
    model = load_detector(str(path))
    # the detector with its pickability head (binpick detect pickability), which reads depth and the query
    assert model.spec == ModelSpec(pickability="rgbd", pickability_query=True) and model.image_size == 320 and model.trained_config["data"]["targets"] == "pickable:y"
    assert model.trained_domains == ["default", "random"]  # pre-trained on randomised bins, fine-tuned on the default ones
    photo = load_detector(str(files("binpick.detection") / "weights" / "rod_photo_tiny_320.safetensors"))
    assert photo.spec.query == "photo" and photo.score_threshold == 0.1  # its own calibrated threshold for picking
    from binpick.detection.detector import PICKING, shipped_weights

    from binpick.detection.weights_file import read_detector_file

    picking = load_detector(shipped_weights(PICKING))  # the pipeline's: the photo detector chosen by its worst standard set
    _, meta = read_detector_file(shipped_weights(PICKING))
    shipping = meta["shipping"]  # how it was chosen (experiments/rod.py ship-best), kept with the weights
    assert picking.spec.query == "photo" and shipping["chosen"] in shipping["candidates"]
    assert min(shipping["scores"].values()) == max(shipping["candidates"].values())  # the highest worst set
    assert all(shipping["scores"][name] >= shipping["replaced"][name] for name in shipping["scores"]) or shipping["reason"]
    # a pickability head (a second look at each detection's window and depth) only where it raised the worst set
    assert (picking.spec.pickability == "rgbd") == shipping["chosen"].endswith("+pickability_head")
    assert set(photo.trained_products) == set(picking.trained_products)  # one network, shipped under both names
    assert next(model.parameters()).dtype == torch.float32  # stored as float16, used as float32
    # a synthetic scene: copies of one coloured shape; the prediction is well formed and in the image
    image = np.asarray(Image.open(make_coco(tmp_path, images=1).parent / "images" / "0000.png"))
    flat = np.full(image.shape[:2], 0.8, np.float32)  # a depth image: the head re-scores
    prediction = predict(model, image, np.array([5, 5, 20, 20], dtype=np.float32), score_threshold=0.0, depth=flat)
    assert len(prediction.boxes) > 0 and np.all(prediction.boxes[:, 2:] > 0)
    assert np.all(prediction.boxes[:, :2] >= -1) and np.all(prediction.boxes[:, 0] + prediction.boxes[:, 2] <= 129)


def test_the_inference_copy_detects_what_the_network_does_and_cannot_be_trained_or_saved(tmp_path):
    from binpick.detection.detector import Detector, shipped_weights

    torch.manual_seed(0)
    detector = Detector.load(shipped_weights("rod_tiny_320"))
    network, fast = detector.network, detector.inference_network
    assert fast is detector.inference_network and fast is not network  # made once, a copy
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in fast.modules())  # folded into the convolutions
    images, heights = torch.rand(2, 3, 320, 320), torch.rand(2, 1, 320, 320)
    query = torch.tensor([[40.0, 50.0, 90.0, 110.0], [150.0, 160.0, 210.0, 200.0]])
    with torch.no_grad():
        raw, raw_fast = network(images, query)["raw"], fast(images, query)["raw"]
        assert all(torch.allclose(a, b, atol=1e-3) for a, b in zip(raw, raw_fast))
        mine, theirs = network.detect(images, query, depth=heights)[0], fast.detect(images, query, depth=heights)[0]
    for a, b in zip(mine, theirs):  # the pickability head re-scores them alike
        assert torch.allclose(a["scores"], b["scores"], atol=1e-4) and torch.allclose(a["boxes"], b["boxes"], atol=1e-2)
    with pytest.raises(RuntimeError, match="inference copy"):
        fast.train()
    with pytest.raises(ValueError, match="cannot be saved"):
        save_detector(fast, tmp_path / "fast.safetensors")
    network.train()  # the network it came from still trains
    assert network.training and not fast.training


def test_shop_photos_are_framed_on_their_product():
    from binpick.detection.data import query_photo
    from binpick.detection.photos import framed_on_product, product_box

    photo = np.full((100, 120, 3), 245, np.uint8)  # a bright, plain studio background
    photo[30:50, 60:100] = (200, 40, 40)  # the product
    x1, y1, x2, y2 = product_box(photo)
    assert 57 <= x1 <= 60 and 98 <= x2 <= 103 and 27 <= y1 <= 30 and 48 <= y2 <= 53  # the product plus a small margin
    assert framed_on_product(photo).shape[:2] == (y2 - y1, x2 - x1)
    # a white product on white is found through the cut-out's alpha, not the colours
    white = np.dstack([np.full((100, 120, 3), 250, np.uint8), np.zeros((100, 120), np.uint8)])
    white[10:20, 10:40, 3] = 255
    height, width, channels = framed_on_product(white).shape
    assert 10 <= height <= 14 and 30 <= width <= 36 and channels == 3
    assert product_box(np.full((40, 40, 3), 250, np.uint8)) is None  # nothing to frame: the whole photo is kept
    assert framed_on_product(np.full((40, 40, 3), 250, np.uint8)).shape == (40, 40, 3)
    whole, framed = query_photo(photo, 32, framed=False), query_photo(photo, 32, framed=True)
    assert whole.shape == framed.shape == (32, 32, 3)
    assert (framed[..., 1] < 100).mean() > 0.7 > 0.2 > (whole[..., 1] < 100).mean()  # framed: mostly product


def test_photo_sizes_match_the_photo_at_each_size_and_load_from_crop_weights(tmp_path):
    from binpick.core.errors import ConfigError

    torch.manual_seed(0)
    spec = ModelSpec(query="photo", photo_sizes=(0.25, 0.5))
    model = DetectorNetwork(spec, 64).eval()
    scene = model.features(torch.rand(2, 3, 64, 64))
    queries = model.query_features(scene, None, torch.rand(2, 3, 96, 96))
    # per level, per sample: one kernel per photo size, from the photo resized to 16 and 32 px
    assert [len(level) for level in queries] == [2, 2, 2] and all(len(sample) == 2 for level in queries for sample in level)
    assert [tuple(k.shape[1:]) for k in queries[0][0]] == [(2, 2), (4, 4)]
    out = model(torch.rand(2, 3, 64, 64), None, torch.rand(2, 3, 96, 96))
    assert out["heatmaps"][0].shape == (2, 1, 8, 8) and float(out["heatmaps"][0].detach().abs().max()) <= 1.0 + 1e-5
    # in training, photos are normalised by the scenes' running statistics and leave them alone
    model.train()
    norm = next(m for m in model.backbone.modules() if isinstance(m, torch.nn.BatchNorm2d))
    scene = model.features(torch.rand(2, 3, 64, 64))
    statistics = norm.running_mean.clone()
    model.query_features(scene, None, torch.rand(2, 3, 96, 96))
    assert torch.equal(norm.running_mean, statistics) and norm.training
    # the weights are the crop-query network's (the query kind holds none): fine-tuning starts from them
    crop = DetectorNetwork(ModelSpec(), 64)
    model.load_state_dict(crop.state_dict())
    for bad in (ModelSpec(photo_sizes=(0.1,)), ModelSpec(query="photo", photo_sizes=(1.5,)),
                ModelSpec(query="photo", method="tdid", photo_sizes=(0.1,))):
        with pytest.raises(ConfigError, match="photo_sizes"):
            bad.check()


def test_the_learning_rate_anneals_by_max_minutes_when_that_comes_first(tmp_path):
    path = make_coco(tmp_path / "toy", images=4, seed=1)
    config = tmp_path / "rod.yaml"
    config.write_text(f"""name: toy
data: {{train: {path}, val: {path}, targets: all, image_size: 64, augment: false}}
train: {{epochs: 1000, batch_size: 2, lr: 0.002, warmup_steps: 2, max_minutes: 10, workers: 0}}
""")
    trainer = DetectorTrainer.new(load_config(DetectConfig, config), tmp_path / "runs")
    trainer.step = 10  # after the warm-up, early in the planned epochs
    trainer.note_time(0.0)
    assert trainer.learning_rate() == pytest.approx(0.002, rel=1e-3)
    trainer.note_time(300.0)  # half the time budget: half-way down the cosine
    assert trainer.learning_rate() == pytest.approx(0.002 * (0.05 + 0.95 * 0.5), rel=1e-3)
    trainer.note_time(600.0)
    assert trainer.learning_rate() == pytest.approx(0.002 * 0.05, rel=1e-3)


def test_early_stopping_ends_after_patience_evaluations_without_a_better_ap50_and_keeps_the_best(tmp_path, monkeypatch):
    from binpick.detection import train as detector_training

    path = make_coco(tmp_path / "toy", images=4, seed=1)
    config = tmp_path / "rod.yaml"
    config.write_text(f"""name: toy
data: {{train: {path}, val: {path}, targets: all, image_size: 64, augment: false}}
train: {{epochs: 20, batch_size: 2, warmup_steps: 1, eval_every: 2, patience: 2, keep_best: true, workers: 0, threads: 1}}
""")
    ap50 = iter([0.2, 0.5, 0.4, 0.5, 0.3, 0.9])  # evaluated at epochs 2, 4, 6, 8: best at 4, then two not better
    monkeypatch.setattr(detector_training, "evaluate_model", lambda *a, **k: dict.fromkeys(
        ("map", "ap50_all", "ap50_unpickable"), 0.0) | {"ap50": next(ap50)})
    trainer = DetectorTrainer.new(load_config(DetectConfig, config), tmp_path / "runs")
    metrics = trainer.run()
    assert metrics["epochs"] == 8 and [row.get("ap50") for row in metrics["history"]] == [None, 0.2, None, 0.5, None, 0.4, None, 0.5]
    assert trainer.best == 0.5 and (trainer.run_dir / "best.safetensors").is_file()
    assert "ap50" not in metrics["history"][0]  # an epoch not evaluated reports no AP at all


def test_a_depth_reading_detector_starts_as_its_colour_weights_and_learns_from_depth(tmp_path):
    from binpick.detection.predict import predict

    path = make_coco(tmp_path / "toy", images=8, seed=2, depth=True)
    # heights move with the image: augmented samples keep the tall objects inside their boxes
    dataset = TaskDataset(RepeatedInstances(path), 64, augment=True, depth=True)
    for epoch in range(3):
        dataset.set_epoch(epoch)
        sample = dataset[epoch]
        heights, inside = sample["depth"][0], torch.zeros(64, 64, dtype=torch.bool)
        for x1, y1, x2, y2 in sample["all"].round().int().tolist():
            inside[y1 + 1:y2 - 1, x1 + 1:x2 - 1] = True
        assert heights[inside].mean() > 0.5 > heights[~inside].mean(), (epoch, heights[inside].mean(), heights[~inside].mean())
    # colour-only weights load into a depth-reading network whose depth encoder starts at zero: the same boxes
    torch.manual_seed(0)
    colour = DetectorNetwork(ModelSpec(), 128).eval()
    save_detector(colour, tmp_path / "colour.safetensors")
    config = tmp_path / "rod.yaml"
    config.write_text(f"""name: toy_depth
data: {{train: {path}, val: {path}, targets: all, image_size: 128, augment: true, train_sizes: [96, 160]}}
model: {{depth: true}}
train: {{epochs: 1, batch_size: 4, lr: 0.002, warmup_steps: 2, eval_every: 1, workers: 0, threads: 1,
         init_from: {tmp_path / "colour.safetensors"}}}
""")
    trainer = DetectorTrainer.new(load_config(DetectConfig, config), tmp_path / "runs")
    batch = collate([trainer.val_set[0], trainer.val_set[1]])
    trainer.model.eval()
    with torch.no_grad():
        theirs = colour(batch["image"], batch["query_box"], batch["query_image"])["raw"]
        mine = trainer.model(batch["image"], batch["query_box"], batch["query_image"], batch["depth"])["raw"]
    assert all(torch.allclose(a, b, atol=1e-4) for a, b in zip(mine, theirs))
    trainer.run()
    model = load_detector(trainer.run_dir)
    assert model.spec.depth and any(float(p.detach().abs().sum()) > 0 for p in model.depth_encoder.projections.parameters())
    image, depth = tmp_path / "toy" / "images" / "0000.png", tmp_path / "toy" / "depth" / "0000.png"
    box = next(a["bbox"] for a in json.loads(path.read_text())["annotations"] if a["image_id"] == 1)
    assert len(predict(model, image, np.array(box), depth=depth, score_threshold=0.0).scores) > 0
    with pytest.raises(ConfigError, match="reads depth"):
        predict(model, image, np.array(box))
    with pytest.raises(ConfigError, match="no depth file"):
        TaskDataset(RepeatedInstances(make_coco(tmp_path / "plain", images=2)), 64, depth=True)


def test_rehearsal_mixes_fresh_tasks_of_a_second_set_into_each_epoch(tmp_path):
    from binpick.detection.training_data import make_datasets

    main, other = make_coco(tmp_path / "main", images=6, seed=1), make_coco(tmp_path / "other", images=12, seed=2)
    config = tmp_path / "rod.yaml"
    body = f"""name: toy
data: {{train: {main}, val: {main}, targets: all, image_size: 64, rehearse: {other}, rehearse_per_epoch: 4}}
"""
    config.write_text(body)
    train, _ = make_datasets(load_config(DetectConfig, config))
    assert len(train) == len(train.main) + 4 and train.source is train.main.source
    drawn = []
    for epoch in (0, 1, 0):
        train.set_epoch(epoch)
        drawn.append(sorted(train.drawn.tolist()))
        assert torch.equal(train[len(train) - 1]["image"], train.rehearsal[int(train.drawn[-1])]["image"])
        assert torch.equal(train[0]["image"], train.main[0]["image"])
    assert drawn[0] == drawn[2] and drawn[0] != drawn[1]  # fresh each epoch, the same on a resume
    assert len(collate([train[0], train[len(train) - 1]])["targets"]) == 2
    config.write_text(body.replace("rehearse_per_epoch: 4", "rehearse_per_epoch: 0"))
    with pytest.raises(ConfigError, match="data.rehearse and data.rehearse_per_epoch go together"):
        load_config(DetectConfig, config)


def test_a_run_killed_within_an_epoch_resumes_from_its_last_checkpoint_there_to_the_same_weights(tmp_path, monkeypatch):
    path = make_coco(tmp_path / "toy", images=4, seed=2)
    config = tmp_path / "rod.yaml"
    config.write_text(f"""name: toy
data: {{train: {path}, val: {path}, targets: all, image_size: 64, augment: false}}
train: {{epochs: 2, batch_size: 2, lr: 0.002, warmup_steps: 2, eval_every: 2, workers: 0, threads: 1, fast_cpu: false,
         checkpoint_minutes: 0.000001}}
""")
    torch.manual_seed(0)
    whole = DetectorTrainer.new(load_config(DetectConfig, config), tmp_path / "whole")
    whole.run()
    assert whole.step == 4  # 2 batches an epoch, 2 epochs

    class Killed(Exception):
        pass

    real = DetectorTrainer.train_step

    def dies_at_the_second(self, batch, sums):
        if self.step == 1:  # its machine goes away in the second step of the first epoch
            raise Killed
        real(self, batch, sums)

    torch.manual_seed(0)
    killed = DetectorTrainer.new(load_config(DetectConfig, config), tmp_path / "killed")
    monkeypatch.setattr(DetectorTrainer, "train_step", dies_at_the_second)
    with pytest.raises(Killed):
        killed.run()
    monkeypatch.setattr(DetectorTrainer, "train_step", real)
    resumed = DetectorTrainer.resume(killed.run_dir)
    assert (resumed.epoch, resumed.step, resumed.resumed_batches) == (0, 1, 1)  # the checkpoint after its first batch
    resumed.run()
    assert resumed.step == 4  # the epoch's other batch, then the second epoch: none trained twice
    for (name, a), b in zip(whole.model.state_dict().items(), resumed.model.state_dict().values()):
        assert torch.allclose(a.float(), b.float(), atol=1e-5), name  # the same weights as the run never killed


def test_a_shop_photo_is_rendered_once_and_again_when_its_mesh_changes(tmp_path, monkeypatch):
    """Every data set, order and export takes every product's photos again: the second one is the first
    one's copy (one changed by its caller changes nothing), another process reads a catalogue photo from
    the cache folder, a damaged cache file is rendered again, and a product whose mesh file changed on
    disk is rendered again."""
    import os

    from binpick.sim import photos
    from binpick.sim.products import Product
    from test_own_products import write_box

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    mesh = tmp_path / "box.obj"
    write_box(mesh, 0.09, 0.05, 0.03)
    product = Product(id="mine/box", category="box", mesh=mesh, rgba=(0.8, 0.2, 0.2, 1.0))
    rendered = []
    real = photos._render_photo
    monkeypatch.setattr(photos, "_render_photo", lambda *args: rendered.append(args) or real(*args))
    first = photos.shop_photo(product, 48)
    first[:] = 0  # the caller's copy
    second = photos.shop_photo(product, 48)
    assert len(rendered) == 1 and second.max() > 0 and second.flags.writeable
    (kept,) = (tmp_path / "cache" / "binpick" / "photos").glob("*.npz")
    photos._cached_photo.cache_clear()  # as another process: read from the cache folder, not rendered
    assert (photos.shop_photo(product, 48) == second).all() and len(rendered) == 1
    kept.write_bytes(b"not an archive")
    photos._cached_photo.cache_clear()
    assert (photos.shop_photo(product, 48) == second).all() and len(rendered) == 2  # rendered again, and kept again
    image, mask = photos.shop_photo(product, 48, with_mask=True)  # another picture: rendered
    assert len(rendered) == 3 and mask.any() and (image == second).all()
    write_box(mesh, 0.03, 0.05, 0.09)  # the user's mesh changed: rendered again, and it shows
    os.utime(mesh, ns=(mesh.stat().st_atime_ns, mesh.stat().st_mtime_ns + 10**9))
    third = photos.shop_photo(product, 48)
    assert len(rendered) == 4 and not (third == second).all()
    random_studio = photos.random_photo_style(np.random.default_rng(0))  # not a catalogue view: not kept on disk
    photos.shop_photo(product, 48, style=random_studio)
    from dataclasses import replace

    from binpick.sim.products import RANDOM_ID_PREFIX

    photos.shop_photo(replace(product, id=f"{RANDOM_ID_PREFIX}000001_0"), 48)  # one world's product: taken once
    assert len(list((tmp_path / "cache" / "binpick" / "photos").glob("*.npz"))) == 3
    monkeypatch.setenv("XDG_CACHE_HOME", str(mesh))  # a cache "folder" that is a file: rendered, not kept, no error
    photos._cached_photo.cache_clear()
    assert (photos.shop_photo(product, 48) == third).all() and len(rendered) == 7

"""The detector's second look (binpick.detection.pickability): windows cut where the boxes are, a head
that learns which copies a policy picks, resumes, ships inside the detector and re-scores its boxes."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from binpick.detection.detector import Detector
from binpick.detection.model import DetectorNetwork, ModelSpec
from binpick.detection.pickability import CROP, WINDOW, PickabilityHead, head_auc, query_crops, roi_windows, train_epoch
from binpick.detection.pickability_training import PickabilityConfig, PickabilityTrainer
from binpick.detection.weights_file import save_detector
from binpick.core.errors import ConfigError
from binpick.core.metrics import roc_auc
from synthetic_coco import make_coco


def test_windows_are_centred_on_the_box_with_its_mask_and_zeros_outside_the_image():
    size = 128
    image = torch.zeros(1, 3, size, size)
    image[0, 0, 60:70, 40:50] = 1.0  # a red patch
    heights = torch.zeros(1, 1, size, size)
    heights[0, 0, 60:70, 40:50] = 2.0
    boxes = torch.tensor([[40.0, 60.0, 50.0, 70.0], [0.0, 0.0, 10.0, 10.0]])
    windows = roi_windows(image, heights, boxes, torch.tensor([0, 0]))
    assert windows.shape == (2, 5, CROP, CROP)
    middle = CROP // 2
    assert windows[0, 0, middle, middle] > 0.9 and windows[0, 3, middle, middle] > 1.8  # colour and height at the centre
    mask = windows[0, 4] > 0.5
    side = WINDOW * size  # pixels of the image the window spans
    assert abs(mask.sum().item() - (10 * CROP / side) ** 2) < 3 * 10 * CROP / side  # the 10 x 10 box, resampled
    assert windows[1, :3, :middle - 2, :middle - 2].abs().max() == 0  # beyond the image's corner: zeros
    assert roi_windows(image, None, boxes, torch.tensor([0, 0])).shape == (2, 4, CROP, CROP)


def test_windows_of_other_products_are_negatives_that_only_the_query_can_explain(tmp_path):
    from binpick.detection.data import RepeatedInstances, TaskDataset
    from binpick.detection.pickability import labelled_windows

    coco = make_coco(tmp_path / "data", images=4, seed=5, pickable=True, depth=True)
    dataset = TaskDataset(RepeatedInstances(coco, targets="pickable:y"), 128, depth=True)
    copies = labelled_windows(dataset, jittered=0)
    sample = dataset[0]
    assert len(sample["other_products"]) == 1  # make_coco puts one copy of another shape in each image
    both = labelled_windows(dataset, jittered=0, distractors=True)
    others = sum(len(dataset[i]["other_products"]) for i in range(len(dataset)))
    assert len(both["labels"]) == len(copies["labels"]) + others
    assert both["labels"].sum() == copies["labels"].sum()  # every added window is a negative
    assert len(both["queries"]) == len(dataset) and int(both["owner"].max()) == len(dataset) - 1
    # which windows hold a copy of the query's product, picked or not: all but the distractors
    assert torch.equal(copies["same"], torch.ones(len(copies["labels"])))
    assert both["same"].sum() == len(copies["labels"]) and bool((both["labels"] <= both["same"]).all())


def test_roc_auc_counts_ties_half():
    assert roc_auc(np.array([1, 1, 0, 0]), np.array([0.9, 0.8, 0.2, 0.1])) == 1.0
    assert roc_auc(np.array([1, 0]), np.array([0.5, 0.5])) == 0.5
    assert roc_auc(np.array([1, 0, 1, 0]), np.array([0.1, 0.9, 0.4, 0.3])) == 0.25


@pytest.mark.slow
def test_the_head_learns_which_copies_are_picked_resumes_and_rescores_the_detector(tmp_path):
    train = make_coco(tmp_path / "train", images=40, seed=3, pickable=True, depth=True, pickable_rule="small")
    val = make_coco(tmp_path / "val", images=12, seed=4, pickable=True, depth=True, pickable_rule="small")
    torch.manual_seed(0)
    save_detector(DetectorNetwork(ModelSpec(), 128), tmp_path / "detector.safetensors")
    config = PickabilityConfig(detector=str(tmp_path / "detector.safetensors"), train=[str(train)], val=str(val),
                               epochs=2, batch_size=16, lr=0.003, width=8, jittered=2, proposals=5, threads=1, query=True,
                               distractors=True)
    trainer = PickabilityTrainer.new(config, tmp_path / "runs")
    trainer.run()
    assert trainer.epoch == 2 and (trainer.run_dir / "windows.safetensors").is_file()
    # resume: the same run folder, more epochs, from epoch 2's checkpoint and the windows cut once
    text = (trainer.run_dir / "config.yaml").read_text().replace("epochs: 2", "epochs: 12")
    (trainer.run_dir / "config.yaml").write_text(text)
    resumed = PickabilityTrainer.resume(trainer.run_dir)
    assert resumed.epoch == 2
    metrics = resumed.run()
    assert metrics["epochs"] == 12
    assert metrics["best_val_auc"] > 0.85, metrics["history"]  # the small copies are told from the large
    # the detector with its head: the same boxes, each score times the head's probability
    detector = Detector.load(trainer.run_dir / "model.safetensors")
    assert detector.network.spec.pickability == "rgbd" and detector.network.spec.pickability_query
    plain = Detector.load(tmp_path / "detector.safetensors").network
    image, depth = tmp_path / "val" / "images" / "0000.png", tmp_path / "val" / "depth" / "0000.png"
    box = next(a["bbox"] for a in json.loads(val.read_text())["annotations"] if a["image_id"] == 1)
    from binpick.detection.predict import predict

    mine = predict(detector.network, image, np.array(box), depth=depth, score_threshold=0.0)
    theirs = predict(plain, image, np.array(box), score_threshold=0.0)
    assert len(mine.scores) and len(mine.scores) == len(theirs.scores)
    assert np.all(mine.scores <= theirs.scores.max() + 1e-6) and np.all(np.diff(mine.scores) <= 1e-7)
    with pytest.warns(UserWarning, match="without its pickability head"):  # no depth: the detector's own scores
        alone = predict(detector.network, image, np.array(box), score_threshold=0.0)
    assert np.allclose(alone.scores, theirs.scores)
    with pytest.raises(ConfigError, match="pickability head reads depth"):  # the network itself insists
        detector.network.detect(torch.zeros(1, 3, 128, 128), torch.tensor([[10.0, 10, 40, 40]]), torch.zeros(1, 3, 96, 96),
                                score_threshold=0.0)
    # left out on request: the detector's own ranking, from colour alone
    without = Detector.load(trainer.run_dir / "model.safetensors", pickability=False)
    again = without.predict(image, box, min_score=0.0)
    assert np.allclose(again.scores, theirs.scores)  # (boxes of equal scores may come in another order)
    assert np.allclose(np.sort(again.boxes, axis=0), np.sort(theirs.boxes, axis=0))
    assert detector.network.pickability is not None  # switching it off made a copy
    assert detector.val(val, targets="pickable:y")["tasks"] == 12
    # another run can start from this head (a warm start), and refuses a head of another kind
    from dataclasses import replace

    warm = PickabilityTrainer.new(replace(config, init=str(trainer.run_dir / "model.safetensors")), tmp_path / "runs")
    trained = detector.network.pickability.state_dict()
    assert all(torch.allclose(v.float(), trained[k].float(), atol=1e-2) for k, v in warm.head.state_dict().items())
    with pytest.raises(ConfigError, match="not of this config's kind"):
        PickabilityTrainer.new(replace(config, init=str(trainer.run_dir / "model.safetensors"), query=False), tmp_path / "runs")
    with pytest.raises(ConfigError, match="holds no pickability head"):
        PickabilityTrainer.new(replace(config, init=str(tmp_path / "detector.safetensors")), tmp_path / "runs")
    with pytest.raises(ConfigError, match="targets must be pickable"):
        PickabilityConfig(targets="all")
    # a factorised head starts from a head that sees the query: its `same` question from it, `pick` afresh
    factorised = PickabilityTrainer.new(replace(config, init=str(trainer.run_dir / "model.safetensors"), factorised=True), tmp_path / "runs")
    assert factorised.head.pick is not None and factorised.network.spec.pickability_factorised
    assert all(torch.allclose(v.float(), trained[k].float(), atol=1e-2) for k, v in factorised.head.state_dict().items() if not k.startswith("pick."))
    factorised.run()  # its windows say which hold the query's product; the saved detector rebuilds the factorised head
    loaded = Detector.load(factorised.run_dir)
    assert loaded.network.spec.pickability_factorised and loaded.network.pickability.pick is not None
    assert len(loaded.predict(image, box, min_score=0.0, depth=depth).scores) == len(theirs.scores)
    with pytest.raises(ConfigError, match="factorised needs query"):
        PickabilityConfig(factorised=True)


def _coloured(colours: torch.Tensor, channels: int) -> torch.Tensor:
    """Windows (or query crops) with a square of the given palette colour at their centre."""
    palette = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 1.0, 0]])
    x = torch.zeros(len(colours), channels, CROP, CROP)
    x[:, :3, 24:40, 24:40] = palette[colours][:, :, None, None]
    if channels == 5:
        x[:, 4, 24:40, 24:40] = 1.0  # the box mask
    return x


def test_a_head_that_sees_the_query_tells_the_ordered_product_from_others_and_one_without_cannot():
    generator = torch.Generator().manual_seed(0)
    n = 512
    window_colour = torch.randint(0, 4, (n,), generator=generator)
    query_colour = torch.randint(0, 4, (n,), generator=generator)
    windows = _coloured(window_colour, 5)
    stored = {"colour": (torch.cat([windows[:, :3], windows[:, 4:]], 1) * 255).to(torch.uint8),
              "height": torch.zeros(n, 1, CROP, CROP, dtype=torch.float16),
              "labels": (window_colour == query_colour).float(),  # a copy of the ordered product or not
              "queries": (_coloured(query_colour, 3) * 255).to(torch.uint8), "owner": torch.arange(n, dtype=torch.int32)}
    aucs = {}
    for query in (True, False):
        torch.manual_seed(0)
        head = PickabilityHead(depth=True, width=8, query=query)
        optimiser = torch.optim.Adam(head.parameters(), lr=0.003)
        schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, lambda step: 1.0)
        for epoch in range(6):
            train_epoch(head, optimiser, schedule, stored, torch.Generator().manual_seed(epoch), batch=32)
        aucs[query] = head_auc(head, stored)
    assert aucs[True] > 0.95 and aucs[False] < 0.7, aucs  # only the query says which colour was ordered
    with pytest.raises(ValueError, match="give the query crops"):
        PickabilityHead(width=8, query=True)(torch.zeros(1, 5, CROP, CROP))


def test_a_factorised_head_answers_picks_it_from_the_window_and_same_product_from_the_query():
    from binpick.detection.pickability import product_logit

    a, b = torch.linspace(-30, 30, 61), torch.linspace(30, -30, 61)
    assert torch.allclose(torch.sigmoid(product_logit(a, b)), torch.sigmoid(a) * torch.sigmoid(b), atol=1e-6)
    generator = torch.Generator().manual_seed(0)
    n = 512
    window_colour = torch.randint(0, 4, (n,), generator=generator)
    query_colour = torch.randint(0, 4, (n,), generator=generator)
    picks = torch.rand(n, generator=generator) < 0.6  # what the policy did: seen in the window's height plane
    windows = _coloured(window_colour, 5)
    windows[:, 3] = picks[:, None, None].float()
    same = (window_colour == query_colour).float()
    stored = {"colour": (torch.cat([windows[:, :3], windows[:, 4:]], 1) * 255).to(torch.uint8),
              "height": windows[:, 3:4].half(), "labels": same * picks.float(), "same": same,
              "queries": (_coloured(query_colour, 3) * 255).to(torch.uint8), "owner": torch.arange(n, dtype=torch.int32)}
    torch.manual_seed(0)
    head = PickabilityHead(depth=True, width=8, query=True, factorised=True)
    optimiser = torch.optim.Adam(head.parameters(), lr=0.001)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, lambda step: 1.0)
    for epoch in range(6):
        train_epoch(head, optimiser, schedule, stored, torch.Generator().manual_seed(epoch), batch=32)
    assert head_auc(head, stored) > 0.95  # the product answers the whole question
    head.eval()
    with torch.no_grad():
        pick, same_logit = head.parts(windows, _coloured(query_colour, 3))
    copies = same > 0.5
    assert roc_auc(picks[copies].numpy(), pick[copies].numpy()) > 0.95  # `pick` learnt pickability, on copies only
    assert roc_auc(same.numpy(), same_logit.numpy()) > 0.95  # `same` learnt the product, from the query
    with pytest.raises(ValueError, match="needs query=True"):
        PickabilityHead(width=8, factorised=True)


def test_query_crops_cut_the_query_box_or_resize_the_photo():
    image = torch.zeros(1, 3, 128, 128)
    image[0, 1, 32:64, 64:96] = 1.0  # a green square: the query box
    crop = query_crops(image, torch.tensor([[64.0, 32.0, 96.0, 64.0]]), None)
    assert crop.shape == (1, 3, CROP, CROP) and crop[0, 1, 4:-4, 4:-4].min() > 0.99 and crop[0, 0].max() == 0
    photo = torch.rand(1, 3, 96, 96)
    assert query_crops(image, None, photo).shape == (1, 3, CROP, CROP)


@pytest.mark.parametrize("query_mode", ["crop", "photo"])
def test_rescoring_reranks_every_detection_and_keeps_them_all(query_mode):
    torch.manual_seed(0)
    network = DetectorNetwork(ModelSpec(query=query_mode, pickability="rgbd", pickability_query=True), 128).eval()
    images, depth = torch.rand(1, 3, 128, 128), torch.rand(1, 1, 128, 128)
    boxes, photos = torch.tensor([[10.0, 10, 40, 40]]), torch.rand(1, 3, 96, 96)
    everything, _ = network.without_pickability().detect(images, boxes, photos, score_threshold=0.0)
    threshold = float(everything[0]["scores"].median())  # about half the detector's boxes pass it
    mine, _ = network.detect(images, boxes, photos, score_threshold=threshold, depth=depth)
    theirs, _ = network.without_pickability().detect(images, boxes, photos, score_threshold=threshold)
    assert len(theirs[0]["scores"]) > 0 and (mine[0]["scores"] < threshold).any()  # re-scored below it, still there
    assert len(mine[0]["scores"]) == len(theirs[0]["scores"])  # the head re-ranks; the detector decides what was found
    assert torch.all(mine[0]["scores"][:-1] >= mine[0]["scores"][1:])
    assert mine[0]["scores"].max() <= theirs[0]["scores"].max()
    # predict, as the picker calls it, keeps them too: a head that doubts every box (as one learnt on
    # default bins does under another camera) must not leave the picker without candidates
    from binpick.detection.predict import predict

    torch.nn.init.constant_(network.pickability.classify[-1].bias, -20.0)
    picture = (images[0].permute(1, 2, 0) * 255).to(torch.uint8).numpy()
    query = dict(query_box=np.array([10.0, 10, 30, 30])) if query_mode == "crop" else dict(query_image=(photos[0].permute(1, 2, 0) * 255).to(torch.uint8).numpy())
    doubted = predict(network, picture, **query, score_threshold=threshold, depth=depth[0, 0].numpy() * 0.05 + 0.8)
    plain = predict(network.without_pickability(), picture, **query, score_threshold=threshold)
    assert len(plain.scores) > 0 and len(doubted.scores) == len(plain.scores) and doubted.scores.max() < 1e-6


def test_a_photo_detector_s_head_learns_from_photos_framed_as_predict_frames_them(tmp_path):
    """Proposals and the head's queries come from the trainer's tasks: for a detector that frames
    shop photos on their product (``photo_sizes``), training must frame them too, or the head learns
    on queries it never sees at ``predict``."""
    from binpick.detection.pickability_training import PickabilityTrainer

    train_file = make_coco(tmp_path / "train", images=4, seed=5, pickable=True, depth=True)
    val_file = make_coco(tmp_path / "val", images=4, seed=6, pickable=True, depth=True)
    from PIL import Image

    for data in (train_file, val_file):  # a shop photo per product, for the photo detector's tasks
        (data.parent / "photos").mkdir(exist_ok=True)
        for category in json.loads(data.read_text())["categories"]:
            Image.new("RGB", (32, 32), (200, 40, 40)).save(data.parent / "photos" / f"{category['name']}.png")
    framing = ModelSpec(query="photo", photo_sizes=(0.1, 0.2))
    for spec, framed in ((framing, True), (ModelSpec(), False)):
        path = tmp_path / f"detector_{framed}.safetensors"
        save_detector(DetectorNetwork(spec, 128), path)
        config = PickabilityConfig(detector=str(path), train=[str(train_file)], val=str(val_file), epochs=1, width=8, threads=1)
        trainer = PickabilityTrainer(config, tmp_path / f"run_{framed}")
        train, _ = trainer._sources()
        assert trainer.task_set(train[0]).frame_photos is framed

"""The recurrent repeated-object detector (thesis §5.2): its losses, its boxes, a run that resumes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from synthetic_coco import make_coco

from binpick.detection.recurrent import (LossWeights, RecurrentDetector, RecurrentSpec, box_masks, mask_box, recurrent_loss,
                                         soft_iou)
from binpick.core.errors import BinpickError, ConfigError


def test_soft_iou_is_zero_for_the_same_mask_and_one_for_disjoint_ones():
    a = box_masks(torch.tensor([[0.0, 0.0, 8.0, 8.0]]), 16, 16, 1.0)
    b = box_masks(torch.tensor([[9.0, 9.0, 15.0, 15.0]]), 16, 16, 1.0)
    assert soft_iou(a, a).item() == pytest.approx(0.0, abs=1e-6)
    assert soft_iou(a, b).item() == pytest.approx(1.0, abs=1e-6)


def test_mask_box_is_the_largest_blob():
    mask = np.zeros((20, 20), dtype=bool)
    mask[2:4, 2:4] = True  # a speck
    mask[8:16, 5:12] = True
    assert mask_box(mask) == [5.0, 8.0, 12.0, 16.0]
    assert mask_box(np.zeros((5, 5), dtype=bool)) is None


def _perfect_output(model: RecurrentDetector, boxes: torch.Tensor, steps: int) -> dict[str, torch.Tensor]:
    """Outputs whose masks are the given boxes, in the given order, with confident logits."""
    side = model.image_size // 4
    masks = box_masks(boxes, side, side, 0.25)
    logits = torch.where(masks > 0, torch.tensor(20.0), torch.tensor(-20.0))
    padded = torch.full((steps, side, side), -20.0)
    padded[: len(boxes)] = logits
    deepest = torch.rand(1, 256, model.image_size // 32, model.image_size // 32)
    return {"masks": padded[None], "stops": torch.zeros(1, steps), "deepest": deepest}


def test_segmentation_loss_ignores_the_order_of_the_copies_and_vanishes_when_every_step_finds_one():
    torch.manual_seed(0)
    model = RecurrentDetector(RecurrentSpec(), 128)
    boxes = torch.tensor([[8.0, 8.0, 40.0, 40.0], [60.0, 60.0, 100.0, 96.0], [10.0, 80.0, 40.0, 120.0]])
    out = _perfect_output(model, boxes, 4)
    weights = LossWeights()
    in_order = recurrent_loss(model, out, [boxes], [torch.zeros(0, 4)], weights)
    shuffled = recurrent_loss(model, out, [boxes[[2, 0, 1]]], [torch.zeros(0, 4)], weights)
    assert in_order["seg"].item() == pytest.approx(0.0, abs=1e-3)
    assert shuffled["seg"].item() == pytest.approx(in_order["seg"].item(), abs=1e-6)
    # the same copy found at every step is not rewarded: two of three steps then miss their copy
    same = _perfect_output(model, boxes[[0, 0, 0]], 4)
    repeated = recurrent_loss(model, same, [boxes], [torch.zeros(0, 4)], weights)
    assert repeated["seg"].item() > 0.5


def test_stop_targets_say_go_on_for_each_copy_and_stop_after():
    model = RecurrentDetector(RecurrentSpec(), 128)
    boxes = torch.tensor([[8.0, 8.0, 40.0, 40.0], [60.0, 60.0, 100.0, 96.0]])
    out = _perfect_output(model, boxes, 4)
    out["stops"] = torch.tensor([[20.0, 20.0, -20.0, -20.0]])
    good = recurrent_loss(model, out, [boxes], [torch.zeros(0, 4)], LossWeights())["stop"].item()
    out["stops"] = torch.tensor([[20.0, -20.0, 20.0, -20.0]])
    bad = recurrent_loss(model, out, [boxes], [torch.zeros(0, 4)], LossWeights())["stop"].item()
    assert good < 1e-3 < 1.0 < bad


def test_repetition_loss_moves_the_decoder_not_the_similarity_network_and_the_contrastive_loss_the_reverse():
    torch.manual_seed(0)
    model = RecurrentDetector(RecurrentSpec(), 128)
    images, boxes = torch.rand(1, 3, 128, 128), torch.tensor([[8.0, 8.0, 40.0, 40.0], [60.0, 60.0, 100.0, 96.0]])
    out = model(images, boxes[:1], 3)
    losses = recurrent_loss(model, out, [boxes], [torch.tensor([[10.0, 70.0, 40.0, 110.0]])], LossWeights())
    losses["rep"].backward(retain_graph=True)
    assert all(p.grad is None for p in model.similarity.parameters())
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in model.cells.parameters())
    model.zero_grad()
    losses["con"].backward()
    assert all(p.grad is None or p.grad.abs().sum() == 0 for p in model.cells.parameters())
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in model.similarity.parameters())


def test_detections_are_the_boxes_round_each_steps_mask_scored_by_its_stop_flag(monkeypatch):
    model = RecurrentDetector(RecurrentSpec(max_steps=3), 128).eval()
    side = 32  # the mask grid: a quarter of the image's side
    masks = torch.full((1, 3, side, side), -10.0)
    masks[0, 0, 2:6, 3:9] = 10.0  # cells x 3-8, y 2-5 -> pixels (12, 8, 36, 24)
    masks[0, 2, 28:32, 30:32] = 10.0  # at the image's corner
    stops = torch.tensor([[3.0, 0.0, -1.0]])
    monkeypatch.setattr(model, "forward", lambda images, boxes, steps=None: {"masks": masks, "stops": stops, "deepest": None})
    result = model.detect(torch.rand(1, 3, 128, 128), torch.tensor([[8.0, 8.0, 40.0, 40.0]]))[0]
    assert result["boxes"].tolist() == [[12.0, 8.0, 36.0, 24.0], [120.0, 112.0, 128.0, 128.0]]  # step 2 found nothing
    assert result["scores"].tolist() == pytest.approx([torch.sigmoid(torch.tensor(3.0)).item(), torch.sigmoid(torch.tensor(-1.0)).item()])


def test_an_untrained_network_gives_finite_boxes_inside_the_image():
    torch.manual_seed(0)
    model = RecurrentDetector(RecurrentSpec(max_steps=4), 128).eval()
    with torch.no_grad():
        model.mask_head[-1].bias.fill_(5.0)  # every step's mask covers something
    results = model.detect(torch.rand(2, 3, 128, 128), torch.tensor([[8.0, 8.0, 40.0, 40.0]] * 2))
    assert [len(r["boxes"]) for r in results] == [4, 4]
    for result in results:
        assert torch.isfinite(result["boxes"]).all() and (result["boxes"] >= 0).all() and (result["boxes"] <= 128).all()


def test_one_batch_is_learnt():
    torch.manual_seed(0)
    model = RecurrentDetector(RecurrentSpec(max_steps=3), 64)
    images = torch.rand(2, 3, 64, 64)
    images[:, :, 8:24, 8:24] = torch.tensor([0.9, 0.1, 0.1])[:, None, None]
    images[:, :, 36:56, 30:50] = torch.tensor([0.9, 0.1, 0.1])[:, None, None]
    boxes = torch.tensor([[8.0, 8.0, 24.0, 24.0], [30.0, 36.0, 50.0, 56.0]])
    optimiser = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(25):
        out = model(images, boxes[:1].repeat(2, 1), 3)
        loss = recurrent_loss(model, out, [boxes, boxes], [torch.zeros(0, 4)] * 2, LossWeights())
        optimiser.zero_grad()
        loss["total"].backward()
        optimiser.step()
        losses.append(loss["seg"].item())
    assert losses[-1] < 0.7 * losses[0]


def _config(data, out, images):
    from binpick.detection.recurrent_training import RecurrentTrainConfig

    return RecurrentTrainConfig(train=str(data), val=str(data), out=str(out), image_size=128, images=images,
                                batch_size=4, lr=3e-3, checkpoint_every=2, threads=1, val_tasks=4, photometric=False)


def test_a_killed_run_resumes_where_it_stopped_and_ends_as_an_unbroken_one(tmp_path):
    from binpick.detection.recurrent_training import CHECKPOINT, load_recurrent, train_recurrent
    from binpick.core.runs import RunCallback

    data = make_coco(tmp_path / "data", images=10, size=128)  # 10 tasks: two whole batches of 4 per epoch
    unbroken = train_recurrent(_config(data, tmp_path / "unbroken", 24))
    assert unbroken["images_seen"] == 24 and len(unbroken["history"]) == 3

    class Kill(RunCallback):
        def message(self, text: str) -> None:
            raise KeyboardInterrupt  # after the first checkpoint: steps 3-6 never ran

    with pytest.raises(KeyboardInterrupt):
        train_recurrent(_config(data, tmp_path / "killed", 24), Kill())
    assert (tmp_path / "killed" / CHECKPOINT).is_file() and not (tmp_path / "killed" / "recurrent.safetensors").exists()
    resumed = train_recurrent(_config(data, tmp_path / "killed", 24))
    assert resumed["history"] == [{**row, "seconds": r["seconds"]} for row, r in zip(unbroken["history"], resumed["history"])]
    a, b = load_recurrent(tmp_path / "unbroken"), load_recurrent(tmp_path / "killed")
    assert all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))
    assert a.image_size == 128 and a.spec == RecurrentSpec()
    # another budget is another run: refused with one line, not silently mixed
    with pytest.raises(ConfigError, match="another configuration"):
        train_recurrent(_config(data, tmp_path / "killed", 32))
    (tmp_path / "bad.safetensors").write_bytes(b"not a file")
    with pytest.raises(BinpickError, match="not a safetensors file"):
        load_recurrent(tmp_path / "bad.safetensors")


def test_bad_settings_are_one_line():
    from binpick.detection.recurrent_training import RecurrentTrainConfig

    with pytest.raises(ConfigError, match="image_size"):
        RecurrentTrainConfig(train="a.json", val="b.json", image_size=100)
    with pytest.raises(ConfigError, match="max_steps"):
        RecurrentSpec(max_steps=0).check()
    with pytest.raises(ConfigError, match="gamma"):
        from binpick.detection.recurrent_training import RecurrentLossConfig

        RecurrentLossConfig(gamma=1.5)
    with pytest.raises(ConfigError, match="repetition_from"):
        RecurrentTrainConfig(train="a.json", val="b.json", repetition_from=0.5, stop_from=0.2)

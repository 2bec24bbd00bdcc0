"""The product check before a grasp: shop photos from randomised studios, framing a photo on any
background, the learnt verifier (trained, calibrated, saved, resumed, best over several photos) and
the picker's use of it."""

from __future__ import annotations

import numpy as np
import pytest

from binpick.core.errors import ConfigError, InputFileError


def test_randomised_studios_differ_and_a_cut_out_photo_carries_its_product_as_alpha():
    from binpick.sim import default_library
    from binpick.sim.photos import CATALOGUE_VIEWS, PhotoStyle, catalogue_photos, random_photo_style, shop_photo

    mug = default_library()["pybullet/mug"]
    styles = [random_photo_style(np.random.default_rng(seed)) for seed in range(6)]
    assert len({(s.azimuth, s.background) for s in styles}) == 6
    image, mask = shop_photo(mug, 64, with_mask=True, style=PhotoStyle(cut_out=True, background=(0.1, 0.6, 0.2)))
    assert image.shape == (64, 64, 4) and np.array_equal(image[..., 3] > 127, mask) and 0.02 < mask.mean() < 0.8
    views = catalogue_photos(mug, 64)
    assert len(views) == len(CATALOGUE_VIEWS) >= 2 and not np.array_equal(views[0][0], views[1][0])


@pytest.mark.parametrize("background, rows", [((250, 250, 250), (30, 90)), ((40, 90, 200), (30, 90)),
                                              ((250, 250, 250), (60, 120)), ((250, 250, 250), (0, 120))])
def test_a_photo_is_framed_on_its_product_on_a_light_or_a_coloured_background(background, rows):
    from binpick.detection.photos import product_box

    photo = np.zeros((120, 160, 3), np.uint8)
    photo[:] = background
    photo[rows[0]:rows[1], 50:100] = (220, 60, 40)  # also touching the frame's edge: a shop's tight crop
    x1, y1, x2, y2 = product_box(photo)
    assert abs(x1 - 50) <= 4 and abs(y1 - rows[0]) <= 4 and abs(x2 - 100) <= 4 and abs(y2 - rows[1]) <= 4


def test_the_verifier_scores_every_box_and_takes_the_best_over_several_photos(tmp_path):
    from binpick.detection.verifier import ProductVerifier, VerifierNet

    rng = np.random.default_rng(0)
    verifier = ProductVerifier(VerifierNet(8))
    rgb = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
    depth = np.full((120, 160), 0.8, np.float32)
    depth[40:80, 40:90] = 0.75
    depth[:5] = 0.0  # holes
    boxes = [[40, 40, 50, 40], [0, 0, 30, 20], [150, 110, 10, 10]]
    red, blue = np.zeros((50, 50, 3), np.uint8), np.zeros((50, 50, 3), np.uint8)
    red[:], blue[:] = (200, 30, 30), (30, 30, 200)
    one = verifier.probabilities(red, None, rgb, depth, boxes)
    other = verifier.probabilities(blue, None, rgb, depth, boxes)
    both = verifier.probabilities([red, blue], [None, None], rgb, depth, boxes)
    assert one.shape == (3,) and np.all((one > 0) & (one < 1))
    assert both == pytest.approx(np.maximum(one, other), abs=1e-4)
    assert verifier.probabilities(red, None, rgb, depth, np.zeros((0, 4))).shape == (0,)
    path = verifier.save(tmp_path / "v.safetensors")
    assert ProductVerifier.load(path).probabilities(red, None, rgb, depth, boxes) == pytest.approx(one, abs=1e-6)
    path.write_bytes(b"not weights")
    with pytest.raises(InputFileError, match="not a safetensors file"):
        ProductVerifier.load(path)


def test_a_repainted_look_alike_takes_the_photos_colours_on_its_own_shape_only():
    from binpick.detection.verifier import STORED
    from binpick.detection.verifier_training import repainted

    window = np.zeros((STORED, STORED, 4), np.uint8)
    window[..., :3] = (40, 90, 200)  # a blue tote floor
    window[28:44, 20:52, :3] = (30, 160, 40)  # a green brick standing 3 cm on it
    window[28:44, 20:52, 3] = 25
    photo = np.zeros((64, 64, 4), np.uint8)
    photo[..., :3] = 255
    photo[16:48, 24:40] = (235, 235, 230, 255)  # a white carton on a white studio background
    out = repainted(window, photo)
    brick = out[28:44, 20:52, :3].reshape(-1, 3).astype(int)
    assert np.abs(brick.mean(0) - (235, 235, 230)).max() < 12  # the brick is white now
    assert np.array_equal(out[..., 3], window[..., 3])  # its shape (heights) is its own
    assert np.array_equal(out[:20, :, :3], window[:20, :, :3])  # the floor round it is untouched
    flat = window.copy()
    flat[..., 3] = 0  # nothing stands out of the floor: nothing to repaint
    assert np.array_equal(repainted(flat, photo), flat)


@pytest.mark.slow
def test_the_verifier_trains_on_randomised_bins_calibrates_and_resumes(tmp_path):
    from binpick.detection.verifier import ProductVerifier
    from binpick.detection.verifier_training import VerifierTrainConfig, train_verifier
    from binpick.warehouse.dataset import GenerateConfig, generate

    data = tmp_path / "bins"
    generate(GenerateConfig(out=str(data), scenes=4, policies=[], workers=1, image_size=128, copies=(2, 3), distractors=(1, 2),
                            domain="random", scenes_per_world=1, val_fraction=0.5, photo_views=2, seed=3))
    assert len(list((data / "photos" / "random_000000_0").glob("*.png"))) == 2  # two randomised studios per product
    config = VerifierTrainConfig(data=str(data), out=str(tmp_path / "run"), epochs=2, batch_size=8, width=8, threads=1)
    metrics = train_verifier(config)
    assert [row["epoch"] for row in metrics["history"]] == [1, 2] and metrics["temperature"] > 0
    assert 0.0 <= metrics["val"]["auc"] <= 1.0 and metrics["val"]["pairs"] > 0
    verifier = ProductVerifier.load(tmp_path / "run" / "product_verifier.safetensors")
    assert verifier.net.temperature.item() == pytest.approx(metrics["temperature"], rel=1e-4)
    resumed = train_verifier(config)  # every epoch already done: nothing is trained again
    assert resumed["history"] == metrics["history"]
    with pytest.raises(ConfigError, match="another configuration"):
        train_verifier(VerifierTrainConfig(**{**config.__dict__, "lr": 0.01}))


def test_the_picker_refuses_an_unknown_check_and_mismatched_photo_masks():
    from binpick.grasping import GraspPlanner
    from binpick.picking import Picker
    from binpick.picking.picker import as_photos

    with pytest.raises(ConfigError, match="verifier must be one of"):
        Picker(None, GraspPlanner("analytic"), verifier="hunch")
    assert Picker(None, GraspPlanner("analytic"), verifier="colour").check == 0.15
    from binpick.detection.verifier import ProductVerifier, VerifierNet

    shipped = ProductVerifier.load().meta.get("threshold", 0.2)
    assert Picker(None, GraspPlanner("analytic")).check == pytest.approx(shipped)  # calibrated with the shipped weights
    calibrated = ProductVerifier(VerifierNet(8), {"threshold": 0.37})
    assert Picker(None, GraspPlanner("analytic"), verifier=calibrated).check == pytest.approx(0.37)
    assert Picker(None, GraspPlanner("analytic"), verifier=calibrated, check=0.6).check == pytest.approx(0.6)  # the caller's wins
    assert Picker(None, GraspPlanner("analytic"), verifier=None).check is None
    photo = np.zeros((20, 20, 3), np.uint8)
    assert len(as_photos([photo, photo], None)) == 2
    with pytest.raises(ConfigError, match="one product mask per photo"):
        as_photos([photo, photo], [None])

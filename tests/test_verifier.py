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
    from binpick.detection.verifier_pairs import repainted

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
    from binpick.warehouse.dataset import generate
    from binpick.warehouse.generation import GenerateConfig

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
    from binpick.picking.inputs import as_photos

    with pytest.raises(ConfigError, match="verifier must be one of"):
        Picker(None, GraspPlanner("analytic"), verifier="hunch")
    for power in (-1.0, float("nan")):
        with pytest.raises(ConfigError, match="agreement must be a power of at least 0"):
            Picker(None, GraspPlanner("analytic"), agreement=power)
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


def test_detections_are_asked_of_each_other_in_one_batch_as_the_check_asks_a_photo():
    """``pairwise`` shows each window to the check as a photo (its standing pixels as the mask): one batch
    gives what the pair-by-pair calls give; copies of a red block agree more than a red and a blue one."""
    import torch

    from binpick.detection import verifier as V

    verifier = V.ProductVerifier.load()
    rgb = np.full((160, 240, 3), 90, np.uint8)
    depth = np.full((160, 240), 0.8, np.float32)
    boxes = [[20, 30, 40, 40], [90, 30, 40, 40], [160, 30, 40, 40], [90, 100, 40, 40]]
    for (x, y, w, h), colour in zip(boxes, [(200, 40, 40), (205, 45, 35), (30, 40, 200), (198, 38, 42)]):
        rgb[y:y + h, x:x + w] = colour
        depth[y:y + h, x:x + w] = 0.74
    depth[:4] = 0.0  # holes
    same = verifier.pairwise(rgb, depth, boxes)
    windows = [V.centre(V.window_input(rgb, depth, box)) for box in boxes]
    photos = [np.dstack([w[..., :3], np.where(V.window_mask(w), 255, 0).astype(np.uint8)]) for w in windows]
    light = V.illuminant(rgb)
    with torch.no_grad():
        one_by_one = np.stack([torch.sigmoid(verifier.net(V.to_tensor(photo[None]), V.to_tensor(np.stack(windows)), torch.from_numpy(
            np.stack([V.colour_features(photo, w, light) for w in windows])))).numpy() for photo in photos])
    expected = (one_by_one + one_by_one.T) / 2
    np.fill_diagonal(expected, 1.0)
    assert same == pytest.approx(expected, abs=1e-5) and np.array_equal(same, same.T)
    assert min(same[0, 1], same[0, 3], same[1, 3]) > max(same[0, 2], same[1, 2], same[3, 2])  # the reds agree, the blue stands apart
    assert verifier.pairwise(rgb, depth, boxes[:1]).shape == (1, 1)


def test_a_plan_reads_each_window_once_for_the_photo_check_and_the_agreement():
    """The frame's windows are read once (towers and histograms) and shared by the check against the
    photo and the detections' check against each other; shared or not, the figures are the same."""
    from binpick.detection import verifier as V

    verifier = V.ProductVerifier.load()
    rgb = np.full((160, 240, 3), 90, np.uint8)
    depth = np.full((160, 240), 0.8, np.float32)
    boxes = np.array([[20, 30, 40, 40], [90, 30, 40, 40], [160, 30, 40, 40]], float)
    for (x, y, w, h), colour in zip(boxes.astype(int), [(200, 40, 40), (30, 40, 200), (198, 38, 42)]):
        rgb[y:y + h, x:x + w] = colour
        depth[y:y + h, x:x + w] = 0.74
    photo = np.zeros((64, 64, 3), np.uint8)
    photo[16:48, 16:48] = (200, 40, 40)
    read = []
    original = verifier.net.window_features
    verifier.net.window_features = lambda window: read.append(len(window)) or original(window)
    windows = verifier.windows(rgb, depth)
    shared = verifier.probabilities(photo, None, rgb, depth, boxes, windows=windows)
    agree = verifier.pairwise(rgb, depth, boxes[[2, 0]], windows=windows)
    assert read == [3]  # one batch of three windows; the agreement's two were read already
    assert shared == pytest.approx(verifier.probabilities(photo, None, rgb, depth, boxes), abs=1e-6)
    assert agree == pytest.approx(verifier.pairwise(rgb, depth, boxes[[2, 0]]), abs=1e-6)
    assert read == [3, 3, 2]  # without shared windows each call reads its own


def test_copies_that_agree_rank_above_a_look_alike_the_photo_check_passes():
    from binpick.picking.agreement import rank_by_support, support

    # 0, 1, 2: copies (they agree); 3: a look-alike with the best detector score; 4: its twin, not the product
    pairwise = np.array([[1, .99, .98, .80, .78], [.99, 1, .99, .79, .80], [.98, .99, 1, .81, .80],
                         [.80, .79, .81, 1, .99], [.78, .80, .80, .99, 1]])
    same = np.array([.99, .99, .99, .95, .30])
    backing = support(pairwise, same)
    assert backing[3] == pytest.approx(.81 * .99) and backing[0] == pytest.approx(.99 * .99)  # the twin lends 0.3 at most
    ranked = [(np.array([10.0 * i, 0, 5, 5]), score, p) for i, (score, p) in enumerate(zip([.80, .70, .60, .90, .85], same))]
    ranked.sort(key=lambda c: -c[1] * c[2])  # the check's ranking: the look-alike first
    assert ranked[0][0][0] == 30
    by_support = rank_by_support(ranked, lambda boxes: pairwise[np.ix_(boxes[:, 0].astype(int) // 10, boxes[:, 0].astype(int) // 10)])
    assert [int(box[0]) // 10 for box, _, _ in by_support][:3] == [0, 1, 2]
    assert rank_by_support(ranked, None, windows=1) == ranked  # one compared: nothing to agree with
    unchecked = [(box, score, None) for box, score, _ in ranked]
    assert rank_by_support(unchecked, None) == unchecked
    assert support(np.ones((1, 1)), np.array([.5])).tolist() == [1.0]


def test_in_a_bin_of_copies_the_first_plan_is_a_copy_not_the_same_coloured_look_alike():
    """A seen product's bin in which the detector scores a same-coloured other product (a green shape
    among green-and-white cylinders) above the copies and the photo check passes it (0.96): asked of
    each other, the copies agree and the look-alike does not, and the first plan is a copy."""
    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.grasping import GraspPlanner
    from binpick.sim import default_library
    from binpick.warehouse.pipeline import PickPipeline

    library = default_library()
    pipeline = PickPipeline(Detector.load(PICKING).inference_network, library, grasp=GraspPlanner.load("learnt", hand="jaws"))
    world, rng = pipeline.build_world("procedural/cylinder_16", 10_011)
    try:
        scene = pipeline.settle(world, rng, 10_011)
    finally:
        world.close()

    def first_lift(agreement):
        pipeline.picker.agreement = agreement
        plans = pipeline.plan(scene, "procedural/cylinder_16")
        x, y, w, h = plans[0].box

        def overlap(instance) -> float:
            ix, iy, iw, ih = instance.bbox
            return max(0.0, min(x + w, ix + iw) - max(x, ix)) * max(0.0, min(y + h, iy + ih) - max(y, iy))

        return max(scene.instances, key=overlap).product_id, plans.timing_ms

    net = pipeline.picker.learnt_verifier().net
    read, original = [], net.window_features
    net.window_features = lambda window: read.append(len(window)) or original(window)
    product, timing = first_lift(4.0)
    assert product == "procedural/cylinder_16" and "agree" in timing
    detections = len(pipeline.plan(scene, "procedural/cylinder_16").boxes)
    assert detections > 2 and sum(read) == 2 * detections  # per plan each window read once: the check and the agreement share it
    assert first_lift(None)[0] != "procedural/cylinder_16"  # without it the look-alike came first

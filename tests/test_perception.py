"""Auto-perception networks (thesis §4.3): shapes, the conditioning loss at work, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from binpick.core.errors import ConfigError
from binpick.april.perception import AutoPerception, PerceptionConfig, load_perception, save_perception, train_perception


def dot_images(count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """64x64 grey images of a bright 6x6 square; the semantic state is its centre (x, y) in [0, 1]."""
    rng = np.random.default_rng(seed)
    states = rng.uniform(0.1, 0.9, size=(count, 2)).astype(np.float32)
    images = np.zeros((count, 64, 64, 1), np.uint8)
    for image, (x, y) in zip(images, states):
        column, row = int(x * 64), int(y * 64)
        image[max(row - 3, 0):row + 3, max(column - 3, 0):column + 3] = 255
    return images, states


def test_encoder_decoder_shapes_and_vae_sigma_only_on_free_dims():
    model = AutoPerception(PerceptionConfig(kind="vae", latent=8, conditioned=6, channels=4), (64, 64, 3), 6)
    images = np.zeros((5, 64, 64, 3), np.uint8)
    latent, mu, log_sigma = model(images)
    assert latent.shape == (5, 8) and mu.shape == (5, 8) and log_sigma.shape == (5, 2)
    model.train()
    sampled, mu, _ = model(images)
    assert torch.equal(sampled[:, :6], mu[:, :6]) and not torch.equal(sampled[:, 6:], mu[:, 6:])
    assert model.reconstruct(images).shape == (5, 64, 64, 3)
    losses = model.loss(images, np.zeros((5, 6), np.float32))
    assert losses["kl"] > 0 and losses["cond"] >= 0
    encoder_convs = [m for m in model.encoder if isinstance(m, torch.nn.Conv2d)]
    decoder_convs = [m for m in model.decoder if isinstance(m, torch.nn.ConvTranspose2d)]
    assert len(encoder_convs) == 6 and len(decoder_convs) == 6 and all(c.stride == (2, 2) for c in encoder_convs)


def test_conditioning_makes_the_latent_predict_the_semantic_state(tmp_path):
    images, states = dot_images(600)
    conditioned, history = train_perception(PerceptionConfig(latent=2, conditioned=2, omega=1.0, channels=8),
                                            images, states, epochs=12, batch_size=32)
    errors = [row["state_mae"] for row in history["epochs"]]
    baseline = float(np.abs(states - states.mean(0)).mean())  # predicting the mean position
    assert errors[-1] < 0.4 * baseline, (errors, baseline)
    test_images, test_states = dot_images(50, seed=1)
    assert np.abs(conditioned.encode(test_images) - test_states).mean() < 0.4 * baseline
    save_perception(conditioned, tmp_path / "p.pt")
    np.testing.assert_allclose(load_perception(tmp_path / "p.pt").encode(test_images), conditioned.encode(test_images),
                               atol=1e-6)


def test_cosine_schedule_learns_and_settles():
    """Cosine decay (perception_training.schedule) reaches the constant rate's fit, and its last
    epoch, at a rate near 0, barely moves the error any more."""
    images, states = dot_images(600)
    _, history = train_perception(PerceptionConfig(latent=2, conditioned=2, omega=1.0, channels=8),
                                  images, states, epochs=12, batch_size=32, schedule="cosine")
    errors = [row["state_mae"] for row in history["epochs"]]
    baseline = float(np.abs(states - states.mean(0)).mean())
    assert errors[-1] < 0.4 * baseline, (errors, baseline)
    # settled: the last epoch moves the error a tenth as much as the largest epoch did (on some CPUs the first
    # epochs sit on a plateau, so the first epoch's move is no yardstick)
    assert abs(errors[-1] - errors[-2]) < 0.1 * np.abs(np.diff(errors)).max(), errors
    with pytest.raises(ConfigError, match="schedule"):
        train_perception(PerceptionConfig(latent=2, conditioned=2, channels=8), images[:4], states[:4], schedule="step")


def test_foreground_weight_counts_small_objects_in_the_reconstruction_loss(tmp_path):
    """perception.foreground_weight λ: pixels unlike the median training image (here the 6x6 square,
    1% of the image) weigh 1 + λ in L_recon, so missing the square costs a decoder as much as a
    sizeable part of the background would, where the plain L1 barely notices it."""
    images, states = dot_images(200)
    plain = AutoPerception(PerceptionConfig(latent=2, conditioned=0, omega=0.0, channels=4), (64, 64, 1), 2)
    weighted = AutoPerception(PerceptionConfig(latent=2, conditioned=0, omega=0.0, channels=4, foreground_weight=50.0),
                              (64, 64, 1), 2)
    weighted.load_state_dict(plain.state_dict(), strict=False)  # the same network; only the loss differs
    weighted.set_background(images)
    assert float(weighted.background.abs().max()) == 0.0  # the median image: the square is nowhere most of the time
    with torch.no_grad():
        error = (plain.decode(plain(images[:8])[0]) - plain._pixels(images[:8])).abs()
        square = torch.as_tensor(images[:8] > 0).permute(0, 3, 1, 2).float()
        expected = ((1 + 50 * square) * error).sum() / (1 + 50 * square).sum()
        torch.testing.assert_close(weighted.loss(images[:8], None)["recon"], expected)
        torch.testing.assert_close(plain.loss(images[:8], None)["recon"], error.mean())
    save_perception(weighted, tmp_path / "p.safetensors")
    loaded = load_perception(tmp_path / "p.safetensors")
    assert loaded.config.foreground_weight == 50.0 and torch.equal(loaded.background, weighted.background)
    _, history = train_perception(weighted.config, images, states, epochs=1, batch_size=32)  # sets its background
    assert history["epochs"][0]["recon"] > 0
    with pytest.raises(ConfigError, match="perception.foreground_weight"):
        PerceptionConfig(foreground_weight=-1)


def test_bad_perception_input_is_one_clear_error():
    with pytest.raises(ConfigError, match=r"conditioned \(m=9\) must be <= perception.latent \(n=8\)"):
        PerceptionConfig(latent=8, conditioned=9)
    with pytest.raises(ConfigError, match="perception.kind"):
        PerceptionConfig(kind="gan")
    model = AutoPerception(PerceptionConfig(latent=4, conditioned=4, channels=4), (64, 64, 1), 4)
    with pytest.raises(ConfigError, match=r"images of shape \(64, 64, 1\).*got \(64, 64, 3\)"):
        model.encode(np.zeros((64, 64, 3), np.uint8))
    with pytest.raises(ConfigError, match="multiple of 64"):
        AutoPerception(PerceptionConfig(channels=4), (48, 48, 1), 6)
    with pytest.raises(ConfigError, match="no perception checkpoint"):
        load_perception("/nonexistent/perception.pt")


def keypoint_perception(seed: int) -> AutoPerception:
    torch.manual_seed(seed)
    return AutoPerception(PerceptionConfig(latent=4, conditioned=2, channels=8, free_features="keypoints"), (64, 64, 3), 2)


def test_free_keypoint_sits_where_the_conditioned_part_leaves_pixels_unexplained(tmp_path):
    """perception.free_features: keypoints -- the n − m free dimensions are the expected (x, y) of a heat
    map over what the decoder cannot draw from the conditioned part alone. With the decoder's drawing
    flat (an untrained one) a square anywhere on a background of the same grey is all that is left
    unexplained, and the keypoint lands on it, in the image's [-1, 1] coordinates (x right, y down)."""
    rng = np.random.default_rng(0)
    for seed in range(3):
        model = keypoint_perception(seed)
        with torch.no_grad():
            grey = float(model._draw(torch.zeros(1, 2), None).mean())
        centres = rng.uniform(0.15, 0.85, size=(40, 2))
        images = np.full((40, 64, 64, 3), round(grey * 255), np.uint8)
        for image, (x, y) in zip(images, centres):
            column, row = int(x * 64), int(y * 64)
            image[row - 3:row + 3, column - 3:column + 3] = (20, 40, 200)
        free = model.encode(images)[:, 2:]
        assert np.abs(free - (centres * 2 - 1)).mean() < 0.05, (seed, np.abs(free - (centres * 2 - 1)).mean())
    save_perception(model, tmp_path / "p.safetensors")
    np.testing.assert_allclose(load_perception(tmp_path / "p.safetensors").encode(images), model.encode(images), atol=1e-6)


def test_free_keypoint_is_drawn_where_it_points_and_the_conditioned_part_draws_alone():
    """The decoder draws a blob at each free keypoint: moving the keypoint changes the picture near its
    old and new places and hardly elsewhere; and L_VP adds the conditioned part's own reconstruction,
    so that what it leaves out is what s̄ does not place."""
    model = keypoint_perception(0)
    conditioned = torch.zeros(1, 2)
    with torch.no_grad():
        left = model.decode(torch.cat([conditioned, torch.tensor([[-0.5, 0.0]])], dim=1))
        right = model.decode(torch.cat([conditioned, torch.tensor([[0.5, 0.0]])], dim=1))
    change = (left - right).abs().mean(dim=(0, 1))  # (64, 64)
    near = torch.zeros(64, 64, dtype=torch.bool)
    near[22:42, 6:26] = near[22:42, 38:58] = True  # 10 px around (16, 32) and (48, 32)
    assert change[near].mean() > 5 * change[~near].mean(), (change[near].mean(), change[~near].mean())
    images, states = dot_images(8)
    images = np.repeat(images, 3, axis=-1)
    losses = model.loss(images, states)
    target = model._pixels(images)
    with torch.no_grad():
        alone = (model._draw(losses["mu"][:, :2], None) - target).abs().mean()
    torch.testing.assert_close(losses["total"].detach(), (losses["recon"] + losses["cond"] + alone).detach())


def test_free_keypoints_need_an_ae_and_pairs():
    with pytest.raises(ConfigError, match="perception.free_features"):
        PerceptionConfig(free_features="grid")
    with pytest.raises(ConfigError, match="kind: ae"):
        PerceptionConfig(kind="vae", latent=8, conditioned=6, free_features="keypoints")
    with pytest.raises(ConfigError, match="n − m must be an even number >= 2, got 1"):
        PerceptionConfig(latent=7, conditioned=6, free_features="keypoints")


def test_goal_keypoints_sit_on_the_goal_and_read_it_closer_than_the_dense_layer():
    """perception.goal_keypoints: a heat map per view whose expected (x, y), through a small MLP, adds to
    the conditioned part; given the goal's place in view (``points``) L_cond asks the keypoint to sit
    there. On the same data and epochs the square is then read closer than by the fully connected layer
    alone, and the keypoint is on it (within a pixel: 0.031 image units) on images it never saw."""
    images, states = dot_images(600)
    test_images, test_states = dot_images(100, seed=1)
    errors = {}
    for keypoints in (0, 1):
        torch.manual_seed(0)
        model, history = train_perception(PerceptionConfig(latent=2, conditioned=2, channels=8, goal_keypoints=keypoints),
                                          images, states, epochs=6, batch_size=32,
                                          points=states * 2 - 1 if keypoints else None)
        errors[keypoints] = float(np.abs(model.encode(test_images) - test_states).mean())
    assert errors[1] < 0.6 * errors[0], errors
    assert "goal_point_mae" in history["epochs"][-1]
    with torch.no_grad():
        found = model.goal_points(model._pixels(test_images)).numpy()
    assert np.abs(found - (test_states * 2 - 1)).mean() < 0.031


def test_goal_keypoints_are_checked_against_the_conditioning_and_the_views():
    from binpick.april.config import AprilConfig

    with pytest.raises(ConfigError, match="perception.goal_keypoints needs a conditioned part"):
        PerceptionConfig(latent=2, conditioned=0, goal_keypoints=1)
    with pytest.raises(ConfigError, match=r"perception.goal_keypoints: one per camera view .*\(2 in env_kwargs.views here\), got 1"):
        AprilConfig(env="binpick/FetchReach-v0", env_kwargs={"views": ["workspace", "side"]},
                    perception=PerceptionConfig(goal_keypoints=1), policy=AprilConfig().policy)
    model = AutoPerception(PerceptionConfig(latent=2, conditioned=2, channels=4, goal_keypoints=2), (64, 64, 1), 2)
    images, states = dot_images(4)
    with pytest.raises(ConfigError, match="2 keypoints need the goal's"):
        model.loss(images, states, points=np.zeros((4, 2), np.float32))


def test_free_keypoints_can_be_kept_to_the_first_view():
    """perception.free_keypoint_channels: with stacked views the free heat maps see only the first view's
    channels, so a large thing in the second view (the side view's arm) cannot hold the keypoint."""
    torch.manual_seed(0)
    config = PerceptionConfig(latent=4, conditioned=2, channels=8, free_features="keypoints", free_keypoint_channels=3)
    model = AutoPerception(config, (64, 64, 6), 2)
    with torch.no_grad():
        grey = round(float(model._draw(torch.zeros(1, 2), None).mean()) * 255)
    images = np.full((2, 64, 64, 6), grey, np.uint8)
    images[:, 40:46, 10:16, :3] = (20, 40, 200)  # the box, in the first view
    images[1, 5:35, 30:60, 3:] = (250, 250, 250)  # something large, in the second view only
    free = model.encode(images)[:, 2:]
    np.testing.assert_allclose(free[0], free[1], atol=1e-5)
    assert np.abs(free[0] - np.array([13, 43]) / 64 * 2 + 1).max() < 0.1, free[0]
    with pytest.raises(ConfigError, match="free_keypoint_channels .* needs perception.free_features: keypoints"):
        PerceptionConfig(free_keypoint_channels=3)
    with pytest.raises(ConfigError, match=r"free_keypoint_channels \(9\) exceeds the images' 6 channels"):
        AutoPerception(PerceptionConfig(latent=4, conditioned=2, free_features="keypoints", free_keypoint_channels=9),
                       (64, 64, 6), 2)

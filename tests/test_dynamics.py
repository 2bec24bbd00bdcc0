"""GP dynamics (thesis §3.3.1): learns Δz from (z, a), agrees with a direct float64 solve, imagines."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from binpick.rl.gp_her.dynamics import GPDynamics
from binpick.rl.gp_her.imagination import imagine_episodes


def toy_transitions(n: int, seed: int = 0):
    """z' = z + 0.05 a, shrunk near the wall |z| > 0.8 (like the table limit of Fig 3.8), plus noise."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(-1, 1, (n, 2))
    a = rng.uniform(-1, 1, (n, 2))
    move = 0.05 * a * np.where(np.abs(z) > 0.8, 0.3, 1.0)
    return z, a, z + move + rng.normal(0, 0.002, (n, 2))


@pytest.fixture(scope="module")
def gp():
    model = GPDynamics(max_points=300, iterations=60, seed=0)
    model.fit(*toy_transitions(300))
    return model


def test_predicts_held_out_moves_better_than_assuming_no_motion(gp):
    z, a, nxt = toy_transitions(200, seed=1)
    mean, variance = gp.predict(z, a)
    error = np.linalg.norm(mean - (nxt - z), axis=1).mean()
    baseline = np.linalg.norm(nxt - z, axis=1).mean()
    assert error < 0.25 * baseline, (error, baseline)
    assert np.all(variance > 0)


def test_uncertainty_grows_away_from_the_data(gp):
    inside = gp.predict(np.zeros((1, 2)), np.zeros((1, 2)))[1]
    outside = gp.predict(np.full((1, 2), 4.0), np.zeros((1, 2)))[1]
    assert np.all(outside > 3 * inside)


def test_closed_form_matches_a_float64_solve(gp):
    z, a, _ = toy_transitions(50, seed=2)
    mean, variance = gp.predict(z, a)
    kernel = gp.model.covar_module
    lengthscale = kernel.base_kernel.lengthscale.detach().double()
    outputscale = kernel.outputscale.detach().double()
    noise = (gp.likelihood.noise + gp.likelihood.task_noises).detach().double()
    train_x = gp.model.train_inputs[0].double() / lengthscale
    train_y = gp.model.train_targets.double().T
    query = torch.as_tensor((np.concatenate([z, a], 1) - gp._x_mean) / gp._x_std)[None] / lengthscale
    gram = outputscale[:, None, None] * torch.exp(-0.5 * torch.cdist(train_x, train_x) ** 2)
    gram = gram + noise[:, None, None] * torch.eye(train_x.shape[1], dtype=torch.float64)
    cross = outputscale[:, None, None] * torch.exp(-0.5 * torch.cdist(query, train_x) ** 2)
    # one output at a time: after bf16 detector training in the same process, oneMKL's *batched*
    # float64 LU (torch.linalg.solve on a stack) fails with "Parameter 6 was incorrect on entry to DLASWP"
    solve = lambda a, b: torch.stack([torch.linalg.solve(a[i], b[i]) for i in range(len(a))])  # noqa: E731
    expected_mean = (cross @ solve(gram, train_y[..., None]))[..., 0].T.numpy() * gp._y_std + gp._y_mean
    solved = solve(gram, cross.transpose(1, 2))
    expected_var = (outputscale[:, None] - (cross * solved.transpose(1, 2)).sum(-1) + noise[:, None]).T.numpy() * gp._y_std**2
    np.testing.assert_allclose(mean, expected_mean, atol=2e-3 * np.abs(expected_mean).max())
    np.testing.assert_allclose(variance, expected_var, rtol=0.1)


def test_save_and_load_give_the_same_predictions(gp, tmp_path):
    gp.save(tmp_path / "gp.safetensors")
    loaded = GPDynamics.load(tmp_path / "gp.safetensors")
    z, a, _ = toy_transitions(20, seed=3)
    np.testing.assert_allclose(loaded.predict(z, a)[0], gp.predict(z, a)[0], rtol=1e-5, atol=1e-7)


def test_imagined_episodes_follow_the_policy_and_stop_at_success(gp):
    def reward(achieved, desired, _info):
        return -(np.linalg.norm(np.asarray(achieved) - np.asarray(desired), axis=-1) > 0.05).astype(float)

    def towards_goal(observation):
        return np.clip(10 * (observation["desired_goal"] - observation["achieved_goal"]), -1, 1)

    rng = np.random.default_rng(0)
    starts = rng.uniform(-0.5, 0.5, (64, 2))
    goals = starts + rng.uniform(-0.3, 0.3, (64, 2))
    episodes = imagine_episodes(gp, towards_goal, starts, goals, reward, max_steps=30, rng=rng)
    assert len(episodes) == 64
    successes = [np.linalg.norm(e.achieved_goal[-1] - e.desired_goal) <= 0.05 for e in episodes]
    assert np.mean(successes) > 0.9, "a controller towards the goal succeeds inside the learnt model"
    for episode in episodes:
        assert len(episode.observation) == episode.length + 1 and len(episode.actions) == episode.length
        np.testing.assert_allclose(episode.observation[0], episode.achieved_goal[0])
        if np.linalg.norm(episode.achieved_goal[-1] - episode.desired_goal) <= 0.05:
            assert all(np.linalg.norm(z - episode.desired_goal) > 0.05 for z in episode.achieved_goal[1:-1])

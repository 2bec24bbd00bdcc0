"""Episode replay and episode HER (thesis §3.1.1, §3.3.2)."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces

from binpick.core.errors import ConfigError
from binpick.rl.common.replay import Episode, EpisodeReplayBuffer

TOL = 0.05


def reward(achieved, desired, _info):
    return -(np.linalg.norm(np.asarray(achieved) - np.asarray(desired), axis=-1) > TOL).astype(np.float64)


SPACE = spaces.Dict({k: spaces.Box(-np.inf, np.inf, (2,), np.float64) for k in ("observation", "achieved_goal", "desired_goal")})
ACTIONS = spaces.Box(-1, 1, (2,), np.float32)


def make_buffer(**kwargs) -> EpisodeReplayBuffer:
    defaults = {"compute_reward": reward, "max_episode_steps": 10, "capacity_episodes": 100, "her_additions": 3, "seed": 0}
    return EpisodeReplayBuffer(1000, SPACE, ACTIONS, device="cpu", **{**defaults, **kwargs})


def line_episode(length: int, goal=(5.0, 5.0)) -> Episode:
    """z moves +0.1 in x each step from the origin; observation == achieved goal."""
    z = np.stack([np.arange(length + 1) * 0.1, np.zeros(length + 1)], axis=1).astype(np.float32)
    return Episode(z.copy(), z, np.array(goal, np.float32), np.tile([1.0, 0.0], (length, 1)).astype(np.float32))


def test_failed_episode_gets_alpha_her_copies_with_achieved_goals_cut_at_success():
    buffer = make_buffer(her_additions=3)
    assert buffer.add_episode(line_episode(8)) == 4
    assert buffer.added == {"real": 1, "her": 3, "imagined": 0}
    copies = [e for e in buffer.stored_episodes("her")]
    goals = {tuple(np.round(e.desired_goal, 5)) for e in copies}
    assert len(goals) == 3, "goals are drawn without replacement"
    for copy in copies:
        # the copy ends exactly where the arm first came within tolerance of the relabelled goal
        assert np.linalg.norm(copy.achieved_goal[-1] - copy.desired_goal) <= TOL
        assert all(np.linalg.norm(z - copy.desired_goal) > TOL for z in copy.achieved_goal[1:-1])


def test_successful_episode_is_not_relabelled_and_alpha_is_bounded_by_length():
    buffer = make_buffer(her_additions=50)
    assert buffer.add_episode(line_episode(3, goal=(0.3, 0.0))) == 1
    assert buffer.add_episode(line_episode(4)) == 1 + 4, "at most m copies for an episode of length m"


def test_capacity_counts_episodes_and_forgets_the_oldest():
    buffer = make_buffer(capacity_episodes=5, her_additions=0)
    for length in range(1, 9):
        buffer.add_episode(line_episode(length))
    assert buffer.episodes == 5
    assert sorted(e.length for e in buffer.stored_episodes()) == [4, 5, 6, 7, 8]
    assert buffer.size() == 4 + 5 + 6 + 7 + 8


def test_ready_when_ten_percent_full():
    buffer = make_buffer(capacity_episodes=50, her_additions=0)
    for _ in range(4):
        buffer.add_episode(line_episode(3))
    assert not buffer.ready
    buffer.add_episode(line_episode(3))
    assert buffer.ready


def test_samples_recompute_rewards_and_dones_from_goals():
    buffer = make_buffer(her_additions=2)
    buffer.add_episode(line_episode(6))
    batch = buffer.sample_arrays(4000)
    expected = reward(batch["next_obs"]["achieved_goal"], batch["obs"]["desired_goal"], None)
    np.testing.assert_array_equal(batch["rewards"], expected)
    np.testing.assert_array_equal(batch["dones"], expected == 0)
    assert 0 < batch["dones"].mean() < 1, "relabelled copies supply the successes a failed episode lacks"
    np.testing.assert_allclose(batch["next_obs"]["achieved_goal"] - batch["obs"]["achieved_goal"],
                               np.tile([0.1, 0.0], (4000, 1)), atol=1e-6)


def test_sampling_is_uniform_over_transitions():
    buffer = make_buffer(her_additions=0)
    buffer.add_episode(line_episode(1))
    buffer.add_episode(line_episode(9))
    batch = buffer.sample_arrays(20_000)
    first_steps = np.mean(batch["obs"]["achieved_goal"][:, 0] == 0.0)
    assert first_steps == pytest.approx(2 / 10, abs=0.02)  # 2 of the 10 transitions start at z = 0


def test_sb3_add_interface_builds_episodes_per_env():
    buffer = make_buffer(n_envs=2, her_additions=1)
    episode = line_episode(3)
    for t in range(3):
        obs = {k: np.stack([v[t]] * 2) for k, v in (("observation", episode.observation), ("achieved_goal", episode.achieved_goal))}
        nxt = {k: np.stack([v[t + 1]] * 2) for k, v in (("observation", episode.observation), ("achieved_goal", episode.achieved_goal))}
        obs["desired_goal"] = nxt["desired_goal"] = np.stack([episode.desired_goal] * 2)
        buffer.add(obs, nxt, np.stack([episode.actions[t]] * 2), np.zeros(2), np.array([t == 2, False]), [{}, {}])
    assert buffer.added["real"] == 1 and buffer.real_transitions == 3
    samples = buffer.sample(8)
    assert samples.observations["observation"].shape == (8, 2) and samples.rewards.shape == (8, 1)


@pytest.mark.parametrize("kwargs,fragment", [({"her_additions": -1}, "alpha_HER"), ({"capacity_episodes": 0}, "(M)"),
                                             ({"start_fraction": 1.5}, "start_fraction")])
def test_bad_settings_name_the_parameter(kwargs, fragment):
    with pytest.raises(ConfigError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        make_buffer(**kwargs)


def test_saved_state_keeps_only_used_slots_and_round_trips(tmp_path):
    from binpick.rl.common.persistence import load_replay, save_replay

    buffer = make_buffer(capacity_episodes=100_000, her_additions=1)
    for length in (3, 5, 7):
        buffer.add_episode(line_episode(length))
    save_replay(buffer, tmp_path)
    assert (tmp_path / "replay.npz").stat().st_size < 200_000, "an almost empty M=1e5 buffer must not save its unused slots"
    restored = make_buffer(capacity_episodes=100_000, her_additions=1)
    load_replay(restored, tmp_path)
    assert restored.episodes == buffer.episodes and restored.added == buffer.added
    assert [e.length for e in restored.stored_episodes()] == [e.length for e in buffer.stored_episodes()]
    np.testing.assert_array_equal(restored.sample_arrays(16)["actions"], buffer.sample_arrays(16)["actions"])  # same rng
    restored.add_episode(line_episode(2))
    assert restored.episodes == buffer.episodes + 2


def test_saved_state_refuses_a_buffer_of_other_settings(tmp_path):
    from binpick.core.errors import InputFileError
    from binpick.rl.common.persistence import load_replay, save_replay

    buffer = make_buffer(capacity_episodes=50, her_additions=1)
    buffer.add_episode(line_episode(3))
    save_replay(buffer, tmp_path)
    with pytest.raises(InputFileError, match="M was 50"):
        load_replay(make_buffer(capacity_episodes=60, her_additions=1), tmp_path)


def test_counts_when_training_could_start_are_recorded():
    buffer = make_buffer(capacity_episodes=20, her_additions=1)
    buffer.add_episode(line_episode(4))
    assert buffer.added_when_ready is not None and buffer.added_when_ready == {"real": 1, "her": 1, "imagined": 0}


def test_her_copies_only_when_the_object_moved():
    """Thesis §4.5.3: in pick and place, relabel only episodes in which the object moved."""
    buffer = make_buffer(her_additions=2, her_min_motion=0.3)
    still = Episode(np.zeros((6, 2), np.float32), np.zeros((6, 2), np.float32), np.array([5.0, 5.0], np.float32),
                    np.zeros((5, 2), np.float32))
    assert buffer.add_episode(still) == 1  # object never moved: no hindsight copies
    assert buffer.add_episode(line_episode(2)) == 1  # moved 0.2 < 0.3
    assert buffer.add_episode(line_episode(8)) == 3  # moved 0.8

"""Fetch worlds (thesis §4.5.2-4.5.3): the obstacle is solid, random and never covers the goal."""

from __future__ import annotations

import numpy as np
import pytest


def _drive_gripper_to(env, point: np.ndarray, steps: int) -> list[np.ndarray]:
    positions = []
    for _ in range(steps):
        gripper = env.unwrapped._get_obs()["achieved_goal"]
        action = np.zeros(4, dtype=np.float32)
        action[:3] = np.clip(10 * (point - gripper), -1, 1)
        env.unwrapped.step(action)
        positions.append(env.unwrapped._get_obs()["achieved_goal"])
    return positions


def test_obstacle_is_placed_at_random_and_never_covers_the_goal(make_env):
    env = make_env("binpick/FetchReachObstacle-v0")
    unwrapped = env.unwrapped
    positions = []
    for seed in range(15):
        observation, _ = env.reset(seed=seed)
        position = unwrapped.obstacle_position
        positions.append(position)
        assert np.max(np.abs(position - observation["desired_goal"])) > unwrapped.obstacle_half_size
        assert unwrapped.obstacle_contacts() == 0, "the box must not start inside the robot"
    positions = np.array(positions)
    assert positions.std(axis=0).min() > 0.03
    assert positions[:, 2].min() > 0.42, "the box floats in the workspace above the table"


def _blocks_the_straight_line(observation, unwrapped) -> bool:
    """Does the box come within 2 cm of the straight line from the gripper to the goal?"""
    from binpick.rl.common.heuristic import box_clearance

    return box_clearance(observation["achieved_goal"], observation["desired_goal"], unwrapped.obstacle_position,
                         unwrapped.obstacle_half_size) < 0.02


def test_obstacle_on_path_puts_the_box_in_the_way(make_env):
    """Placed at random the box is almost never in the way (a policy blind to it loses nothing);
    obstacle_on_path puts it across the line to the goal where there is room, still clear of both ends."""
    counts = {}
    for on_path in (0.0, 1.0):
        env = make_env("binpick/FetchReachObstacle-v0", obstacle_half_size=0.03, obstacle_on_path=on_path)
        unwrapped, blocked = env.unwrapped, 0
        for seed in range(40):
            observation, _ = env.reset(seed=seed)
            blocked += _blocks_the_straight_line(observation, unwrapped)
            assert np.max(np.abs(unwrapped.obstacle_position - observation["desired_goal"])) > unwrapped.obstacle_half_size
            assert unwrapped.obstacle_contacts() == 0
        counts[on_path] = blocked
    assert counts[0.0] <= 4 and counts[1.0] >= 14, counts


def test_a_teacher_that_knows_the_box_goes_round_it(make_env):
    """ObstacleDetour (APRiL's scripted teacher) reaches goals behind the box that driving straight
    at them does not, from the privileged state alone."""
    from binpick.rl.common.evaluate import evaluate_policy
    from binpick.rl.common.heuristic import ObstacleDetour, ReachController
    from binpick.rl.common.wrappers import SemanticState

    env = SemanticState(make_env("binpick/FetchReachObstacle-v0", obstacle_half_size=0.03, obstacle_on_path=1.0),
                        privileged=["obstacle_position"])
    detour = evaluate_policy(ObstacleDetour(0.03), env, episodes=30, seed=20_000)
    straight = evaluate_policy(ReachController(), env, episodes=30, seed=20_000)
    assert detour.success_rate >= 0.9 and detour.success_rate >= straight.success_rate + 0.1, (detour, straight)


def test_privileged_state_shows_the_teacher_where_the_box_is(make_env, tmp_path):
    from binpick.core.config import load_config
    from binpick.core.errors import ConfigError
    from binpick.rl.config import RLConfig
    from binpick.rl.common.wrappers import SemanticState

    env = SemanticState(make_env("binpick/FetchReachObstacle-v0"), privileged=["obstacle_position"])
    observation, _ = env.reset(seed=3)
    assert env.observation_space["observation"].shape == (6,)
    np.testing.assert_allclose(observation["observation"][:3], observation["achieved_goal"])
    np.testing.assert_allclose(observation["observation"][3:], env.unwrapped.obstacle_position)
    with pytest.raises(ConfigError, match="has no 'obstacle_position'"):
        SemanticState(make_env("binpick/FetchReach-v0"), privileged=["obstacle_position"])
    config = tmp_path / "rl.yaml"
    for extra, message in (("privileged_state: [obstacle_position]\ngp: {enabled: true}", "gp.enabled: false"),
                           ("privileged_state: [goal_colour]", "privileged_state must be one of 'obstacle_position'"),
                           ("privileged_state: obstacle_position", "privileged_state must be a list")):
        config.write_text(f"env: binpick/FetchReachObstacle-v0\n{extra}\n")
        with pytest.raises(ConfigError, match=message):
            load_config(RLConfig, config)


def test_arm_collides_with_the_obstacle(make_env):
    env = make_env("binpick/FetchReachObstacle-v0")
    env.reset(seed=1)
    unwrapped = env.unwrapped
    centre = unwrapped.obstacle_position
    half = unwrapped.obstacle_half_size
    contacts = 0
    closest = np.inf
    for position in _drive_gripper_to(env, centre, 40):
        contacts = max(contacts, unwrapped.obstacle_contacts())
        closest = min(closest, np.max(np.abs(position - centre)))
    assert contacts > 0, "driving into the box must touch it"
    assert closest > 0.5 * half, f"the gripper passed into the box (inf-norm distance {closest:.3f})"


def test_without_obstacle_the_same_drive_reaches_the_point(make_env):
    env = make_env("binpick/FetchReach-v0")
    observation, _ = env.reset(seed=1)
    point = observation["achieved_goal"] + np.array([0.1, 0.05, -0.05])
    final = _drive_gripper_to(env, point, 40)[-1]
    assert np.linalg.norm(final - point) < 0.02


def test_obstacle_can_hide_the_goal_from_the_camera(make_env):
    env = make_env("binpick/FetchReachObstacle-v0", image="rgb", image_size=64)
    observation, _ = env.reset(seed=0)
    unwrapped = env.unwrapped

    def red_pixels(image):
        return int(np.sum((image[..., 0] > 150) & (image[..., 1] < 60) & (image[..., 2] < 60)))

    visible = red_pixels(observation["image"])
    assert visible > 0, "the goal is visible when nothing is in the way"
    # put the box between the camera and the goal: on the line from the goal towards the camera
    towards_camera = -unwrapped.observation_poses[0].forward
    unwrapped.model.body_pos[unwrapped._obstacle_body] = unwrapped.goal + 0.2 * towards_camera
    hidden = red_pixels(unwrapped._get_obs()["image"])
    assert hidden < visible


def test_a_second_view_sees_the_goal_the_first_one_loses_behind_the_box(make_env):
    env = make_env("binpick/FetchReachObstacle-v0", image="rgb", image_size=64, views=["workspace", "side"])
    assert env.observation_space["image"].shape == (64, 64, 6)
    env.reset(seed=0)
    unwrapped = env.unwrapped

    def red_pixels(image):
        return int(np.sum((image[..., 0] > 150) & (image[..., 1] < 60) & (image[..., 2] < 60)))

    towards_camera = -unwrapped.observation_poses[0].forward
    unwrapped.model.body_pos[unwrapped._obstacle_body] = unwrapped.goal + 0.2 * towards_camera
    image = unwrapped._get_obs()["image"]
    assert red_pixels(image[..., :3]) == 0, "the box hides the goal from the workspace view"
    assert red_pixels(image[..., 3:]) > 0, "the side view still sees it"


def test_in_views_places_the_goal_where_each_camera_draws_it(make_env):
    """``in_views`` projects world points with the observation cameras' poses: the goal sphere's pixels
    (those that change when it is hidden) are centred where it says, in both stacked views, to a
    fraction of a pixel (perception.goal_keypoints learns to sit there)."""
    env = make_env("binpick/FetchReach-v0", image="rgb", image_size=64, views=["workspace", "side"])
    unwrapped = env.unwrapped
    site = unwrapped.model.site("target0").id
    errors = []
    for seed in range(4):
        observation, _ = env.reset(seed=seed)
        shown = observation["image"].astype(int)
        alpha = float(unwrapped.model.site_rgba[site, 3])
        unwrapped.model.site_rgba[site, 3] = 0.0
        hidden = unwrapped._get_obs()["image"].astype(int)
        unwrapped.model.site_rgba[site, 3] = alpha
        places = unwrapped.in_views(observation["desired_goal"][None])
        assert places.shape == (1, 4)
        for view, place in enumerate(places[0].reshape(2, 2)):
            rows, columns = np.nonzero(np.abs(shown - hidden)[..., 3 * view:3 * view + 3].sum(-1) > 30)
            assert len(rows) >= 3, (seed, view)
            drawn = (np.array([columns.mean(), rows.mean()]) + 0.5) / 64 * 2 - 1
            errors.append(np.abs(drawn - place).max())
    assert max(errors) < 0.03, errors  # 1 px is 0.031 image units


def test_unknown_view_is_one_clear_error(make_env):
    from binpick.core.errors import ConfigError

    with pytest.raises(ConfigError, match="views must be one of 'workspace', 'side'"):
        make_env("binpick/FetchReach-v0", image="rgb", image_size=64, views=["top"])


def test_pick_and_place_actions_are_delta_z_and_gripper(make_env):
    env = make_env("binpick/FetchPickAndPlace-v0")
    observation, _ = env.reset(seed=0)
    assert env.action_space.shape == (4,)
    assert env.spec.max_episode_steps == 100
    data = env.unwrapped.data
    fingers = lambda: data.qpos[env.unwrapped.model.joint("robot0:l_gripper_finger_joint").qposadr[0]]  # noqa: E731
    for _ in range(5):
        env.step(np.array([0, 0, 0, 1.0], dtype=np.float32))
    opened = fingers()
    for _ in range(5):
        env.step(np.array([0, 0, 0, -1.0], dtype=np.float32))
    assert fingers() < opened - 0.01, "a_g = -1 closes the gripper"


def test_gripper_opening_puts_the_fingers_into_the_semantic_state(make_env, tmp_path):
    """RL config gripper_opening: s̄ = (gripper, opening, object, goal); the opening is what the
    fingers span, so closing on nothing and holding the cube differ in s̄ as they do in the images."""
    from binpick.april.observations import PixelsAsSemantic, semantic_observation, semantic_state
    from binpick.core.config import load_config
    from binpick.core.errors import ConfigError
    from binpick.rl.config import RLConfig
    from binpick.rl.common.wrappers import SemanticState

    env = SemanticState(make_env("binpick/FetchPickAndPlace-v0"), gripper=True, opening=True)
    observation, _ = env.reset(seed=0)
    assert env.observation_space["observation"].shape == (7,)
    np.testing.assert_allclose(observation["observation"][4:], observation["achieved_goal"])
    for _ in range(8):
        observation, *_ = env.step(np.array([0, 0, 0, 1.0], dtype=np.float32))
    opened = observation["observation"][3]
    for _ in range(8):
        observation, *_ = env.step(np.array([0, 0, 0, -1.0], dtype=np.float32))
    assert 0.05 < opened < 0.11 and observation["observation"][3] < opened - 0.03, (opened, observation["observation"][3])
    raw = env.unwrapped._get_obs()
    state = semantic_state(raw, True, opening=True)
    assert state.shape == (10,) and np.isclose(state[3], raw["observation"][9:11].sum())
    again = semantic_observation(state, 3)  # the dict a policy trained on s̄ takes: the object before the goal
    np.testing.assert_allclose(again["achieved_goal"], raw["achieved_goal"], atol=1e-6)
    pixels = PixelsAsSemantic(make_env("binpick/FetchPickAndPlace-v0", image="rgb", image_size=64),
                              lambda image: np.zeros((1, 10)), gripper=True, opening=True)
    assert pixels.observation_space["observation"].shape == (7,)
    config = tmp_path / "rl.yaml"
    config.write_text("env: binpick/FetchReach-v0\ngripper_opening: true\n")
    with pytest.raises(ConfigError, match="gripper_opening adds the fingers to a pick-and-place semantic state"):
        load_config(RLConfig, config)


def test_fixed_goal_and_noisy_start_for_table_3_3(make_env):
    fixed = make_env("binpick/FetchReach-v0", goal_offset=(0.1, 0.0, 0.05))
    noisy = make_env("binpick/FetchReach-v0", goal_offset=(0.1, 0.0, 0.05), start_noise=0.1)
    plain_starts = {tuple(np.round(fixed.reset(seed=s)[0]["achieved_goal"], 4)) for s in range(4)}
    observations = [noisy.reset(seed=s)[0] for s in range(8)]
    starts = np.array([o["achieved_goal"] for o in observations])
    goals = np.array([o["desired_goal"] for o in observations])
    assert len(plain_starts) == 1, "without noise the start is fixed"
    assert np.ptp(goals, axis=0).max() < 1e-9, "the goal is the same every episode"
    assert starts.std(axis=0).min() > 0.02, "noisy starts spread over the workspace"
    np.testing.assert_allclose(goals[0] - np.array(next(iter(plain_starts))), [0.1, 0.0, 0.05], atol=0.01)

"""The SAC learners of a run: binpick's goal-conditioned SAC on the episode replay with HER (and GP
imagination when ``gp.enabled``), or SB3's SAC + HerReplayBuffer, the peer it is measured against."""

from __future__ import annotations

import gymnasium as gym
from stable_baselines3 import SAC, HerReplayBuffer

from binpick.rl.common.replay import EpisodeReplayBuffer
from binpick.rl.config import RLConfig
from binpick.rl.gp_her.agents import GoalSAC


def _sac_settings(config: RLConfig, tensorboard: str | None, simulators: int = 1) -> dict:
    """SB3 SAC's constructor settings from the run's ``sac`` section."""
    sac = config.sac
    return dict(learning_rate=sac.learning_rate, batch_size=sac.batch_size, gamma=sac.gamma, tau=sac.tau,
                gradient_steps=sac.gradient_steps * simulators, learning_starts=sac.learning_starts, ent_coef=sac.ent_coef,
                seed=config.seed, policy_kwargs={"net_arch": list(sac.net_arch)}, tensorboard_log=tensorboard, device="cpu")


def build_sb3_sac_her(config: RLConfig, env: gym.Env, tensorboard: str | None, envs=None) -> SAC:
    """SB3's SAC with its HerReplayBuffer ('future' goals, k = ``replay.future_k``): the peer."""
    return SAC("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer,
               replay_buffer_kwargs={"n_sampled_goal": config.replay.future_k, "goal_selection_strategy": "future"},
               **_sac_settings(config, tensorboard))


def build_sac(config: RLConfig, env: gym.Env, tensorboard: str | None, envs=None) -> SAC:
    """binpick's SAC on ``env``, or on ``envs`` (a ``VecEnv`` of N simulators of it): ``sac.gradient_steps``
    are per simulator step, as in a local run, so one vector step of N simulators is followed by N times as many."""
    common = _sac_settings(config, tensorboard, envs.num_envs if envs is not None else 1)
    replay = dict(compute_reward=env.unwrapped.compute_reward, max_episode_steps=env.spec.max_episode_steps,
                  capacity_episodes=config.replay.capacity_episodes, her_additions=config.replay.her_additions,
                  start_fraction=config.replay.start_fraction, her_min_motion=config.replay.her_min_motion,
                  seed=config.seed)
    if config.gp.enabled:
        common["learning_starts"] = config.gp.warmup_episodes * env.spec.max_episode_steps
    return GoalSAC("MultiInputPolicy", env if envs is None else envs, replay_buffer_class=EpisodeReplayBuffer,
                   replay_buffer_kwargs=replay, **common)

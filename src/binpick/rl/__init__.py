"""Reinforcement learning for binpick (thesis ch. 3): trainers, GP imagination, episode HER, A3C,
and evaluation of any policy::

    from binpick.rl import TrainedPolicy, evaluate_policy
    policy = TrainedPolicy.load("runs/fetchreach_gp_her/<time>")      # or a policy.safetensors file
    env = TrainedPolicy.make_env("runs/fetchreach_gp_her/<time>")     # the env as the run trained on it
    print(evaluate_policy(policy, env, episodes=20).summary())
"""

from binpick.rl.common.evaluate import EvalResult, evaluate_policy, random_policy

__all__ = ["EvalResult", "TrainedPolicy", "evaluate_policy", "random_policy"]


def __getattr__(name: str):
    """``TrainedPolicy`` imports Stable-Baselines3 and torch: only when it is asked for."""
    if name == "TrainedPolicy":
        from binpick.rl.train import TrainedPolicy

        return TrainedPolicy
    raise AttributeError(f"module 'binpick.rl' has no attribute {name!r}")

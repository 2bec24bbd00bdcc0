"""Reinforcement learning for binpick (thesis ch. 3), shaped as Stable-Baselines3 keeps its own:
``rl/common`` (replay with HER, wrappers, evaluation, saving without pickle, curriculum, demonstrations),
``rl/gp_her`` (GP dynamics, imagined episodes, the goal-conditioned SAC), ``rl/a3c``, ``rl/dqn``, each
with its config section; :mod:`binpick.rl.train` runs any of them. Any trained policy::

    from binpick import Policy
    from binpick.rl import evaluate_policy
    policy = Policy.load("runs/fetchreach_gp_her/<time>")      # or a policy.safetensors file
    env = Policy.make_env("runs/fetchreach_gp_her/<time>")     # the env as the run trained on it
    print(evaluate_policy(policy, env, episodes=20).summary())
"""

from binpick.rl.common.evaluate import EvalResult, evaluate_policy, random_policy

__all__ = ["EvalResult", "evaluate_policy", "random_policy"]


def __getattr__(name: str):
    if name == "TrainedPolicy":  # renamed: one class loads every trained policy
        raise AttributeError("binpick.rl.TrainedPolicy is now binpick.Policy: Policy.load(run).predict(obs) -> (action, state)")
    raise AttributeError(f"module 'binpick.rl' has no attribute {name!r}")

"""Reinforcement learning for binpick (thesis ch. 3). For now: evaluation of any policy."""

from binpick.rl.evaluate import EvalResult, evaluate_policy, random_policy

__all__ = ["EvalResult", "evaluate_policy", "random_policy"]

"""GP + HER (thesis ch. 3): GP dynamics fitted on real episodes, imagined episodes from them, the goal-conditioned SAC that learns from both."""

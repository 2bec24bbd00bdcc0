"""A3C (thesis ch. 3, §4.5): the actor-critic networks, the trainer with worker processes, pre-training by behaviour cloning."""

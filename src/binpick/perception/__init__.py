"""Auto-perception networks (thesis ch. 4): images -> a latent partly tied to the semantic state."""

from binpick.perception.autoencoder import AutoPerception, PerceptionConfig
from binpick.perception.train import load_perception, save_perception, train_perception

__all__ = ["AutoPerception", "PerceptionConfig", "load_perception", "save_perception", "train_perception"]

"""Auto-perception networks (thesis ch. 4): images -> a latent partly tied to the semantic state."""

from binpick.april.perception.autoencoder import AutoPerception, PerceptionConfig
from binpick.april.perception.train import PERCEPTION_FILE, load_perception, perception_path, save_perception, train_perception

__all__ = ["PERCEPTION_FILE", "AutoPerception", "PerceptionConfig", "load_perception", "perception_path", "save_perception",
           "train_perception"]

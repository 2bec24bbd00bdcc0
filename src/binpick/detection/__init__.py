"""Repeated object detection (thesis ch. 5, §6.3): find every other instance of a known one.

    from binpick.detection import Detector
    detector = Detector.load("rod_tiny_320")                              # or a run folder / .safetensors
    detector.predict("scene.png", query_box=(120, 80, 40, 52)).save("overlay.png")
"""

from binpick.detection.detector import Detector, shipped_weights
from binpick.detection.model import DetectorNetwork, ModelSpec
from binpick.detection.predict import Prediction, predict
from binpick.detection.train import DetectorTrainer
from binpick.detection.weights_file import load_detector, save_detector

__all__ = ["Detector", "DetectorNetwork", "DetectorTrainer", "ModelSpec", "Prediction", "load_detector", "predict",
           "save_detector", "shipped_weights"]

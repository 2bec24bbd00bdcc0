"""Repeated object detection (thesis ch. 5, §6.3): find every other instance of a known one.

    from binpick.detection import load_detector, predict
    model = load_detector("runs/rod_warehouse/<time>")
    prediction = predict(model, "scene.png", query_box=(120, 80, 40, 52))
"""

from binpick.detection.model import Detector, ModelSpec
from binpick.detection.predict import Prediction, predict
from binpick.detection.train import DetectorTrainer, load_detector, save_detector

__all__ = ["Detector", "DetectorTrainer", "ModelSpec", "Prediction", "load_detector", "predict", "save_detector"]

"""The detection job as one object, in the shape users know from Ultralytics::

    detector = Detector.load("rod_tiny_320")                 # shipped weights, a .safetensors file or a run folder
    result = detector.predict("scene.png", query_box=(120, 80, 40, 52))
    result.save("overlay.png"); print(result.to_json())      # or result.plot() -> RGB array
    metrics = detector.val("runs/data/bins/annotations_val.json")
    trained = Detector.train("configs/detection/rod_warehouse.yaml", epochs=2)   # overrides as keyword arguments

``predict`` finds every other instance of the query (a box in the image, or a shop photo for
photo-conditioned weights); ``val`` is COCO AP against the data set's targets; ``train`` runs a
:class:`~binpick.detection.train.DetectorTrainer` and returns the trained detector.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from binpick.detection.model import DetectorNetwork
from binpick.detection.predict import Prediction, predict
from binpick.core.errors import ConfigError
from binpick.core.runs import SILENT, RunCallback

# crop query (§5.3); shop-photo query (§6.3); the photo detector the pick pipeline uses (the one chosen by
# tools/rebuild.py photo; its weights' metadata say how, and whether it carries a pickability head)
SHIPPED = ("rod_tiny_320", "rod_photo_tiny_320", "rod_photo_learnt_tiny_320")
PICKING = "rod_photo_learnt_tiny_320"


def shipped_weights(name: str) -> Path:
    """The path of weights that ship inside the package, by name (one of ``SHIPPED``)."""
    from importlib.resources import files

    stem = name.removesuffix(".safetensors")
    path = Path(str(files("binpick.detection") / "weights" / f"{stem}.safetensors"))
    if stem not in SHIPPED or not path.is_file():
        from binpick.core.config import did_you_mean

        raise ConfigError(f"no shipped detector weights named {name!r}{did_you_mean(stem, SHIPPED)}; shipped: {', '.join(SHIPPED)}")
    return path


class Detector:
    """Repeated-object detector: a trained network plus what it was trained on."""

    def __init__(self, network: DetectorNetwork, source: Path | None = None, metrics: dict[str, Any] | None = None) -> None:
        self.network, self.source, self.metrics = network, source, metrics
        self._inference: DetectorNetwork | None = None
        self.runtime = "torch"

    @property
    def inference_network(self) -> DetectorNetwork:
        """``network`` for prediction only (:meth:`DetectorNetwork.for_inference`: batch norms folded,
        ~1.2x faster predict at batch 1 on a CPU, the same detections), made on first use. Train and save
        ``network``; a change to it after this was made is not seen here."""
        if self._inference is None:
            self._inference = self.network.for_inference()
        return self._inference

    @classmethod
    def load(cls, weights: str | Path = "rod_tiny_320", pickability: bool = True, runtime: str = "torch") -> Detector:
        """A shipped name, a ``.safetensors`` (or older ``.pt``) file, or a run folder. ``pickability=False``
        leaves out a pickability head the weights hold (binpick.detection.pickability): the detector's
        own ranking, from colour alone. ``runtime="onnx"``: predict through ONNX Runtime (:meth:`using`)."""
        from binpick.detection.weights_file import load_detector

        path = Path(weights)
        if not path.exists() and str(weights).removesuffix(".safetensors") in SHIPPED:
            path = shipped_weights(str(weights))
        elif not path.exists():
            from binpick.core.config import did_you_mean

            raise ConfigError(f"no detector weights at {str(weights)!r}: give a run folder, a .safetensors file or a shipped "
                              f"name{did_you_mean(path.name.removesuffix('.safetensors'), SHIPPED)}; shipped: {', '.join(SHIPPED)}")
        network = load_detector(path)
        return cls(network if pickability else network.without_pickability(), path).using(runtime)

    def using(self, runtime: str, onnx_file: str | Path | None = None) -> Detector:
        """This detector predicting through ``runtime``: ``torch``, or ``onnx`` (ONNX Runtime on the graph
        :meth:`export` writes, ``onnx_file`` or one kept in binpick's cache; the same boxes, a
        pickability head's re-scoring still in PyTorch)."""
        from binpick.core.config import check_choice
        from binpick.detection.onnx_runtime import RUNTIMES

        check_choice("runtime", runtime, RUNTIMES)
        self._inference = None
        if runtime == "onnx":
            from binpick.detection.onnx_runtime import OnnxNetwork, cached_export

            network = self.network.for_inference()
            self._inference = OnnxNetwork(network, onnx_file if onnx_file is not None else cached_export(network))
        self.runtime = runtime
        return self

    def export(self, format: str = "onnx", path: str | Path | None = None) -> Path:
        """Write the detector for deployment: ``onnx`` (binpick.detection.onnx_runtime), to ``path``, a
        file or a folder for ``<weights name>.onnx`` (default: here). Returns the file's path."""
        from binpick.core.config import check_choice
        from binpick.detection.onnx_runtime import export_onnx

        check_choice("format", format, ("onnx",))
        stem = (self.source.parent.name if self.source and self.source.name == "model.safetensors"
                else self.source.stem if self.source else "detector")
        path = Path(path) if path is not None else Path(".")
        return export_onnx(self.network, path / f"{stem}.{format}" if path.is_dir() else path)

    # ------------------------------------------------------------------ what it is
    @property
    def query(self) -> str:
        """``crop`` (a box in the image) or ``photo`` (a shop photo)."""
        return self.network.spec.query

    @property
    def trained_products(self) -> list[str] | None:
        return self.network.trained_products

    @property
    def trained_domains(self) -> list[str]:
        """Scene domains it was trained on (``default``, ``random``, ...), pre-training included."""
        return self.network.trained_domains

    def __repr__(self) -> str:
        spec = self.network.spec
        sees = " that sees the query" + (" (factorised)" if spec.pickability_factorised else "") if spec.pickability_query else ""
        head = f", pickability head{sees}" if spec.pickability else ""
        return (f"Detector({spec.method} {spec.layout}, {spec.backbone} backbone, {self.network.image_size} px, "
                f"{spec.query} query{head}, from {self.source})")

    # ------------------------------------------------------------------ jobs
    def predict(self, image: np.ndarray | str | Path, query_box=None, query_image: np.ndarray | str | Path | None = None,
                min_score: float = 0.3, depth: np.ndarray | str | Path | None = None) -> Prediction:
        """Boxes (x, y, w, h) and scores of the other instances the detector scores at least
        ``min_score`` (a pickability head then re-scores them, and may score them lower); the result
        plots and saves itself. ``depth`` (metres, or a 16-bit PNG in mm) is needed by detectors that read depth."""
        from binpick.core.config import check_range

        check_range("min_score", min_score, 0.0, 1.0)
        box = None if query_box is None else np.asarray(query_box, dtype=np.float32)
        if box is not None and box.shape != (4,):
            raise ConfigError(f"query_box must be x, y, w, h, got {query_box!r}")
        return predict(self.inference_network, image, box, query_image, score_threshold=min_score, depth=depth)

    def val(self, data: str | Path, targets: str | None = None, batch_size: int = 8, callback: RunCallback = SILENT) -> dict:
        """COCO AP50 and mAP on an annotations file, against ``targets`` (default: what it was trained on)."""
        from binpick.detection.data import RepeatedInstances, TaskDataset
        from binpick.detection.train import evaluate_model

        targets = targets or self.network.trained_config.get("data", {}).get("targets", "all")
        source = RepeatedInstances(data, targets=targets)
        dataset = TaskDataset(source, self.network.image_size, self.query,
                              self.network.query_size, frame_photos=self.network.spec.frames_photos,
                              depth=self.network.spec.reads_depth)
        with callback.task("evaluating", len(dataset)) as task:
            metrics = evaluate_model(self.network, dataset, batch_size, progress=lambda n: task.update(advance=n))
        return metrics | {"targets": targets, "scenes_trained_on": self.scenes_trained_on(source)}

    def scenes_trained_on(self, source) -> int | None:
        """How many of ``source``'s scenes the last training set (still on disk) also held: data sets
        made with one generator ``--seed`` share scenes across their splits. None: unknown."""
        from binpick.detection.data import RepeatedInstances
        from binpick.core.errors import BinpickError

        train = self.network.trained_config.get("data", {}).get("train")
        if not isinstance(train, str) or not Path(train).is_file() or not source.scene_seeds:
            return None
        try:
            return len(RepeatedInstances(train).scene_seeds & source.scene_seeds)
        except BinpickError:
            return None

    @classmethod
    def train(cls, config: str | Path, runs: str | Path = "runs", callback: RunCallback = SILENT, **overrides: Any) -> Detector:
        """Train a new run from a YAML config; ``overrides`` are ``--set`` keys with ``.`` written as
        ``__`` (``train__epochs=2``) or plain top-level keys. Returns the trained detector."""
        from binpick.core.jobs import dotted, open_job
        from binpick.detection.weights_file import WEIGHTS_FILE, load_detector

        trainer = open_job(config, task="detect", runs=runs, overrides=dotted(overrides))
        metrics = trainer.run(callback)
        return cls(load_detector(trainer.run_dir / WEIGHTS_FILE), trainer.run_dir, metrics)

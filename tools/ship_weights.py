"""Copy a trained detector into the package as half-precision safetensors weights (what `binpick detect
predict`, `binpick pick` and the demo use when no --weights is given). The file also lists the
products it has learnt (its training set's and those of the weights it started from), so the pick pipeline can say whether an order is zero-shot,
and the scene domains it was trained on (``default``, ``random``, ...: pre-training and fine-tuning).

    python tools/ship_weights.py runs/rod16/finetune_rod/<time> rod_tiny_320
    python tools/ship_weights.py runs/rod16/finetune_rod_photo/<time> rod_photo_tiny_320 0.1
    python tools/ship_weights.py runs/grasp/rod_finetune_photo_learnt/<time> rod_photo_learnt_tiny_320 0.1

A third argument is the score threshold the pick pipeline keeps detections above for these weights
(scores are calibrated per model: the pipeline's 0.2 dropped every copy in 11 of 50 seen orders for
rod_photo_tiny_320, whose true copies score lower; 0.1 placed 76% of the first 25).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from binpick.core.config import load_run_config
from binpick.detection.config import DetectConfig
from binpick.detection.training_data import learnt_products
from binpick.detection.weights_file import load_detector, read_detector_file, save_detector, weights_path

ROOT = Path(__file__).resolve().parents[1]
WEIGHTS = ROOT / "src" / "binpick" / "detection" / "weights"


def main() -> None:
    if len(sys.argv) not in (3, 4):
        sys.exit(__doc__)
    run, name = Path(sys.argv[1]), sys.argv[2]
    threshold = {"score_threshold": float(sys.argv[3])} if len(sys.argv) == 4 else {}
    model = load_detector(run)
    os.chdir(ROOT)  # run configs name their data and starting weights relative to the repository
    products = learnt_products(load_run_config(DetectConfig, run if run.is_dir() else run.parent))
    domains = read_detector_file(weights_path(run))[1].get("trained_domains") or ["default"]
    path = WEIGHTS / f"{name}.safetensors"
    save_detector(model, path, {"config": model.trained_config, "source_run": str(run), "trained_products": products,
                                "trained_domains": domains, **threshold}, half=True)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB; trained on {len(products)} products, domains {', '.join(domains)})")


if __name__ == "__main__":
    main()

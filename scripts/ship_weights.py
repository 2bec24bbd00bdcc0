"""Copy a trained detector into the package as half-precision weights (what `binpick detect predict`
and the demo use when no --weights is given).

    python scripts/ship_weights.py runs/rod/rod_warehouse/<time> rod_tiny_256
"""

from __future__ import annotations

import sys
from pathlib import Path

from binpick.detection.train import load_detector, save_detector

WEIGHTS = Path(__file__).resolve().parents[1] / "src" / "binpick" / "detection" / "weights"


def main() -> None:
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    run, name = Path(sys.argv[1]), sys.argv[2]
    model = load_detector(run)
    path = WEIGHTS / f"{name}.pt"
    save_detector(model, path, {"config": model.trained_config, "source_run": str(run)}, half=True)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()

"""binpick: learned bin picking for warehouse order fulfilment.

Importing the package registers its Gymnasium envs (``binpick/Arm2D-v0``, ...). MuJoCo needs an
OpenGL platform for images; on a headless machine binpick defaults ``MUJOCO_GL`` to ``egl`` (set it
yourself to override, e.g. ``osmesa``).
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # must happen before mujoco is first imported
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

from binpick.envs import ENV_IDS, make  # noqa: E402  (registers the envs)

__version__ = "0.2.0"
__all__ = ["ENV_IDS", "Detector", "Picker", "Policy", "make", "train", "__version__"]

# The deployable objects and the one training entry point, imported when first used (importing binpick
# stays light: no torch until a detector or a trainer is asked for).
_LAZY = {"train": "binpick.core.jobs", "Detector": "binpick.detection", "Picker": "binpick.picking",
         "Policy": "binpick.core.policy"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    if name == "TrainedPolicy":  # renamed: one class loads every trained policy
        raise AttributeError("binpick.TrainedPolicy is now binpick.Policy: Policy.load(run).predict(obs) -> (action, state), "
                             "for RL runs of any algorithm and APRiL runs alike")
    raise AttributeError(f"module 'binpick' has no attribute {name!r}")

"""Render docs/img/<env>.png: one frame per env as a person sees it, beside the policy's image input.

    .venv/bin/python tools/render_docs_images.py
"""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

import binpick  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "docs" / "img"
SIZE = 320


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for env_id in binpick.ENV_IDS:
        name = env_id.split("/")[1].removesuffix("-v0")
        if name == "Arm2D":
            env = binpick.make(env_id, render_mode="rgb_array", render_size=SIZE)
        else:
            env = binpick.make(env_id, render_mode="rgb_array", width=SIZE, height=SIZE, image="rgb", image_size=84)
        observation, _ = env.reset(seed=3)
        frame = env.render()
        image = observation if isinstance(observation, np.ndarray) else observation["image"]
        env.close()
        # the policy's input, enlarged with visible pixels, to the right of the view
        pixels = Image.fromarray(image).resize((SIZE, SIZE), Image.Resampling.NEAREST)
        sheet = Image.new("RGB", (2 * SIZE + 8, SIZE), (255, 255, 255))
        sheet.paste(Image.fromarray(frame), (0, 0))
        sheet.paste(pixels, (SIZE + 8, 0))
        sheet.save(OUT / f"{name}.png", optimize=True)
        print(f"wrote {OUT / f'{name}.png'}")


if __name__ == "__main__":
    main()

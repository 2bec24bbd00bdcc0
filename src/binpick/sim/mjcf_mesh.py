"""Reading OBJ files that MuJoCo's own reader handles only in part."""

from __future__ import annotations

import functools
from pathlib import Path


@functools.lru_cache(maxsize=256)
def merged_obj(path: Path) -> tuple[str, str] | None:
    """Vertices and triangles of an OBJ made of several objects (``o`` groups), as MJCF attributes.

    MuJoCo's OBJ reader renders only the first group of such files (pybullet's random shapes are
    convex decompositions of 4-8 parts), so these meshes are passed inline instead. None for a
    single-group file, which MuJoCo reads itself (keeping its texture coordinates)."""
    text = Path(path).read_text(errors="replace")
    if sum(line.startswith(("o ", "g ")) for line in text.splitlines()) <= 1:
        return None
    vertices, faces = [], []
    for line in text.splitlines():
        if line.startswith("v "):
            vertices.append(line.split()[1:4])
        elif line.startswith("f "):
            corners = [int(token.split("/")[0]) for token in line.split()[1:]]
            corners = [c - 1 if c > 0 else len(vertices) + c for c in corners]
            faces += [(corners[0], corners[i], corners[i + 1]) for i in range(1, len(corners) - 1)]
    return " ".join(" ".join(v) for v in vertices), " ".join(f"{a} {b} {c}" for a, b, c in faces)

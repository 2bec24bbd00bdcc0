"""Reading OBJ files that MuJoCo's own reader handles only in part."""

from __future__ import annotations

import functools
import math
from pathlib import Path


@functools.lru_cache(maxsize=256)
def merged_obj(path: Path) -> tuple[str, str] | None:
    """Vertices and triangles of an OBJ made of several objects (``o`` groups), as MJCF attributes.

    MuJoCo's OBJ reader renders only the first group of such files (pybullet's random shapes are
    convex decompositions of 4-8 parts), so these meshes are passed inline instead. None for a
    single-group file, which MuJoCo reads itself (keeping its texture coordinates)."""
    from binpick.core.errors import ConfigError
    from binpick.core.files import read_bytes

    text = read_bytes(path, "mesh", max_bytes=256 << 20).decode("utf-8", errors="replace")
    if sum(line.startswith(("o ", "g ")) for line in text.splitlines()) <= 1:
        return None
    vertices: list[tuple[float, ...]] = []
    faces = []
    for number, line in enumerate(text.splitlines(), start=1):
        try:  # numbers only reach the MJCF: nothing in the file can add XML of its own
            if line.startswith("v "):
                vertex = tuple(float(token) for token in line.split()[1:4])
                if len(vertex) != 3 or not all(math.isfinite(v) for v in vertex):
                    raise ValueError("a vertex is 3 finite numbers")
                vertices.append(vertex)
            elif line.startswith("f "):
                corners = [int(token.split("/")[0]) for token in line.split()[1:]]
                corners = [c - 1 if c > 0 else len(vertices) + c for c in corners]
                if len(corners) < 3 or not all(0 <= c < len(vertices) for c in corners):
                    raise ValueError("a face names 3 or more existing vertices")
                faces += [(corners[0], corners[i], corners[i + 1]) for i in range(1, len(corners) - 1)]
        except ValueError as error:
            raise ConfigError(f"mesh {str(path)!r} line {number} cannot be read ({error}): {line[:60]!r}") from None
    return " ".join(f"{x!r} {y!r} {z!r}" for x, y, z in vertices), " ".join(f"{a} {b} {c}" for a, b, c in faces)

"""Run folders and crash-safe checkpoints.

Checkpoints: write a whole folder, then switch to it with one atomic rename.

``checkpoints/ckpt-<steps>/`` is filled under a temporary name and renamed when complete; the
one-line file ``checkpoints/latest`` names the current one and is replaced atomically. A ``kill -9``
at any moment leaves either the previous checkpoint or the new one, never half of one.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path


def commit_checkpoint(directory: Path, steps: int, write: Callable[[Path], None]) -> Path:
    """Call ``write(folder)`` on a fresh folder, publish it as the latest checkpoint, drop older ones."""
    directory = Path(directory)
    final = directory / f"ckpt-{steps:09d}"
    partial = directory / f".partial-{steps:09d}"
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    write(partial)
    shutil.rmtree(final, ignore_errors=True)
    os.replace(partial, final)
    pointer = directory / "latest.tmp"
    pointer.write_text(final.name)
    os.replace(pointer, directory / "latest")
    for old in directory.glob("ckpt-*"):
        if old != final:
            shutil.rmtree(old, ignore_errors=True)
    return final


def latest_checkpoint(directory: Path) -> Path | None:
    """The folder ``latest`` names, or None before the first checkpoint."""
    pointer = Path(directory) / "latest"
    return Path(directory) / pointer.read_text().strip() if pointer.exists() else None


def new_run_dir(runs_root: Path, name: str, config_yaml: str) -> Path:
    """``runs_root/name/<YYYYmmdd-HHMMSS>[-k]/`` holding ``config.yaml``: everything to re-run it."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    base = Path(runs_root) / name
    base.mkdir(parents=True, exist_ok=True)
    for attempt in range(1000):
        run_dir = base / (stamp if attempt == 0 else f"{stamp}-{attempt}")
        try:
            run_dir.mkdir()
        except FileExistsError:
            continue
        (run_dir / "config.yaml").write_text(config_yaml)
        return run_dir
    raise RuntimeError(f"could not create a new run folder under {base}")

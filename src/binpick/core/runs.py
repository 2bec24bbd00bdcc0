"""The run layer: what every long job in binpick (RL, A3C, detection, APRiL, data generation) shares.

A job has one shape (:class:`Job`): ``Job.new(config, runs)`` makes a run folder for a validated
config, ``Job.resume(run_dir)`` continues one, ``job.run(callback)`` does the work and returns its
metrics. A run folder ``runs/<name>/<time>/`` holds ``config.yaml`` (everything to re-run it),
``checkpoints/``, TensorBoard events and the job's outputs.

Checkpoints: write a whole folder, then switch to it with one atomic rename.
``checkpoints/ckpt-<steps>/`` is filled under a temporary name and renamed when complete; the
one-line file ``checkpoints/latest`` names the current one and is replaced atomically. A ``kill -9``
at any moment leaves either the previous checkpoint or the new one, never half of one. Single files
are written atomically by :mod:`binpick.core.files` (text, JSON, bytes, npz) and :mod:`binpick.core.tensorfile`
(safetensors).

Progress: library code never owns the terminal. A job reports through a :class:`RunCallback`; the
CLI passes one that draws Rich progress bars, the default stays silent.
"""

from __future__ import annotations

import os
import re
import shutil
import time
from collections.abc import Callable, Iterator
from typing import Any, Protocol
from contextlib import contextmanager
from pathlib import Path

import yaml

from binpick.core.config import to_dict
from binpick.core.errors import ConfigError, InputFileError
from binpick.core.files import atomic_write_text, ensure_dir, fsync_dir, read_text

_NAME = re.compile(r"ckpt-\d{9}")


def commit_checkpoint(directory: Path, steps: int, write: Callable[[Path], None]) -> Path:
    """Call ``write(folder)`` on a fresh folder, publish it as the latest checkpoint, drop older ones."""
    directory = Path(directory)
    final = directory / f"ckpt-{steps:09d}"
    partial = directory / f".partial-{steps:09d}"
    shutil.rmtree(partial, ignore_errors=True)
    ensure_dir(partial, "checkpoint")
    write(partial)
    fsync_dir(partial)
    shutil.rmtree(final, ignore_errors=True)
    os.replace(partial, final)
    atomic_write_text(directory / "latest", final.name)
    for old in directory.glob("ckpt-*"):
        if old != final:
            shutil.rmtree(old, ignore_errors=True)
    return final


def latest_checkpoint(directory: Path) -> Path | None:
    """The folder ``latest`` names, or None before the first checkpoint; a damaged pointer is one line."""
    pointer = Path(directory) / "latest"
    if not pointer.exists():
        return None
    name = read_text(pointer, "checkpoint pointer").strip()
    if not _NAME.fullmatch(name):
        raise InputFileError(f"checkpoint pointer {str(pointer)!r} is damaged: it names {name[:40]!r}, "
                             "not a checkpoint folder (ckpt-<steps>)")
    folder = Path(directory) / name
    if not folder.is_dir():
        raise InputFileError(f"checkpoint pointer {str(pointer)!r} names {name}, which does not exist: "
                             "the run folder was damaged (delete the pointer to restart from zero)")
    return folder


_RUN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,127}")


def check_run_name(name: str) -> str:
    """A config's ``name`` becomes a folder inside the runs folder: a plain name (letters, digits,
    ``_ . + -``), never a path that could leave it (``..``, ``/``, an absolute path, a NUL)."""
    if not isinstance(name, str) or not _RUN_NAME.fullmatch(name) or ".." in name:
        raise ConfigError(f"name {str(name)[:80]!r} must be a plain folder name (letters, digits, _ . + -, up to 128): "
                          "a run's folder is made inside the runs folder, never elsewhere")
    return name


def new_run(runs_root: str | Path, config: Any, task: str) -> Path:
    """A new run folder for a job's validated ``config`` (a dataclass with a ``name``), its
    ``config.yaml`` the config with the job's ``task`` first: everything to re-run or resume it."""
    return new_run_dir(Path(runs_root), config.name, yaml.safe_dump({"task": task, **to_dict(config)}, sort_keys=False))


def pinned_run(folder: str | Path, config: Any, task: str) -> Path:
    """A run folder a config names itself (its ``out``), with the same ``config.yaml`` as :func:`new_run`
    writes; a run already there resumes when its settings agree (each job checks them)."""
    folder = ensure_dir(Path(folder), "out")
    atomic_write_text(folder / "config.yaml", yaml.safe_dump({"task": task, **to_dict(config)}, sort_keys=False))
    return folder


def new_run_dir(runs_root: Path, name: str, config_yaml: str) -> Path:
    """``runs_root/name/<YYYYmmdd-HHMMSS>[-k]/`` holding ``config.yaml``: everything to re-run it."""
    check_run_name(name)
    run_dir = new_folder(Path(runs_root) / name)
    atomic_write_text(run_dir / "config.yaml", config_yaml)
    return run_dir


def new_folder(parent: Path) -> Path:
    """A new empty folder ``parent/<YYYYmmdd-HHMMSS>[-k]/`` (never one that exists: two runs started in the
    same second get their own)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    base = ensure_dir(Path(parent), "runs folder")
    for attempt in range(1000):
        folder = base / (stamp if attempt == 0 else f"{stamp}-{attempt}")
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        return folder
    raise RuntimeError(f"could not create a new folder under {base}")


@contextmanager
def removed_on_error(run_dir: Path) -> Iterator[Path]:
    """A new run folder that is deleted again if setting the run up fails (a bad env parameter, a
    damaged ``init_from`` run): failed starts leave no empty folders behind."""
    try:
        yield run_dir
    except BaseException:
        shutil.rmtree(run_dir, ignore_errors=True)
        try:
            run_dir.parent.rmdir()  # runs/<name>/ too, if this was its only run
        except OSError:
            pass
        raise


# ---------------------------------------------------------------------- progress
class Task:
    """One progress bar's worth of work. The silent default does nothing; a front end overrides it."""

    def update(self, done: int | None = None, *, advance: int = 0, total: int | None = None, status: str | None = None) -> None:
        """Set ``done`` (or add ``advance``) units of work, optionally a new ``total`` and status text."""

    def close(self) -> None:
        """The task is over (its bar may stay on screen)."""

    def __enter__(self) -> Task:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class StopRequested(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM) asked a job to stop, raised at a step boundary by its callback's next
    progress update: the job's state is whole there, so it may checkpoint before it goes."""


class RunCallback:
    """How a job reports: tasks with progress, and one-line messages. This base class is silent;
    ``binpick.cli`` passes one that draws Rich progress bars, tests and scripts may pass their own."""

    def task(self, label: str, total: int | None = None, done: int = 0) -> Task:
        return Task()

    def message(self, text: str) -> None:
        """A line worth showing a person (a stage started, a file written)."""


SILENT = RunCallback()


class Job(Protocol):
    """The shape of every long job (see the module docstring)."""

    run_dir: Path

    @classmethod
    def new(cls, config: Any, runs: Path) -> Job: ...

    @classmethod
    def resume(cls, run_dir: Path) -> Job: ...

    def run(self, callback: RunCallback = SILENT) -> dict[str, Any]: ...

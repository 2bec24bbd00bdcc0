"""Worker processes that start without importing torch and MuJoCo again.

A spawned worker is a fresh interpreter: it imports torch, MuJoCo and binpick before its first step,
3-4 s of CPU each on a small machine, every time a data set or an A3C run starts its workers. A fork of
the trainer itself is not safe (its simulators may hold EGL contexts, its torch thread pools). The
forkserver start method forks each worker from a small server process that has imported the modules
named here once and created nothing else: workers start in a fraction of a second, with nothing of the
parent's state but what they are sent.
"""

from __future__ import annotations

import multiprocessing
import os
from multiprocessing.context import BaseContext


def worker_context(*preload: str) -> BaseContext:
    """A multiprocessing context whose workers are forked from a server that imported ``preload``
    (module names) when it started: the first call in a process starts the server, later calls reuse it.
    The server keeps the environment variables of the moment it started; ``BINPICK_SPAWN_WORKERS=1``
    gives spawned workers instead."""
    if os.environ.get("BINPICK_SPAWN_WORKERS") == "1" or "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(preload))
    return context

"""Ctrl-C and SIGTERM during a job: the first asks it to stop at its next progress update, a second
stops it at once; a job started with Ctrl-C ignored (in the background) keeps ignoring it but still
stops on SIGTERM; the handlers it found are back when it ends."""

from __future__ import annotations

import io
import os
import signal
import time

import pytest
from rich.console import Console

from binpick.core.runs import StopRequested
from binpick.cli.terminal import RichCallback


def callback() -> RichCallback:
    return RichCallback(Console(file=io.StringIO()))


def test_the_first_signal_stops_at_the_next_update_and_the_second_at_once():
    outside = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal (a suite run with `&` ignores it)
    try:
        with callback() as progress:
            task = progress.task("job", 10)
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # the handler ran and returned: the job goes on to its next step
            with pytest.raises(StopRequested):
                task.update(1)
            with pytest.raises(KeyboardInterrupt):
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)
        assert signal.getsignal(signal.SIGINT) == signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, outside)


def test_a_background_job_keeps_ignoring_ctrl_c_and_stops_on_sigterm():
    ignored = signal.signal(signal.SIGINT, signal.SIG_IGN)
    term = signal.getsignal(signal.SIGTERM)
    try:
        with callback() as progress:
            assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
            task = progress.task("job", 10)
            os.kill(os.getpid(), signal.SIGINT)  # ignored
            task.update(1)
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)
            with pytest.raises(StopRequested):
                task.update(2)
        assert signal.getsignal(signal.SIGTERM) == term
    finally:
        signal.signal(signal.SIGINT, ignored)


def test_plain_lines_when_the_output_is_not_a_terminal():
    out = io.StringIO()
    with RichCallback(Console(file=out), log_every=0.0) as progress, progress.task("epochs", 4) as task:
        for done in range(1, 5):
            task.update(done, status=f"loss {1 / done:.2f}")
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("epochs: 1/4 (25%) in 0 s") and "loss 1.00" in lines[0]
    assert lines[-1].startswith("epochs: 4/4 (100%)") and "left" not in lines[-1]

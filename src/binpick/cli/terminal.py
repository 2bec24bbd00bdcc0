"""What a person sees in a terminal: Rich progress bars for any job's :class:`~binpick.core.runs.RunCallback`.

The one place binpick sets up progress bars. ``binpick.cli`` and the benchmark scripts use it;
library code only ever talks to a ``RunCallback``.
"""

from __future__ import annotations

import os
import signal
import threading
import time

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from binpick.core.runs import RunCallback, StopRequested, Task


class _RichTask(Task):
    def __init__(self, progress: Progress, task_id, owner: RichCallback) -> None:
        self.progress, self.task_id, self.owner = progress, task_id, owner

    def update(self, done: int | None = None, *, advance: int = 0, total: int | None = None, status: str | None = None) -> None:
        self.owner.stop_if_interrupted()
        fields = {} if status is None else {"status": status}
        if total is not None:
            fields["total"] = total
        if done is not None:
            fields["completed"] = done
        self.progress.update(self.task_id, advance=advance or None, **fields)
        self.owner.log_line(self.task_id)

    def close(self) -> None:
        self.owner.log_line(self.task_id, last=True)
        self.progress.stop_task(self.task_id)


class RichCallback(RunCallback):
    """Progress bars (one per task, with a status column) and messages printed above them.

    Use as a context manager: ``with RichCallback(console) as callback: job.run(callback)``. Inside it,
    the first Ctrl-C (or SIGTERM, which a cluster's scheduler sends) asks the job to stop: the next
    progress update raises ``KeyboardInterrupt``, at a step boundary, where a job's state is whole and
    it writes a checkpoint on its way out. A second Ctrl-C raises at once. (Raising from the handler
    itself could land in a finaliser, where Python drops the exception and the job runs on.) A job
    started with SIGINT ignored (``nohup ... &``) keeps ignoring it; SIGTERM still stops it."""

    def __init__(self, console: Console | None = None, log_every: float = 30.0) -> None:
        self.console = console or Console(markup=False)
        self.interrupted = False
        self._previous_handlers: dict[int, object] = {}
        # output to a file or a pipe gets plain lines (first, every log_every seconds, last), as SB3's logger
        # prints them, instead of bars that only a terminal redraws
        self.plain, self.log_every = not self.console.is_terminal, log_every
        self._logged: dict[object, float] = {}
        self.progress = Progress(TextColumn("{task.description}", style="bold", markup=False), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("{task.fields[status]}", markup=False), TimeElapsedColumn(), TimeRemainingColumn(),
                                 console=self.console, disable=self.plain)

    def log_line(self, task_id, last: bool = False) -> None:
        """In plain mode, one line for the task: its first update, then every ``log_every`` s, and its end."""
        if not self.plain:
            return
        now = time.monotonic()
        first = task_id not in self._logged
        if not (first or last or now - self._logged[task_id] >= self.log_every):
            return
        self._logged[task_id] = now
        task = next(t for t in self.progress.tasks if t.id == task_id)
        done = f"{task.completed:,.0f}" + (f"/{task.total:,.0f} ({task.percentage:.0f}%)" if task.total else "")
        elapsed = f"{task.elapsed or 0.0:.0f} s"
        remaining = f", {task.time_remaining:.0f} s left" if task.time_remaining is not None and not last else ""
        status = f"  {task.fields['status']}" if task.fields.get("status") else ""
        self.console.print(f"{task.description}: {done} in {elapsed}{remaining}{status}", markup=False, highlight=False, soft_wrap=True)

    def task(self, label: str, total: int | None = None, done: int = 0) -> Task:
        self.progress.start()
        return _RichTask(self.progress, self.progress.add_task(label, total=total, completed=done, status=""), self)

    def message(self, text: str) -> None:
        self.progress.console.print(text, markup=False, highlight=False)

    def close(self) -> None:
        self.progress.stop()

    def stop_if_interrupted(self) -> None:
        if self.interrupted:
            raise StopRequested

    def _on_ctrl_c(self, signum, frame) -> None:
        if self.interrupted:  # the second: now
            raise KeyboardInterrupt
        self.interrupted = True
        # a plain write: printing through Rich here could wait on a lock the interrupted code holds
        os.write(2, b"\nstopping at the next step (Ctrl-C again: stop at once)\n")

    def __enter__(self) -> RichCallback:
        if threading.current_thread() is threading.main_thread():
            for number in (signal.SIGINT, signal.SIGTERM):
                previous = signal.getsignal(number)
                if previous is not None and previous != signal.SIG_IGN and number not in self._previous_handlers:
                    self._previous_handlers[number] = signal.signal(number, self._on_ctrl_c)
        return self

    def __exit__(self, *exc: object) -> None:
        for number, handler in self._previous_handlers.items():
            signal.signal(number, handler)
        self._previous_handlers.clear()
        self.close()

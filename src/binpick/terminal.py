"""What a person sees in a terminal: Rich progress bars for any job's :class:`~binpick.runs.RunCallback`.

The one place binpick sets up progress bars. ``binpick.cli`` and the benchmark scripts use it;
library code only ever talks to a ``RunCallback``.
"""

from __future__ import annotations

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from binpick.runs import RunCallback, Task


class _RichTask(Task):
    def __init__(self, progress: Progress, task_id) -> None:
        self.progress, self.task_id = progress, task_id

    def update(self, done: int | None = None, *, advance: int = 0, total: int | None = None, status: str | None = None) -> None:
        fields = {} if status is None else {"status": status}
        if total is not None:
            fields["total"] = total
        if done is not None:
            fields["completed"] = done
        self.progress.update(self.task_id, advance=advance or None, **fields)

    def close(self) -> None:
        self.progress.stop_task(self.task_id)


class RichCallback(RunCallback):
    """Progress bars (one per task, with a status column) and messages printed above them.

    Use as a context manager: ``with RichCallback(console) as callback: job.run(callback)``."""

    def __init__(self, console: Console | None = None) -> None:
        self.console = console or Console(markup=False)
        self.progress = Progress(TextColumn("{task.description}", style="bold", markup=False), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("{task.fields[status]}", markup=False), TimeElapsedColumn(), TimeRemainingColumn(),
                                 console=self.console)

    def task(self, label: str, total: int | None = None, done: int = 0) -> Task:
        self.progress.start()
        return _RichTask(self.progress, self.progress.add_task(label, total=total, completed=done, status=""))

    def message(self, text: str) -> None:
        self.progress.console.print(text, markup=False, highlight=False)

    def close(self) -> None:
        self.progress.stop()

    def __enter__(self) -> RichCallback:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

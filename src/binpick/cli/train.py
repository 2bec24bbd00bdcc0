"""`binpick train CONFIG`: every trainable thing through one command (the config's ``task:`` picks the job)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from binpick.cli.app import ConfigSetOption, app, console, job_progress, parse_settings, start_or_resume


@app.command("train")
def train(
    config: Annotated[Path | None, typer.Argument(help="YAML config with a task: key (rl, april, detect, recurrent, "
                                                       "pickability, product_check, grasp_quality, data); see configs/ "
                                                       "and binpick train --list")] = None,
    resume: Annotated[Path | None, typer.Option(help="Run folder (or data-set folder) to continue")] = None,
    runs: Annotated[Path, typer.Option(help="Where new run folders go (a config that names an out folder goes there)")] = Path("runs"),
    settings: ConfigSetOption = None,
    list_tasks: Annotated[bool, typer.Option("--list", help="List the tasks and their config keys, then exit")] = False,
    address: Annotated[str | None, typer.Option(help="Train on a Ray cluster (detect, pickability, grasp_quality; rl "
                                                     "with a3c or sac; a data set's worlds as tasks): local (one on this "
                                                     "machine), auto, HOST:PORT or ray://HOST:PORT")] = None,
    workers: Annotated[int, typer.Option(help="With --address: Ray Train workers (data-parallel), or the "
                                                    "simulators feeding an RL sac learner; A3C's rollout workers are its a3c.workers")] = 1,
) -> None:
    """Train what CONFIG describes, or continue a run with --resume: checkpoints, TensorBoard and metrics.json
    in runs/<name>/<time>/; Ctrl-C or a crash loses at most the work since the last checkpoint."""
    from binpick.core import jobs

    if list_tasks:
        table = Table(title="binpick train: tasks")
        for column in ("task", "trains", "config keys"):
            table.add_column(column, no_wrap=column == "task")
        for task, what, keys in jobs.describe():
            table.add_row(task, what, ", ".join(keys))
        console.print(table)
        return
    job = jobs.open_job(config, resume, runs=runs, overrides=parse_settings(settings), address=address, workers=workers)
    kind = jobs.kind_of_job(job)
    if resume is not None:
        done = jobs.progress(resume)
        console.print(f"resuming {resume} ({kind.task}){'' if done is None else f' at {done} {kind.steps_key}'}")
    else:
        console.print(f"{kind.task}: {job.run_dir}")
    again = f"binpick train --resume {job.run_dir}" + (f" --address {address} --workers {workers}" if address else "")
    with job_progress(job.run_dir, again) as callback:
        metrics = jobs.run_job(job, callback, address, workers)
    done = jobs.progress(job.run_dir)
    console.print(f"done: {'' if done is None else f'{done} {kind.steps_key}; '}{summary(metrics)}; run folder {job.run_dir}")


def run_task(task: str, config: Path | None, resume: Path | None, runs: Path, settings: list[str] | None,
             before_run=None) -> tuple[object, dict]:
    """What every per-task training command does: a new run of ``task`` from ``config`` (+ ``--set``), or
    ``--resume`` of one of its runs, then the job with progress bars; returns the job and its metrics."""
    from binpick.core import jobs

    kind = jobs.KINDS[task]
    job = start_or_resume(task, config, resume, runs, parse_settings(settings),
                          where=lambda job: "" if (done := jobs.progress(resume)) is None else f" at {done} {kind.steps_key}")
    if before_run is not None:
        before_run(job)
    with job_progress(job.run_dir, f"binpick train --resume {job.run_dir}") as callback:
        return job, job.run(callback)


def summary(metrics: dict) -> str:
    """The run's headline figures, whichever job it was."""
    parts = []
    for key in ("final_success", "best_val_auc", "scenes", "images"):
        if isinstance(value := metrics.get(key), (int, float)):
            parts.append(f"{key} {value:.3f}" if isinstance(value, float) else f"{key} {value}")
    final = metrics.get("final")
    if isinstance(final, dict) and isinstance(final.get("ap50"), (int, float)):
        parts.append(f"val AP50 {final['ap50']:.3f}")
    return ", ".join(parts) or "finished"

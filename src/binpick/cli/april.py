"""APRiL: `binpick april run|eval`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from binpick.cli.app import (
    ConfigSetOption,
    ResumeOption,
    RunsOption,
    april_app,
    console,
    evaluate_with_progress,
    job_progress,
    parse_settings,
    seed_option,
    start_or_resume,
)
from binpick.core.errors import ConfigError


@april_app.command("run")
def april_run(
    config: Annotated[Path | None, typer.Argument(help="YAML config (see configs/april/april_*.yaml)")] = None,
    resume: ResumeOption = None,
    runs: RunsOption = Path("runs"),
    settings: ConfigSetOption = None,
) -> None:
    """The whole pipeline: collect -> perception -> policy -> evaluate (resumable per stage)."""
    run = start_or_resume("april", config, resume, runs, parse_settings(settings),
                          where=lambda job: f" (done: {', '.join(job.stages) or 'nothing yet'})")
    with job_progress(run.run_dir, f"binpick april run --resume {run.run_dir}") as callback:
        result = run.run(callback)
    table = Table(title=f"{run.config.name}: average actions per episode")
    for column in ("row", "avg actions ± std", "success", "simulator episodes"):
        table.add_column(column)
    for name, row in result["rows"].items():
        table.add_row(name, f"{row['avg_actions']:.2f} ± {row['std']:.2f}", f"{row['success']:.0%}", f"{row['sim_episodes']:,}")
    console.print(table)


@april_app.command("eval")
def april_eval(
    run: Annotated[Path, typer.Argument(help="APRiL run folder")],
    runtime_input: Annotated[str, typer.Option("--input", help="pixels, or state (ground truth; semantic policies)")] = "pixels",
    episodes: Annotated[int, typer.Option(help="Seeded evaluation episodes")] = 100,
    seed: Annotated[int, seed_option("Seed of the first episode")] = 30_000,
) -> None:
    """Evaluate a trained APRiL run from pixels or from the ground-truth state."""
    from binpick.april import AprilRun
    from binpick.april.evaluate import deployment_env
    from binpick.core.config import check_choice, check_range

    check_range("episodes", episodes, 1, 1_000_000, integer=True)
    check_choice("--input", runtime_input, ["pixels", "state"])
    april = AprilRun.resume(run)
    if "policy" not in april.stages:
        raise ConfigError(f"APRiL run {run} has no trained policy yet: binpick april run --resume {run}")
    if runtime_input == "state" and april.config.policy.mode != "semantic":
        raise ConfigError(f"--input state needs a policy trained on the semantic state; this run's is {april.config.policy.mode}")
    env, policy, _ = deployment_env(april, runtime_input)
    evaluate_with_progress(env, policy, f"{april.config.name} from {runtime_input}", episodes, seed)

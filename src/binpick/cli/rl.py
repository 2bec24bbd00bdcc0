"""Reinforcement learning: `binpick rl train|distributed|eval`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from binpick.cli.app import (
    ConfigSetOption,
    ResumeOption,
    RunsOption,
    console,
    evaluate_with_progress,
    job_progress,
    parse_settings,
    progress,
    rl_app,
    seed_option,
    start_or_resume,
    warn,
)
from binpick.core.files import ensure_dir


@rl_app.command("train")
def rl_train(
    config: Annotated[Path | None, typer.Argument(help="YAML config (see configs/rl/rl_*.yaml)")] = None,
    resume: ResumeOption = None,
    runs: RunsOption = Path("runs"),
    steps: Annotated[int | None, typer.Option(help="Same as --set total_timesteps=N (simulator steps)")] = None,
    seed: Annotated[int | None, seed_option("Same as --set seed=N")] = None,
    init_from: Annotated[Path | None, typer.Option(help="A3C: start from this run's latest checkpoint (--set init_from=RUN)")] = None,
    settings: ConfigSetOption = None,
) -> None:
    """Train a run: checkpoints, TensorBoard, metrics.json and curves.png in runs/<name>/<time>/."""
    from binpick.rl.config import never_learns

    flags = {"total_timesteps": steps, "seed": seed, "init_from": None if init_from is None else str(init_from)}
    overrides = parse_settings(settings) | {k: v for k, v in flags.items() if v is not None}
    trainer = start_or_resume("rl", config, resume, runs, overrides, where=lambda job: f" at {job.steps_done} simulator steps")
    warn(never_learns(trainer.config))
    with job_progress(trainer.run_dir, f"binpick rl train --resume {trainer.run_dir}") as callback:
        metrics = trainer.run(callback)
    summary = (f"final success {metrics['final_success']:.0%}, average actions {metrics['final_avg_actions']:.2f} "
               f"± {metrics['final_std_actions']:.2f}")
    if metrics.get("sim_steps_to_threshold", "absent") != "absent":
        summary += f"; simulator steps to {metrics['success_threshold']:.0%}: {metrics['sim_steps_to_threshold']}"
    console.print(f"{summary}; wrote {trainer.run_dir / 'metrics.json'}")


@rl_app.command("distributed")
def rl_distributed(
    algorithm: Annotated[str, typer.Option(help="sac (GP + HER learner here, fed by simulator actors) or a3c (actors send gradients)")] = "sac",
    env_id: Annotated[str | None, typer.Option("--env", help="Env (default: FetchReach for sac, Arm2D for a3c)")] = None,
    workers: Annotated[int, typer.Option(help="Simulators, one Ray actor (process) each")] = 2,
    steps: Annotated[int, typer.Option(help="Simulator steps of the run")] = 5000,
    address: Annotated[str | None, typer.Option(help="Ray cluster to join (HOST:6379, from `ray start --head`); default: a local one")] = None,
    out: Annotated[Path, typer.Option(help="Folder the run folder is made in")] = Path("runs/distributed"),
    seed: Annotated[int, seed_option("Seed")] = 0,
) -> None:
    """A small RL run with its simulators on Ray (thesis §6.1); a simulator that dies is restarted and the run
    goes on. A whole RL YAML runs the same way: binpick train CONFIG --address ... [--workers N]."""
    from binpick.core.cluster import check_ray_address, probe_ray_address
    from binpick.core.config import check_choice, check_range, from_dict
    from binpick.core.jobs import open_job, run_job
    from binpick.envs import resolve_env_id
    from binpick.rl.config import RLConfig, never_learns

    check_choice("algorithm", algorithm, ("sac", "a3c"))
    check_range("workers", workers, 1, 4096, integer=True)
    if address not in (None, "local"):
        probe_ray_address(check_ray_address(address))  # before a run folder is made
    if algorithm == "sac":
        settings = {"name": "sac_distributed", "env": resolve_env_id(env_id or "FetchReach"), "algorithm": "sac",
                    "total_timesteps": steps, "seed": seed, "gp": {"enabled": True},
                    "eval": {"every": max(steps, 1), "episodes": 20}}  # one evaluation: the final policy
    else:
        settings = {"name": "a3c_distributed", "env": resolve_env_id(env_id or "Arm2D"), "algorithm": "a3c",
                    "total_timesteps": steps, "seed": seed, "a3c": {"workers": workers}}
    config = from_dict(RLConfig, settings, where="rl distributed")
    warn(never_learns(config))
    simulators = workers if algorithm == "sac" else 1  # A3C's rollout workers are its a3c.workers
    trainer = open_job(settings=config, task="rl", runs=ensure_dir(out, "--out"), address=address or "local", workers=simulators)
    with progress() as callback:  # as `binpick train CONFIG --address ... --workers N`
        metrics = run_job(trainer, callback, address or "local", simulators)
    restarts = metrics.get("worker_restarts", 0)
    console.print(f"{metrics['sim_steps']} simulator steps in {metrics['wall_seconds']} s ({restarts} simulator restart(s)); "
                  f"final success {metrics['final_success']:.0%}, {metrics['final_avg_actions']:.1f} actions; wrote {trainer.run_dir}")


@rl_app.command("eval")
def rl_eval(
    run: Annotated[Path, typer.Argument(help="Run folder (runs/<name>/<time>)")],
    episodes: Annotated[int, typer.Option(help="Seeded evaluation episodes")] = 100,
    seed: Annotated[int, seed_option("Seed of the first episode")] = 10_000,
    env_id: Annotated[str | None, typer.Option("--env", help="Must match the env the run was trained on")] = None,
) -> None:
    """Evaluate a run's latest checkpoint: average actions ± std and success rate."""
    from binpick.core.config import check_range
    from binpick.rl.policy import load_policy
    from binpick.rl.envs import make_env

    check_range("episodes", episodes, 1, 1_000_000, integer=True)
    model, config = load_policy(run, env_id)
    evaluate_with_progress(make_env(config), model, f"{config.name} · {config.env}", episodes, seed)

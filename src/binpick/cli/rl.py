"""Reinforcement learning: `binpick rl train|distributed|eval`."""

from __future__ import annotations

import time
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
    from binpick.rl.config import load_rl_config, never_learns
    from binpick.rl.train import RLRun

    flags = {"total_timesteps": steps, "seed": seed, "init_from": None if init_from is None else str(init_from)}
    overrides = parse_settings(settings) | {k: v for k, v in flags.items() if v is not None}
    trainer = start_or_resume(RLRun, config, resume, runs, load_rl_config, overrides,
                              where=lambda job: f" at {job.steps_done} simulator steps")
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
    algorithm: Annotated[str, typer.Option(help="sac (SAC + HER learner fed whole episodes) or a3c (workers send gradients)")] = "sac",
    env_id: Annotated[str | None, typer.Option("--env", help="Env (default: FetchReach for sac, Arm2D for a3c)")] = None,
    workers: Annotated[int, typer.Option(help="Simulators, one Ray actor (process) each")] = 2,
    steps: Annotated[int, typer.Option(help="Env steps the workers play")] = 5000,
    address: Annotated[str | None, typer.Option(help="Ray cluster to join (HOST:6379, from `ray start --head`); default: a local one")] = None,
    out: Annotated[Path, typer.Option(help="Folder for the model and metrics.json")] = Path("runs/distributed"),
    seed: Annotated[int, seed_option("Seed")] = 0,
) -> None:
    """Learning from Ray simulator workers (thesis §6.1); a worker that dies is restarted and the run goes on."""
    from binpick.cluster import check_ray_address
    from binpick.core.config import check_choice
    from binpick.envs import resolve_env_id

    check_choice("algorithm", algorithm, ("sac", "a3c"))
    if algorithm == "sac":
        from binpick.integrations.ray.learner import (
            DistributedConfig,
            train_distributed,
        )

        config = DistributedConfig(env=resolve_env_id(env_id or "FetchReach"), workers=workers, total_timesteps=steps,
                                   address=address, seed=seed)
    else:  # A3C: a run folder like any RL run's (binpick train CONFIG --address ... takes a whole RL YAML)
        from binpick.core.config import from_dict
        from binpick.integrations.ray.a3c import learn_on_ray
        from binpick.rl.a3c_train import A3CTrainer
        from binpick.rl.config import RLConfig

        config = from_dict(RLConfig, {"name": "a3c_distributed", "env": resolve_env_id(env_id or "Arm2D"), "algorithm": "a3c",
                                      "total_timesteps": steps, "seed": seed, "a3c": {"workers": workers}}, where="rl distributed")
        check_ray_address(None if address == "local" else address)
        trainer = A3CTrainer.new(config, ensure_dir(out, "--out"))
        with progress() as callback:
            metrics = trainer.run(callback, learn=learn_on_ray(address))
        console.print(f"{metrics['sim_steps']} env steps in {metrics['wall_seconds']} s "
                      f"({metrics.get('worker_restarts', 0)} worker restart(s)); final success {metrics['final_success']:.0%}, "
                      f"{metrics['final_avg_actions']:.1f} actions; wrote {trainer.run_dir}")
        return
    if steps <= config.learning_starts:
        warn(f"--steps {steps} ends before the learner's first update (after {config.learning_starts} steps): "
             "the policy will not learn")
    run_dir = ensure_dir(out, "--out") / time.strftime("%Y%m%d-%H%M%S")  # written when the run ends
    with progress() as callback, callback.task(f"{algorithm}, {workers} workers", steps) as task:
        metrics = train_distributed(config, run_dir, on_episode=lambda _e, _r, model: task.update(model.num_timesteps))
    console.print(f"{metrics['env_steps']} env steps in {metrics['wall_s']} s ({metrics['lost_episodes']} lost to dead workers); "
                  f"final success {metrics['final_success']:.0%}, {metrics['final_avg_actions']:.1f} actions; wrote {run_dir}")


@rl_app.command("eval")
def rl_eval(
    run: Annotated[Path, typer.Argument(help="Run folder (runs/<name>/<time>)")],
    episodes: Annotated[int, typer.Option(help="Seeded evaluation episodes")] = 100,
    seed: Annotated[int, seed_option("Seed of the first episode")] = 10_000,
    env_id: Annotated[str | None, typer.Option("--env", help="Must match the env the run was trained on")] = None,
) -> None:
    """Evaluate a run's latest checkpoint: average actions ± std and success rate."""
    from binpick.core.config import check_range
    from binpick.rl.train import load_policy, make_env

    check_range("episodes", episodes, 1, 1_000_000, integer=True)
    model, config = load_policy(run, env_id)
    evaluate_with_progress(make_env(config), model, f"{config.name} · {config.env}", episodes, seed)

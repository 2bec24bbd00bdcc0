"""The ``binpick`` command: one sub-command group per job (``binpick envs list``, ...).

User mistakes end in one line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Annotated

import typer
import yaml
from rich.console import Console
from rich.table import Table
from rich.text import Text

from binpick.errors import BinpickError, ConfigError
from binpick.files import atomic_write, atomic_write_json, check_output_file, ensure_dir, parse_yaml
from binpick.terminal import RichCallback

app = typer.Typer(help="Learned bin picking: simulated worlds, RL, APRiL and repeated object detection.",
                  no_args_is_help=True, pretty_exceptions_enable=False, add_completion=False)
envs_app = typer.Typer(help="The simulated worlds of the thesis (Gymnasium ids binpick/...).", no_args_is_help=True)
app.add_typer(envs_app, name="envs")
rl_app = typer.Typer(help="Reinforcement learning (thesis ch. 3): train and evaluate runs.", no_args_is_help=True)
app.add_typer(rl_app, name="rl")
april_app = typer.Typer(help="APRiL (thesis ch. 4): train the policy on state, deploy it on pixels.", no_args_is_help=True)
app.add_typer(april_app, name="april")
data_app = typer.Typer(help="Warehouse bin data sets with pickability from trial grasps (thesis §5.4.4, §6.3).",
                       no_args_is_help=True)
app.add_typer(data_app, name="data")
detect_app = typer.Typer(help="Repeated object detection (thesis ch. 5, §6.3): ROD and TDID.", no_args_is_help=True)
app.add_typer(detect_app, name="detect")
grasp_app = typer.Typer(help="Grasps from depth: train the grasp-quality model on simulated trials.",
                        no_args_is_help=True)
app.add_typer(grasp_app, name="grasp")
products_app = typer.Typer(help="The products binpick can generate bins of and pick: built in, or your own (--products YAML).",
                           no_args_is_help=True)
app.add_typer(products_app, name="products")
ros_app = typer.Typer(help="ROS 1 bridge (thesis §6.1.1): serve a binpick env as an action server, drive it over ROS.",
                      no_args_is_help=True)
app.add_typer(ros_app, name="ros")
ros2_app = typer.Typer(help="ROS 2 (PyPI's ros-rclpy wheels, in .venv-ros2): pick planning for a robot's camera.", no_args_is_help=True)
app.add_typer(ros2_app, name="ros2")

console = Console(markup=False)  # paths and names are printed as they are, never read as Rich markup
MAX_SEED = 2**32 - 1  # NumPy's legacy seeding (SB3, Gymnasium) takes 32-bit seeds


def seed_option(text: str):
    """A ``--seed`` option that takes only what every seeded library accepts: 0 .. 2^32 - 1."""
    return typer.Option("--seed", min=0, max=MAX_SEED, help=text)


SetOption = Annotated[list[str] | None, typer.Option("--set", help="Env parameter KEY=VALUE (repeatable), e.g. --set goal_area=0.5")]
POLICIES = ("random",)
DEFAULT_POLICY = "learnt"  # the grasp policy of pick and demo: the best in results/grasp.json and results/pick.json


def _print_version(value: bool) -> None:
    if value:
        from binpick import __version__

        console.print(f"binpick {__version__}")
        raise typer.Exit()


@app.callback()
def _root(version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                                help="Print binpick's version and exit")] = False) -> None:
    pass


def parse_settings(pairs: list[str] | None) -> dict:
    """``["goal_area=0.5", "image=grey"]`` -> ``{"goal_area": 0.5, "image": "grey"}`` (YAML scalars)."""
    settings = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set expects KEY=VALUE, got {pair!r}")
        settings[key.strip()] = parse_yaml(value, f"--set {key.strip()}") if value.strip() else None
    return settings


def progress() -> RichCallback:
    """Progress bars on this command's console (``with progress() as callback: job.run(callback)``)."""
    return RichCallback(console)


ConfigSetOption = Annotated[list[str] | None, typer.Option("--set", help="Config override KEY=VALUE or SECTION.KEY=VALUE, applied "
                                                                        "before validation (repeatable), e.g. --set train.epochs=2")]


def start_or_resume(job_class, config: Path | None, resume: Path | None, runs: Path, load, overrides: dict,
                    where=lambda job: ""):
    """The one way every training command starts: a new run from ``config`` (YAML + ``--set``
    overrides, validated once by ``load``) or ``--resume`` of a run folder (its own saved config);
    ``where(job)`` says how far a resumed run had come."""
    if (config is None) == (resume is None):
        raise ConfigError("give either a CONFIG file to start a run or --resume RUN_DIR to continue one")
    if resume is not None:
        if not (resume / "config.yaml").is_file():
            raise ConfigError(f"{str(resume)!r} is not a run folder (no config.yaml)")
        if overrides:
            raise ConfigError("--set and other overrides apply to new runs; a resumed run keeps its config.yaml")
        job = job_class.resume(resume)
        console.print(f"resuming {resume}{where(job)}")
        return job
    job = job_class.new(load(config, overrides), runs)
    console.print(f"run folder: {job.run_dir}")
    return job


@envs_app.command("list")
def envs_list() -> None:
    """List the registered envs with their episode limit T and thesis section."""
    from binpick.envs import ENVS

    table = Table(title="binpick environments")
    for column in ("id", "T", "thesis", "what it is"):  # ids are what people copy: never cut; the summary wraps
        table.add_column(column, no_wrap=column != "what it is")
    for spec in ENVS.values():
        table.add_row(spec.env_id, str(spec.max_episode_steps), spec.thesis, spec.summary)
    console.print(table)


@envs_app.command("show")
def envs_show(
    env_id: Annotated[str, typer.Argument(help="Env id, e.g. binpick/FetchReach-v0 or FetchReach")],
    out: Annotated[Path, typer.Option("--out", "-o", help="PNG file to write")] = Path("frame.png"),
    seed: Annotated[int, seed_option("Reset seed")] = 0,
    size: Annotated[int, typer.Option(help="Frame side in pixels")] = 480,
    settings: SetOption = None,
) -> None:
    """Reset an env and save what a person sees (and the policy's image observation, if any)."""

    from binpick.envs import env_spec, make, resolve_env_id

    env_id = resolve_env_id(env_id)
    _check_png_path(out)
    kwargs = parse_settings(settings)
    own = sorted(set(kwargs) & {"render_mode", "render_size", "width", "height"})
    if own:
        raise ConfigError(f"--set {own[0]}: `envs show` sets the frame itself; give --size instead")
    kwargs.update(dict.fromkeys(env_spec(env_id).frame_size, size))
    env = make(env_id, render_mode="rgb_array", **kwargs)
    try:
        observation, _ = env.reset(seed=seed)
        frame = env.render()
    finally:
        env.close()
    _save_png(frame, out)
    console.print(f"wrote {out} ({frame.shape[1]}x{frame.shape[0]})")
    image = observation.get("image") if isinstance(observation, dict) else observation
    if image is not None:
        obs_path = out.with_name(out.stem + "_obs" + out.suffix)
        _save_png(image[..., 0] if image.shape[-1] == 1 else image, obs_path)
        console.print(f"wrote {obs_path} (image observation {image.shape[1]}x{image.shape[0]}x{image.shape[2]})")


@envs_app.command("rollout")
def envs_rollout(
    env_id: Annotated[str, typer.Argument(help="Env id, e.g. binpick/Arm2D-v0 or Arm2D")],
    policy: Annotated[str, typer.Option(help=f"Policy to run: {', '.join(POLICIES)}")] = "random",
    episodes: Annotated[int, typer.Option(help="Number of seeded episodes")] = 20,
    seed: Annotated[int, seed_option("Seed of the first episode (episode i uses seed+i)")] = 0,
    json_out: Annotated[Path | None, typer.Option("--json", help="Also write the result as JSON here")] = None,
    settings: SetOption = None,
) -> None:
    """Run a policy and print the thesis's metric: average episode length ± std and success rate."""
    from binpick.config import check_choice, check_range
    from binpick.envs import make
    from binpick.rl.evaluate import evaluate_policy, random_policy

    check_choice("policy", policy, POLICIES)
    check_range("episodes", episodes, 1, None, integer=True)
    if json_out is not None:
        check_output_file(json_out, "--json")
    env = make(env_id, **parse_settings(settings))
    try:
        with progress() as callback, callback.task(f"{env.spec.id} · {policy}", episodes) as task:
            result = evaluate_policy(random_policy(env, seed), env, episodes=episodes, seed=seed,
                                     on_episode=lambda *_: task.update(advance=1))
    finally:
        env.close()
    console.print(result.summary())
    if json_out is not None:
        atomic_write_json(json_out, {**result.to_dict(), "policy": policy, "seed": seed})
        console.print(f"wrote {json_out}")


@envs_app.command("tour")
def tour(
    out: Annotated[Path, typer.Option(help="Folder for the frames and summary")] = Path("runs/tour"),
    episodes: Annotated[int, typer.Option(help="Random-policy episodes per env")] = 10,
) -> None:
    """Render every env and roll a random policy in each: a quick check that simulation and rendering work."""
    from binpick.config import check_range
    from binpick.envs import ENV_IDS, make
    from binpick.rl.evaluate import evaluate_policy, random_policy

    check_range("episodes", episodes, 1, 10_000, integer=True)
    run_dir = ensure_dir(out / time.strftime("%Y%m%d-%H%M%S"), "--out")
    table = Table(title=f"random policy, {episodes} seeded episodes per env")
    for column in ("env", "T", "avg actions ± std", "success"):
        table.add_column(column)
    summary = []
    started = time.perf_counter()
    with progress() as callback, callback.task("all envs", len(ENV_IDS) * episodes) as overall:
        for env_id in ENV_IDS:
            name = env_id.split("/")[1]
            env = make(env_id, render_mode="rgb_array")
            try:
                env.reset(seed=0)
                frame_path = run_dir / f"{name}.png"
                _save_png(env.render(), frame_path)
                with callback.task(name, episodes) as task:
                    def advance(*_: object) -> None:
                        task.update(advance=1)
                        overall.update(advance=1)

                    result = evaluate_policy(random_policy(env, 0), env, episodes=episodes, seed=0, on_episode=advance)
            finally:
                env.close()
            summary.append(result.to_dict())
            table.add_row(name, str(result.max_episode_steps), f"{result.mean_length:.1f} ± {result.std_length:.1f}",
                          f"{100 * result.success_rate:.0f}%")
    console.print(table)
    atomic_write_json(run_dir / "summary.json", summary)
    console.print(f"frames and summary.json in {run_dir} ({time.perf_counter() - started:.1f} s)")


def product_library(products_file: Path | None):
    """The built-in products, plus a user's YAML of their own when given (checked as data generate checks it)."""
    from binpick.sim import default_library, load_products

    library = default_library()
    return load_products(products_file, library) if products_file is not None else library


@products_app.command("list")
def products_list(
    products_file: Annotated[Path | None, typer.Option("--products", help="Also your own products from this YAML")] = None,
) -> None:
    """Every product: the id to order it by (a unique short name works too), its category and source."""
    library = product_library(products_file)
    shorts = [pid.split("/")[-1] for pid in library.products]
    table = Table(title=f"{len(library)} products in {len(library.categories)} categories")
    for column in ("id", "short name", "category", "mesh"):
        table.add_column(column, no_wrap=column != "mesh", overflow="fold")
    for product in sorted(library, key=lambda p: p.id):
        short = product.id.split("/")[-1]
        table.add_row(product.id, short if shorts.count(short) == 1 else "(not unique)", product.category,
                      product.mesh.name if product.mesh else "procedural")
    console.print(table)


@rl_app.command("train")
def rl_train(
    config: Annotated[Path | None, typer.Argument(help="YAML config (see configs/rl_*.yaml)")] = None,
    resume: Annotated[Path | None, typer.Option(help="Run folder to continue from its latest checkpoint")] = None,
    runs: Annotated[Path, typer.Option(help="Where new run folders go")] = Path("runs"),
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
    with progress() as callback:
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
    from binpick.config import check_choice
    from binpick.envs import resolve_env_id

    check_choice("algorithm", algorithm, ("sac", "a3c"))
    if algorithm == "sac":
        from binpick.distributed.learner import DistributedConfig, train_distributed

        config = DistributedConfig(env=resolve_env_id(env_id or "FetchReach"), workers=workers, total_timesteps=steps,
                                   address=address, seed=seed)
    else:
        from binpick.distributed.a3c import DistributedA3CConfig, train_a3c_distributed

        config = DistributedA3CConfig(env=resolve_env_id(env_id or "Arm2D"), workers=workers, total_timesteps=steps,
                                      address=address, seed=seed)
    if algorithm == "sac" and steps <= config.learning_starts:
        warn(f"--steps {steps} ends before the learner's first update (after {config.learning_starts} steps): "
             "the policy will not learn")
    run_dir = ensure_dir(out, "--out") / time.strftime("%Y%m%d-%H%M%S")  # written when the run ends
    with progress() as callback, callback.task(f"{algorithm}, {workers} workers", steps) as task:
        if algorithm == "sac":
            metrics = train_distributed(config, run_dir, on_episode=lambda _e, _r, model: task.update(model.num_timesteps))
        else:
            metrics = train_a3c_distributed(config, run_dir, on_update=lambda done, _pool: task.update(done))
    lost = metrics.get("lost_episodes", metrics.get("lost_rollouts"))
    console.print(f"{metrics['env_steps']} env steps in {metrics['wall_s']} s ({lost} lost to dead workers); "
                  f"final success {metrics['final_success']:.0%}, {metrics['final_avg_actions']:.1f} actions; wrote {run_dir}")


@rl_app.command("eval")
def rl_eval(
    run: Annotated[Path, typer.Argument(help="Run folder (runs/<name>/<time>)")],
    episodes: Annotated[int, typer.Option(help="Seeded evaluation episodes")] = 100,
    seed: Annotated[int, seed_option("Seed of the first episode")] = 10_000,
    env_id: Annotated[str | None, typer.Option("--env", help="Must match the env the run was trained on")] = None,
) -> None:
    """Evaluate a run's latest checkpoint: average actions ± std and success rate."""
    from binpick.config import check_range
    from binpick.rl.train import load_policy, make_env

    check_range("episodes", episodes, 1, 1_000_000, integer=True)
    model, config = load_policy(run, env_id)
    _evaluate_with_progress(make_env(config), model, f"{config.name} · {config.env}", episodes, seed)


def _evaluate_with_progress(env, policy, label: str, episodes: int, seed: int) -> None:
    """Seeded evaluation episodes with a progress bar; prints the summary and closes the env."""
    from binpick.rl.evaluate import evaluate_policy

    try:
        with progress() as callback, callback.task(label, episodes) as task:
            result = evaluate_policy(policy, env, episodes=episodes, seed=seed, on_episode=lambda *_: task.update(advance=1))
    finally:
        env.close()
    console.print(result.summary())


@april_app.command("run")
def april_run(
    config: Annotated[Path | None, typer.Argument(help="YAML config (see configs/april_*.yaml)")] = None,
    resume: Annotated[Path | None, typer.Option(help="APRiL run folder to continue after a crash")] = None,
    runs: Annotated[Path, typer.Option(help="Where new run folders go")] = Path("runs"),
    settings: ConfigSetOption = None,
) -> None:
    """The whole pipeline: collect -> perception -> policy -> evaluate (resumable per stage)."""
    from binpick.april import AprilRun, load_april_config

    run = start_or_resume(AprilRun, config, resume, runs, load_april_config, parse_settings(settings),
                          where=lambda job: f" (done: {', '.join(job.stages) or 'nothing yet'})")
    with progress() as callback:
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
    from binpick.config import check_choice, check_range

    check_range("episodes", episodes, 1, 1_000_000, integer=True)
    check_choice("--input", runtime_input, ["pixels", "state"])
    april = AprilRun.resume(run)
    if "policy" not in april.stages:
        raise ConfigError(f"APRiL run {run} has no trained policy yet: binpick april run --resume {run}")
    if runtime_input == "state" and april.config.policy.mode != "semantic":
        raise ConfigError(f"--input state needs a policy trained on the semantic state; this run's is {april.config.policy.mode}")
    env, policy, _ = deployment_env(april, runtime_input)
    _evaluate_with_progress(env, policy, f"{april.config.name} from {runtime_input}", episodes, seed)


def _pair(text: str, name: str) -> tuple[int, int]:
    try:
        low, high = (int(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--{name} must be LOW,HIGH (two integers), got {text!r}") from None
    return low, high


@data_app.command("generate")
def data_generate(
    out: Annotated[Path, typer.Option(help="Data-set folder (new, or one to resume)")],
    scenes: Annotated[int, typer.Option(help="Number of bin scenes")] = 100,
    policies: Annotated[str, typer.Option(help="Grasp policies that label pickability, comma-separated: x, y (scripted, jaws along an axis), analytic, learnt (the grasp planner); '' for none")] = "x,y",
    workers: Annotated[int, typer.Option(help="Parallel processes")] = 2,
    grasp_trials: Annotated[int, typer.Option(help="Random grasp candidates from depth to execute per visible instance "
                                                   "(grasp-quality training data); 0 for none")] = 0,
    products: Annotated[Path | None, typer.Option(help="YAML of your own products (meshes, textures)")] = None,
    only_products: Annotated[bool, typer.Option(help="Use only the products in --products")] = False,
    size: Annotated[int, typer.Option(help="Image size in pixels")] = 416,
    copies: Annotated[str, typer.Option(help="Instances of the target product per bin, LOW,HIGH")] = "2,8",
    distractors: Annotated[str, typer.Option(help="Other products per bin, LOW,HIGH")] = "0,3",
    held_out: Annotated[str, typer.Option(help="Product categories for the zero-shot test split, comma-separated")] = "",
    targets: Annotated[str, typer.Option(help="Products or categories to fill bins with, comma-separated (default: all)")] = "",
    randomise: Annotated[bool, typer.Option(help="Randomise lighting and colours per world (older; see --domain)")] = False,
    domain: Annotated[str, typer.Option(help="Scene look: default, random (domain randomisation), shifted, or a domain YAML file")] = "default",
    sensor: Annotated[str, typer.Option(help="Depth camera: perfect (the renderer's depth), realistic (holes, noise, tilted "
                                             "camera and tote, as a structured-light sensor gives it) or a sensor YAML file")] = "perfect",
    address: Annotated[str | None, typer.Option(help="Run scene workers as Ray tasks: HOST:PORT of a Ray cluster, or local")] = None,
    val_fraction: Annotated[float, typer.Option(help="Share of worlds (groups of --scenes-per-world scenes) in the val split")] = 0.1,
    scenes_per_world: Annotated[int, typer.Option(help="Scenes made from one compiled world (one product); small sets: 1")] = 8,
    photo_views: Annotated[int, typer.Option(help="Shop photos per product taken in randomised studios (light, background, "
                                                  "viewpoint, framing, cut-out), besides the canonical one")] = 0,
    seed: Annotated[int, seed_option("Seed")] = 0,
    settings: Annotated[list[str] | None, typer.Option("--set", help="Any other generator setting KEY=VALUE, e.g. "
                                                                     "--set val_fraction=0.25 (see GenerateConfig)")] = None,
) -> None:
    """Generate bin scenes (resumes after a kill), shop photos, COCO files and a data-set card."""
    from binpick.config import from_dict
    from binpick.warehouse.dataset import DataGeneration, GenerateConfig

    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {str(out)!r} is a file, not a data-set folder")
    flags = {"out": str(out), "scenes": scenes, "policies": [p for p in policies.split(",") if p], "workers": workers,
             "grasp_trials": grasp_trials,
             "image_size": size, "copies": list(_pair(copies, "copies")), "distractors": list(_pair(distractors, "distractors")),
             "held_out_categories": [c for c in held_out.split(",") if c], "randomise": randomise, "domain": domain, "sensor": sensor,
             "address": address,
             "targets": [t for t in targets.split(",") if t], "products": str(products) if products else None,
             "only_products": only_products, "val_fraction": val_fraction, "scenes_per_world": scenes_per_world, "photo_views": photo_views,
             "seed": seed}
    config = from_dict(GenerateConfig, flags | parse_settings(settings), where="data generate")  # validated once
    with progress() as callback:
        stats = DataGeneration.new(config).run(callback)
    _print_stats(stats, out)
    empty = [split for split in ("train", "val") if not stats["splits"].get(split)]
    if empty:
        warn(f"no {' and no '.join(empty)} scenes: a detector needs both; give --scenes-per-world 1 and a "
             "--val-fraction that leaves each some scenes")


@data_app.command("show")
def data_show(
    data: Annotated[Path, typer.Argument(help="Data-set folder")],
    index: Annotated[int, typer.Option(help="Scene index")] = 0,
    out: Annotated[Path, typer.Option(help="PNG to write")] = Path("scene.png"),
    policy: Annotated[str | None, typer.Option(help="Colour pickability by this policy (default: the first)")] = None,
) -> None:
    """Draw a scene's boxes: green pickable, red unpickable, blue the query, grey other products."""
    from binpick.viz.bins import labelled_scene
    from binpick.warehouse.dataset import read_scene

    _check_png_path(out)
    record, policies = read_scene(data, index)
    if policy is not None and policy not in policies:
        raise ConfigError(f"--policy {policy!r}: this data set was labelled by {', '.join(policies) or 'no policy'}")
    _save_png(labelled_scene(data, record, policy or (policies[0] if policies else None)), out)
    console.print(f"scene {index} ({record['target']}, {len(record['annotations'])} instances) -> {out}")


@data_app.command("export")
def data_export(
    data: Annotated[Path, typer.Argument(help="Data-set folder")],
    out: Annotated[Path, typer.Option(help="Folder for the files (one sub-folder per scene when several)")],
    scene: Annotated[list[int] | None, typer.Option(help="Scene index (repeat for several; default: 0)")] = None,
) -> None:
    """Write scenes as a real RGB-D camera gives them: rgb.png, depth.png (16-bit mm), camera.yaml
    (ROS camera_info + camera_to_base), photo.png (the ordered product) and truth.json; try
    `binpick plan` on them."""
    from binpick.warehouse.export import export_dataset_scene

    scenes = scene or [0]
    for index in scenes:
        if index < 0:
            raise ConfigError(f"--scene must be 0 or more, got {index}")
    for index in scenes:
        folder = export_dataset_scene(data, index, out if len(scenes) == 1 else out / f"{index:06d}")
        console.print(f"scene {index} -> {folder}: rgb.png depth.png camera.yaml photo.png truth.json")


@data_app.command("stats")
def data_stats(data: Annotated[Path, typer.Argument(help="Data-set folder")]) -> None:
    """Counts: instances per image, pickable fraction per policy and category, policy disagreement.
    Reads the scene files only: nothing in the data set is written."""
    from binpick.warehouse.dataset import dataset_stats, load_records, open_dataset

    manifest = open_dataset(data)
    _print_stats(dataset_stats(load_records(data), manifest["config"]["policies"]), data)


def _print_stats(stats: dict, where: Path) -> None:
    table = Table(title=f"{where}: {stats['scenes']} scenes")
    table.add_column("")
    table.add_column("value")
    table.add_row("instances per image", f"{stats['instances_per_image']:.2f} ({stats['target_instances_per_image']:.2f} of the target)")
    for policy, fraction in stats["pickable_fraction"].items():
        table.add_row(f"pickable by policy {policy}", f"{fraction:.1%}")
    if stats["pickability_differs_fraction"] is not None:
        table.add_row("pickability differs between policies", f"{stats['pickability_differs_fraction']:.1%}")
    table.add_row("splits", ", ".join(f"{k} {v}" for k, v in sorted(stats["splits"].items())))
    console.print(table)


@detect_app.command("train")
def detect_train(
    config: Annotated[Path | None, typer.Argument(help="YAML config (see configs/rod_*.yaml)")] = None,
    resume: Annotated[Path | None, typer.Option(help="Run folder to continue from its latest checkpoint")] = None,
    runs: Annotated[Path, typer.Option(help="Where new run folders go")] = Path("runs"),
    settings: ConfigSetOption = None,
) -> None:
    """Train a detector: checkpoints each epoch, TensorBoard, metrics.json and model.safetensors in runs/<name>/<time>/."""
    from binpick.detection.config import load_detect_config
    from binpick.detection.train import DetectorTrainer

    trainer = start_or_resume(DetectorTrainer, config, resume, runs, load_detect_config, parse_settings(settings),
                              where=lambda job: f" at epoch {job.epoch}")
    console.print(f"{len(trainer.train_set)} training tasks")
    with progress() as callback:
        metrics = trainer.run(callback)
    final = metrics["final"]
    console.print(f"val AP50 {_fmt(final.get('ap50'))}, mAP {_fmt(final.get('map'))}; wrote {trainer.run_dir / 'model.safetensors'}")


@detect_app.command("pickability")
def detect_pickability(
    config: Annotated[Path | None, typer.Argument(help="YAML config (see configs/pickability_crop.yaml)")] = None,
    resume: Annotated[Path | None, typer.Option(help="Run folder to continue from its latest checkpoint")] = None,
    runs: Annotated[Path, typer.Option(help="Where new run folders go")] = Path("runs"),
    settings: ConfigSetOption = None,
) -> None:
    """Teach a detector a second look at each detection (will the policy pick this copy?): windows cut
    once, a checkpoint each epoch, TensorBoard, the best val ROC AUC kept; model.safetensors in
    runs/<name>/<time>/ is the detector with its pickability head."""
    from binpick.config import load_config
    from binpick.detection.pickability_training import PickabilityConfig, PickabilityTrainer

    trainer = start_or_resume(PickabilityTrainer, config, resume, runs,
                              lambda path, overrides: load_config(PickabilityConfig, path, overrides),
                              parse_settings(settings), where=lambda job: f" at epoch {job.epoch}")
    with progress() as callback:
        metrics = trainer.run(callback)
    console.print(f"best val ROC AUC {_fmt(metrics['best_val_auc'])}; wrote {trainer.run_dir / 'model.safetensors'} "
                  f"(binpick detect eval {trainer.run_dir} --data ...)")


@grasp_app.command("train")
def grasp_train(
    config: Annotated[Path | None, typer.Argument(help="YAML config (see configs/grasp_quality.yaml)")] = None,
    resume: Annotated[Path | None, typer.Option(help="Run folder to continue from its latest checkpoint")] = None,
    runs: Annotated[Path, typer.Option(help="Where new run folders go")] = Path("runs"),
    settings: ConfigSetOption = None,
) -> None:
    """Train the grasp-quality network on a data set with --grasp-trials: a checkpoint each epoch,
    TensorBoard, the best val ROC AUC kept, model.safetensors in runs/<name>/<time>/."""
    from binpick.config import load_config
    from binpick.grasping.training import QualityTrainConfig, QualityTrainer

    trainer = start_or_resume(QualityTrainer, config, resume, runs, lambda path, overrides: load_config(QualityTrainConfig, path, overrides),
                              parse_settings(settings), where=lambda job: f" at epoch {job.epoch}")
    with progress() as callback:
        metrics = trainer.run(callback)
    console.print(f"best val ROC AUC {_fmt(metrics['best_val_auc'])}; wrote {trainer.run_dir / 'model.safetensors'} "
                  f"(use it with binpick pick --grasp learnt --grasp-weights)")


def _fmt(value) -> str:
    return "n/a" if value is None else f"{value:.3f}"


@detect_app.command("eval")
def detect_eval(
    run: Annotated[Path, typer.Argument(help="Run folder, model.safetensors or a shipped name (rod_tiny_320)")],
    data: Annotated[Path, typer.Option(help="COCO annotations file (e.g. runs/data/bins_2000/annotations_test.json)")],
    targets: Annotated[str | None, typer.Option(help="all | pickable:<policy> (default: as trained)")] = None,
    out: Annotated[Path | None, typer.Option(help="Write the metrics JSON and a PR-curve PNG here (a folder)")] = None,
    pickability: Annotated[bool, typer.Option(help="Re-score with the weights' pickability head, if they hold one")] = True,
) -> None:
    """AP50 and mAP@[.5:.95] (pycocotools) against the targets, all instances and unpickable ones."""
    from binpick.detection import Detector

    if out is not None:
        ensure_dir(out, "--out")
    detector = Detector.load(run, pickability=pickability)
    with progress() as callback:
        metrics = detector.val(data, targets, callback=callback)
    table = Table(title=f"{run} on {data} ({metrics['tasks']} tasks, targets {metrics['targets']})")
    for column in ("ground truth", "AP50", "mAP"):
        table.add_column(column)
    table.add_row("targets", _fmt(metrics["ap50"]), _fmt(metrics["map"]))
    table.add_row("all instances", _fmt(metrics["ap50_all"]), _fmt(metrics["map_all"]))
    table.add_row("unpickable (lower is better)", _fmt(metrics["ap50_unpickable"]), _fmt(metrics["map_unpickable"]))
    console.print(table)
    if metrics.get("scenes_trained_on"):
        console.print(f"warning: {metrics['scenes_trained_on']} of these scenes were in the weights' training set "
                      "(data sets made with one generator --seed share scenes): these figures are not held out", style="yellow")
    if out is not None:
        from binpick.viz.detection import plot_pr_curves

        atomic_write_json(out / "metrics.json", metrics)
        plot_pr_curves({str(run.name): {**metrics["pr"], "ap50": metrics["ap50"] or 0.0}}, out / "pr_curve.png", f"{data.name}")
        console.print(f"wrote {out / 'metrics.json'} and {out / 'pr_curve.png'}")


@detect_app.command("predict")
def detect_predict(
    image: Annotated[Path, typer.Argument(help="Scene image (PNG/JPEG)")],
    weights: Annotated[Path | None, typer.Option(help="Run folder, model.safetensors or a shipped name (default: the shipped model for the query kind)")] = None,
    query_box: Annotated[str | None, typer.Option(help="Known instance x,y,w,h in pixels")] = None,
    query_image: Annotated[Path | None, typer.Option(help="Product photo to look for (photo-conditioned models)")] = None,
    depth: Annotated[Path | None, typer.Option(help="The scene's depth: 16-bit PNG in mm or .npy in metres (detectors that read depth)")] = None,
    out: Annotated[Path | None, typer.Option(help="Overlay PNG: query blue, detections orange with scores, a legend")] = None,
    heatmap: Annotated[Path | None, typer.Option(help="PNG of the ROD levels' max heatmaps, titled, with a colour bar")] = None,
    min_score: Annotated[float, typer.Option(help="Detections below this score are not printed or drawn")] = 0.3,
    pickability: Annotated[bool, typer.Option(help="Re-score with the weights' pickability head, if they hold one (it needs --depth)")] = True,
) -> None:
    """Find the other instances of the query; prints JSON boxes (x, y, w, h) and scores."""
    from binpick.config import check_range
    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.detection.predict import parse_box

    check_range("--min-score", min_score, 0.0, 1.0)
    for path, option in ((out, "--out"), (heatmap, "--heatmap")):
        if path is not None:
            _check_png_path(path, option)
    detector = Detector.load(weights or (PICKING if query_image is not None else "rod_tiny_320"), pickability=pickability)
    box = parse_box(query_box) if query_box is not None else None
    import warnings

    with warnings.catch_warnings(record=True) as notes:
        warnings.simplefilter("always")
        prediction = detector.predict(image, box, query_image, min_score=min_score, depth=depth)
    for note in notes:
        console.print(f"note: {note.message}", style="yellow")
    print(json.dumps(prediction.to_json(min_score)))  # as drawn: what still scores min_score after a head's second look
    if out is not None:
        _save_png(prediction.plot(), out, "--out")
    if heatmap is not None:
        _save_png(prediction.plot_heatmaps(), heatmap, "--heatmap")


MasterOption = Annotated[str | None, typer.Option("--master", help="ROS master URI (default: $ROS_MASTER_URI)")]
NamespaceOption = Annotated[str, typer.Option(help="Action namespace clients connect to, e.g. /binpick/env")]


def _check_timeout(timeout: float) -> float:
    from binpick.config import check_range

    return check_range("--timeout", timeout, 0.0, 3600.0, low_inclusive=False)


def _check_namespace(namespace: str, option: str = "--namespace") -> str:
    import re

    if not re.fullmatch(r"/?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*/?", namespace):
        raise ConfigError(f"{option} must be a ROS graph name like /binpick/env (letters, digits, _ and /), "
                          f"got {namespace!r}")
    return namespace


def _ros_environment(master: str | None, timeout: float) -> None:
    """Point this process's ROS node at ``master`` on 127.0.0.1 (before rospy is imported), and wait up
    to ``timeout`` seconds for it to answer: rospy would wait forever."""
    import os

    from binpick.ros import check_master_uri, local_ros_environment, require_ros, wait_for_master

    uri = master or os.environ.get("ROS_MASTER_URI")
    if not uri:
        raise ConfigError("no ROS master: give --master http://127.0.0.1:PORT/ or set ROS_MASTER_URI")
    check_master_uri(uri)
    require_ros()
    wait_for_master(uri, timeout)
    os.environ.update({k: v for k, v in local_ros_environment(uri).items() if k not in os.environ or k == "ROS_MASTER_URI"})


@ros_app.command("master")
def ros_master(port: Annotated[int, typer.Option(min=1, max=65535, help="Port on 127.0.0.1")] = 11311) -> None:
    """Run a ROS master on 127.0.0.1 until Ctrl-C or SIGTERM (both stop the master process too)."""
    import signal

    from binpick.ros.master import RosMaster

    def stop(*_: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)  # `kill` of this command must not leave rosmaster listening
    try:  # a stop while rosmaster still starts is as clean as one later (RosMaster stops its child either way)
        with RosMaster(port) as master:
            console.print(f"ROS master at {master.uri} (Ctrl-C to stop)")
            master.process.wait()
    except KeyboardInterrupt:
        pass


@ros_app.command("serve")
def ros_serve(
    env_id: Annotated[str, typer.Argument(help="binpick env id, e.g. binpick/FetchReach-v0")],
    namespace: NamespaceOption = "/binpick/env",
    master: MasterOption = None,
    timeout: Annotated[float, typer.Option(help="Seconds to wait for the ROS master")] = 10.0,
) -> None:
    """Serve an env as an actionlib server: goals reset or step it, results carry observation and reward."""
    from binpick.envs import resolve_env_id

    env_id = resolve_env_id(env_id)
    _check_namespace(namespace)
    _ros_environment(master, _check_timeout(timeout))
    from binpick.ros.server import serve

    serve(env_id, namespace)


@ros_app.command("bench")
def ros_bench(
    namespace: Annotated[str, typer.Option(help="Action namespace of a served Fetch env, e.g. /binpick/env")] = "/binpick/env",
    episodes: Annotated[int, typer.Option(help="Episodes of the scripted reach policy")] = 10,
    master: MasterOption = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Also write the summary here")] = None,
    timeout: Annotated[float, typer.Option(help="Seconds to wait for the server and for each result")] = 10.0,
) -> None:
    """Drive a served Fetch env over ROS with the scripted reach policy: success and round-trip latency."""
    from binpick.config import check_range

    check_range("episodes", episodes, 1, 100_000, integer=True)
    _check_namespace(namespace)
    if json_out is not None:
        check_output_file(json_out, "--json")
    _ros_environment(master, _check_timeout(timeout))
    import gymnasium as gym
    import numpy as np

    from binpick.rl.evaluate import evaluate_policy
    from binpick.rl.heuristic import ReachController

    env = gym.make("binpick/Ros-v0", namespace=namespace, timeout=timeout)
    result = evaluate_policy(ReachController(env.action_space.shape[0]), env, episodes=episodes, seed=0)
    trips = np.array(env.unwrapped.round_trips_ms)
    summary = {**result.to_dict(), "round_trips": int(trips.size), "median_ms": round(float(np.median(trips)), 3),
               "p95_ms": round(float(np.percentile(trips, 95)), 3), "namespace": namespace}
    print(json.dumps(summary))
    if json_out is not None:
        atomic_write_json(json_out, summary)


NodeCamera = Annotated[Path | None, typer.Option("--camera", help="camera.yaml whose camera_to_base places the camera in the robot's "
                                                                   "base frame (intrinsics come from the camera_info topic)")]
ColourTopic = Annotated[str, typer.Option(help="sensor_msgs/Image colour topic")]
DepthTopic = Annotated[str, typer.Option(help="sensor_msgs/Image depth topic, registered to colour (16UC1 mm or 32FC1 m)")]
InfoTopic = Annotated[str, typer.Option(help="sensor_msgs/CameraInfo of the colour camera")]
NodeProducts = Annotated[Path | None, typer.Option("--products", help="YAML of your own products (ids goals may name)")]
NodeWeights = Annotated[Path | None, typer.Option(help="Photo-conditioned detector (default: shipped)")]
NodeGrasp = Annotated[str, typer.Option(help="Grasp policy: learnt, analytic or fixed")]
NodeGraspWeights = Annotated[Path | None, typer.Option(help="Grasp-quality weights (default: shipped)")]
COLOUR, DEPTH, INFO = "/camera/color/image_raw", "/camera/aligned_depth_to_color/image_raw", "/camera/color/camera_info"


def _pick_node_setup(camera: Path | None, namespace: str, colour: str, depth: str, info: str, weights: Path | None, grasp: str,
                     grasp_weights: Path | None):
    """Checked names, then the extrinsic (a camera.yaml's camera_to_base; identity without one), the
    picker and the topics: everything a pick node needs before ROS starts."""
    import numpy as np

    from binpick.picking import Picker, read_camera_info
    from binpick.picking.node import Topics

    for name, option in ((namespace, "--namespace"), (colour, "--colour-topic"), (depth, "--depth-topic"), (info, "--info-topic")):
        _check_namespace(name, option)
    pose, frame, workspace = np.eye(4), "camera", None
    if camera is not None:
        calibration = read_camera_info(camera)
        pose, frame, workspace = calibration.camera.camera_to_world, calibration.base_frame, calibration.workspace
    # the camera_info topic brings K and D; camera.yaml's workspace bounds every pose the node emits
    return pose, frame, Picker.load(weights, grasp, grasp_weights, workspace=workspace), Topics(colour, depth, info)


@ros_app.command("pick-node")
def ros_pick_node(
    camera: NodeCamera = None,
    namespace: Annotated[str, typer.Option(help="Action namespace of the PlanPick server")] = "/binpick/plan_pick",
    colour_topic: ColourTopic = COLOUR, depth_topic: DepthTopic = DEPTH, info_topic: InfoTopic = INFO,
    products_file: NodeProducts = None, weights: NodeWeights = None, grasp: NodeGrasp = DEFAULT_POLICY,
    grasp_weights: NodeGraspWeights = None,
    master: MasterOption = None,
    timeout: Annotated[float, typer.Option(help="Seconds to wait for the ROS master")] = 10.0,
) -> None:
    """Serve pick planning over ROS 1: camera topics in, a PlanPick action (grasp poses in the base frame) out."""
    pose, frame, picker, topics = _pick_node_setup(camera, namespace, colour_topic, depth_topic, info_topic, weights, grasp, grasp_weights)
    library = product_library(products_file)
    _ros_environment(master, _check_timeout(timeout))
    from binpick.ros.pick_node import serve

    serve(picker, pose, frame, namespace, topics, library)


def _dimensions(text: str) -> list[float]:
    """``L,W,H`` in metres, each in (0, 2]."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(0.0 < v <= 2.0 for v in values):
        raise ConfigError(f"--size must be three lengths in metres L,W,H (each in (0, 2]), got {text!r}")
    return values


@ros2_app.command("pick-node")
def ros2_pick_node(
    camera: NodeCamera = None,
    namespace: Annotated[str, typer.Option(help="Namespace of the goal/result topics")] = "/binpick/plan_pick",
    colour_topic: ColourTopic = COLOUR, depth_topic: DepthTopic = DEPTH, info_topic: InfoTopic = INFO,
    products_file: NodeProducts = None, weights: NodeWeights = None, grasp: NodeGrasp = DEFAULT_POLICY,
    grasp_weights: NodeGraspWeights = None,
) -> None:
    """Serve pick planning over ROS 2 (run with .venv-ros2/bin/binpick): camera topics in, grasp poses out."""
    from binpick.ros2 import require_ros2

    require_ros2()
    pose, frame, picker, topics = _pick_node_setup(camera, namespace, colour_topic, depth_topic, info_topic, weights, grasp, grasp_weights)
    from binpick.ros2.pick_node import serve

    serve(picker, pose, frame, namespace, topics, product_library(products_file))


@app.command("pick")
def pick(
    product: Annotated[str, typer.Option(help="Product(s) to order: ids, unique short names or categories, comma-separated "
                                              "(orders cycle through them); `binpick products list` shows them")],
    products_file: Annotated[Path | None, typer.Option("--products", help="YAML of your own products (as for data generate)")] = None,
    photo: Annotated[list[Path] | None, typer.Option(help="Your own shop photo of the product; repeat for several views "
                                                        "(default: rendered catalogue views)")] = None,
    orders: Annotated[int, typer.Option(help="Orders to fulfil (one new bin each)")] = 5,
    weights: Annotated[Path | None, typer.Option(help="Photo-conditioned detector: run folder or .safetensors (default: shipped)")] = None,
    grasp: Annotated[str, typer.Option(help="Grasp policy: learnt (grasp-quality model), analytic (across the "
                                            "principal minor axis) or fixed (jaws along y, as before)")] = DEFAULT_POLICY,
    grasp_weights: Annotated[Path | None, typer.Option(help="Grasp-quality weights for --grasp learnt (default: shipped)")] = None,
    out: Annotated[Path | None, typer.Option(help="Folder for per-order GIFs, overlays, results.json and report.html "
                                                  "(default: runs/pick/<time>)")] = None,
    seed: Annotated[int, seed_option("Seed of the first order's bin")] = 0,
) -> None:
    """Fulfil orders end to end: shop photo -> ROD -> grasp chosen from depth -> grasp -> order tote."""
    from binpick.config import check_range
    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.grasping import GraspPlanner
    from binpick.warehouse.pipeline import PickPipeline

    check_range("orders", orders, 1, 100_000, integer=True)
    planner = GraspPlanner.load(grasp, grasp_weights)  # a bad policy or weights file: one line, before any work
    run_dir = ensure_dir(out or Path("runs/pick") / time.strftime("%Y%m%d-%H%M%S"), "--out")
    library = product_library(products_file)
    products = [pid for name in product.split(",") if name.strip() for pid in library.resolve(name.strip())]
    if not products:
        raise ConfigError(f"--product {product!r} names no product: give ids or categories, e.g. robosuite/milk,can")
    if photo:
        if len(products) != 1:
            raise ConfigError("--photo is the photo of one product: give exactly one product id with it")
        from dataclasses import replace

        from binpick.detection.data import read_image

        for path in photo:
            read_image(path)  # unreadable -> one line now, not mid-run
        library.add(replace(library[products[0]], photos=tuple(photo)))
    model = Detector.load(weights or PICKING).inference_network
    _fulfil(PickPipeline(model, library, grasp=planner), products, orders, seed, run_dir)


@app.command("plan")
def plan(
    rgb: Annotated[Path | None, typer.Option(help="Colour image (PNG/JPEG), registered with the depth image")] = None,
    depth: Annotated[Path | None, typer.Option(help="Depth image: 16-bit PNG in millimetres or .npy in metres (0: no reading), "
                                                    "at the colour's size or one of the same aspect")] = None,
    camera: Annotated[Path | None, typer.Option(help="camera.yaml: ROS camera_info layout, plus camera_to_base (the camera's pose in the robot's base frame)")] = None,
    sample: Annotated[bool, typer.Option(help="Plan on the sample frame that ships with binpick (a bin seen by a realistic "
                                              "RGB-D sensor, tilted; its shop photo unless --query-box)")] = False,
    photo: Annotated[list[Path] | None, typer.Option(help="Shop photo of the ordered product (a transparent PNG's alpha marks the "
                                                        "product); repeat for several photos of it (the best match counts)")] = None,
    query_box: Annotated[str | None, typer.Option(help="Or: x,y,w,h of the instance to pick in the colour image (planned "
                                                       "first, then the copies of it that the detector finds)")] = None,
    copies_only: Annotated[bool, typer.Option(help="With --query-box: plan on the other copies only, not the instance "
                                                   "pointed at (repeated-object evaluation)")] = False,
    out: Annotated[Path, typer.Option(help="plan.json: grasps (position, quaternion x,y,z,w in the base frame), scores, boxes")] = Path("plan.json"),
    overlay: Annotated[Path | None, typer.Option(help="PNG of the frame with detections and the planned jaws, numbered")] = None,
    weights: Annotated[Path | None, typer.Option(help="Detector: run folder or .safetensors (default: the shipped one for the query)")] = None,
    grasp: Annotated[str, typer.Option(help="Grasp policy: learnt, analytic or fixed")] = DEFAULT_POLICY,
    grasp_weights: Annotated[Path | None, typer.Option(help="Grasp-quality weights for --grasp learnt (default: shipped)")] = None,
    max_grasps: Annotated[int, typer.Option(help="Plan grasps for this many detections (best first)")] = 3,
    size: Annotated[str | None, typer.Option(help="The product's catalogue dimensions L,W,H in metres: instances clearly "
                                                  "bigger are not grasped")] = None,
) -> None:
    """Plan grasps from one real RGB-D frame: no simulator. Prints the best grasp; writes plan.json."""
    from binpick.config import check_range
    import numpy as np

    from binpick.detection.predict import parse_box
    from binpick.files import atomic_write_text
    from binpick.picking import Picker
    from binpick.picking.frames import read_frame, read_photo

    check_range("--max-grasps", max_grasps, 1, 100, integer=True)
    if sample:
        from binpick.samples import SAMPLE_FRAME

        rgb, depth, camera = rgb or SAMPLE_FRAME / "rgb.png", depth or SAMPLE_FRAME / "depth.png", camera or SAMPLE_FRAME / "camera.yaml"
        photo = photo if photo or query_box is not None else [SAMPLE_FRAME / "photo.png"]
    if rgb is None or depth is None or camera is None:
        raise ConfigError("give the frame's --rgb, --depth and --camera (or --sample for the frame that ships with binpick)")
    if (not photo) == (query_box is None):
        raise ConfigError("give exactly one of --photo (the product's shop photo; repeatable) or --query-box x,y,w,h")
    if out.suffix.lower() != ".json":
        raise ConfigError(f"--out must end in .json, got {str(out)!r}")
    check_output_file(out, "--out")
    if overlay is not None:
        _check_png_path(overlay, "--overlay")
    box = parse_box(query_box) if query_box is not None else None
    dimensions = _dimensions(size) if size is not None else None
    colour, metres, info = read_frame(rgb, depth, camera)
    query = [read_photo(path) for path in photo] if photo else None
    if box is not None and (box[0] < 0 or box[1] < 0 or box[0] + box[2] > colour.shape[1] or box[1] + box[3] > colour.shape[0]):
        raise ConfigError(f"--query-box {query_box!r} lies outside the {colour.shape[1]}x{colour.shape[0]} colour image")
    crop = weights if box is not None else None
    picker = Picker.load(None if box is not None else weights, grasp, grasp_weights, crop_detector=crop, max_grasps=max_grasps)
    if copies_only and box is None:
        raise ConfigError("--copies-only goes with --query-box (the instance whose copies to plan on)")
    plans = picker.plan(colour, metres, info, photo=query, query_box=box, size=dimensions, copies_only=copies_only)
    result = {"inputs": {"rgb": str(rgb), "depth": str(depth), "camera": str(camera),
                         "photo": [str(path) for path in photo] if photo else None, "query_box": query_box, "copies_only": copies_only,
                         "size": dimensions},
              "grasp_policy": grasp, **plans.to_json()}
    atomic_write_text(out, json.dumps(result, indent=1))
    if overlay is not None:
        _save_png(plans.plot(colour, info.camera, picker.grasp.gripper.opening, query, box), overlay, "--overlay")
    best = plans.grasps[0] if plans.grasps else None
    if best is None:
        reasons: dict[str, int] = {}
        for p in plans:
            for k, n in p.rejected.items():
                reasons[k] = reasons.get(k, 0) + n
        why = [f"{plans.not_the_product} failed the product check"] if plans.not_the_product else []
        why += [f"{k} x{n}" for k, n in reasons.items()]
        console.print(f"no feasible grasp: {plans.detections} detection(s){': ' + '; '.join(why) if why else ''} -> {out}", soft_wrap=True)
    else:
        x, y, z = best.position
        console.print(f"{len(plans.grasps)} grasp(s) from {plans.detections} detections in {plans.timing_ms['total']:.0f} ms; best: "
                      f"({x:.3f}, {y:.3f}, {z:.3f}) m in {plans.frame}, yaw {np.degrees(best.yaw):.0f} deg, "
                      f"width {100 * best.width:.1f} cm, score {best.score:.2f} -> {out}", soft_wrap=True)


def _fulfil(pipeline, products: list[str], orders: int, seed: int, run_dir: Path) -> dict:
    """Run the orders with a progress bar, then print their table and the summary."""
    from binpick.warehouse.pipeline import fulfil

    table = Table(title=f"{orders} order{'s' if orders > 1 else ''}")
    for column in ("order", "product", "trained", "result", "grasps", "found", "s"):
        table.add_column(column, no_wrap=column != "result")  # long failure reasons wrap; the rest stays whole
    with progress() as callback, callback.task("orders", orders) as task:

        def row(result) -> None:
            seen = "?" if result.seen is None else "yes" if result.seen else "no"
            outcome = Text("placed", style="green") if result.success else Text(str(result.reason), style="red")
            table.add_row(str(result.order), result.product, seen, outcome,
                          str(result.grasps), str(result.detections), f"{result.seconds:.1f}")
            task.update(advance=1)

        summary, _ = fulfil(pipeline, products, orders, seed, run_dir, on_order=row)
    console.print(table)
    right = "n/a" if summary["right_product"] is None else format(summary["right_product"], ".0%")
    console.print(f"pick success {summary['pick_success']:.0%}, right product {right}, {summary['picks_per_min']} picks/min, "
                  f"{summary['orders']} orders in {summary['wall_s']} s")
    console.print(f"report: {run_dir / 'report.html'} (GIFs and results.json beside it)", soft_wrap=True)
    return summary


# The demo's orders, in turn: four products the shipped detector was trained on, two held out (duck, can).
DEMO_PRODUCTS = ("robosuite/milk", "robosuite/cereal", "pybullet/duck", "procedural/box_03", "robosuite/bottle", "robosuite/can")


@app.command("demo")
def demo(
    orders: Annotated[int, typer.Option(help="Orders to fulfil (products cycle through the demo's list)")] = 6,
    out: Annotated[Path | None, typer.Option(help="Folder for the report, GIFs and results.json (default: runs/demo/<time>)")] = None,
    seed: Annotated[int, seed_option("Seed of the first order's bin")] = 0,
) -> None:
    """The main job: fulfil a handful of orders end to end with the shipped detector, products seen in
    its training and zero-shot ones, and write an HTML report with each order's detections and GIF."""
    from binpick.config import check_range
    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.grasping import GraspPlanner
    from binpick.sim import default_library
    from binpick.warehouse.pipeline import PickPipeline

    check_range("orders", orders, 1, 1000, integer=True)
    run_dir = ensure_dir(out or Path("runs/demo") / time.strftime("%Y%m%d-%H%M%S"), "--out")
    model = Detector.load(PICKING).inference_network
    _fulfil(PickPipeline(model, default_library(), grasp=GraspPlanner.load(DEFAULT_POLICY)), list(DEMO_PRODUCTS), orders, seed, run_dir)


def _check_png_path(path: Path, option: str = "--out") -> Path:
    """A PNG path that can be written (checked before the work that fills it starts)."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ConfigError(f"{option} must end in .png, got {str(path)!r}")
    return check_output_file(path, option)


def _save_png(array, path: Path, option: str = "--out") -> None:
    from PIL import Image

    path = _check_png_path(path, option)
    atomic_write(path, lambda handle: Image.fromarray(array).save(handle, format="PNG"))


def warn(message: str | None) -> None:
    """``warning: <message>`` as one line on stderr (nothing for None)."""
    if message:
        Console(stderr=True, highlight=False).print(f"warning: {' '.join(message.split())}", markup=False, soft_wrap=True)


def print_error(message: str) -> None:
    """``error: <message>`` as one line on stderr; the message is never read as Rich markup."""
    from rich.text import Text

    line = " ".join(str(message).split())  # one line, whatever the message holds
    Console(stderr=True, highlight=False).print(Text.assemble(("error: ", "bold red"), line), soft_wrap=True)


def main() -> None:
    """Console-script entry point: run the app; a user's mistake ends in one line and exit code 2.

    Click's usage errors (a bad option value, a missing argument) are printed the same way as
    binpick's own, instead of Typer's boxed panel."""
    try:
        code = app(prog_name="binpick", standalone_mode=False)
    except typer.TyperException as error:  # Click's errors, as Typer vendors Click
        context = getattr(error, "ctx", None)
        if type(error).__name__ == "NoArgsIsHelpError" and context is not None:  # `binpick rl` alone: its help
            typer.echo(context.get_help())
        else:
            command = context.command_path if context is not None else "binpick"
            message = error.format_message() if hasattr(error, "format_message") else str(error)
            print_error(f"{message} (see '{command} --help')")
        sys.exit(getattr(error, "exit_code", 2))
    except typer.Abort:
        print_error("aborted")
        sys.exit(130)
    except BinpickError as error:
        print_error(str(error))
        sys.exit(2)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()

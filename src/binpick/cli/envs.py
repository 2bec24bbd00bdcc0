"""The worlds and the product library: `binpick envs ...`, `binpick products list`."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from binpick.cli.app import (
    POLICIES,
    SetOption,
    check_png_path,
    console,
    envs_app,
    output_folder,
    parse_settings,
    product_library,
    products_app,
    progress,
    save_png,
    seed_option,
)
from binpick.core.errors import ConfigError
from binpick.core.files import atomic_write_json, check_output_file, ensure_dir


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
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder for <env>.png (and <env>_obs.png, the policy's image)")] = Path("."),
    seed: Annotated[int, seed_option("Reset seed")] = 0,
    size: Annotated[int, typer.Option(help="Frame side in pixels")] = 480,
    settings: SetOption = None,
) -> None:
    """Reset an env and save what a person sees (and the policy's image observation, if any)."""

    from binpick.envs import env_spec, make, resolve_env_id

    env_id = resolve_env_id(env_id)
    frame_path = output_folder(out) / f"{env_id.split('/')[-1]}.png"
    check_png_path(frame_path)
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
    save_png(frame, frame_path)
    console.print(f"wrote {frame_path} ({frame.shape[1]}x{frame.shape[0]})")
    image = observation.get("image") if isinstance(observation, dict) else observation
    if image is not None:
        obs_path = frame_path.with_name(frame_path.stem + "_obs.png")
        save_png(image[..., 0] if image.shape[-1] == 1 else image, obs_path)
        console.print(f"wrote {obs_path} (image observation {image.shape[1]}x{image.shape[0]}x{image.shape[2]})")


@envs_app.command("rollout")
def envs_rollout(
    env_id: Annotated[str, typer.Argument(help="Env id, e.g. binpick/Arm2D-v0 or Arm2D")],
    policy: Annotated[str, typer.Option(help=f"Policy to run: {', '.join(POLICIES)}")] = "random",
    episodes: Annotated[int, typer.Option(help="Number of seeded episodes")] = 20,
    seed: Annotated[int, seed_option("Seed of the first episode (episode i uses seed+i)")] = 0,
    out: Annotated[Path | None, typer.Option(help="Also write rollout.json (the result) into this folder")] = None,
    settings: SetOption = None,
) -> None:
    """Run a policy and print the thesis's metric: average episode length ± std and success rate."""
    from binpick.core.config import check_choice, check_range
    from binpick.envs import make
    from binpick.rl.common.evaluate import evaluate_policy, random_policy

    check_choice("policy", policy, POLICIES)
    check_range("episodes", episodes, 1, None, integer=True)
    json_out = None if out is None else check_output_file(output_folder(out) / "rollout.json", "--out")
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
    from binpick.core.config import check_range
    from binpick.envs import ENV_IDS, make
    from binpick.rl.common.evaluate import evaluate_policy, random_policy

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
                save_png(env.render(), frame_path)
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

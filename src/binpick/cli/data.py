"""Warehouse bin data sets: `binpick data generate|show|export|stats`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from binpick.cli.app import (
    check_png_path,
    console,
    data_app,
    job_progress,
    output_folder,
    parse_pair,
    parse_settings,
    save_png,
    seed_option,
    warn,
)
from binpick.core.errors import ConfigError


@data_app.command("generate")
def data_generate(
    out: Annotated[Path, typer.Option(help="Data-set folder (new, or one to resume)")],
    scenes: Annotated[int, typer.Option(help="Number of bin scenes")] = 100,
    policies: Annotated[str, typer.Option(help="Policies that label pickability: x, y, analytic, learnt; '' none")] = "x,y",
    workers: Annotated[int, typer.Option(help="Parallel processes")] = 2,
    grasp_trials: Annotated[int, typer.Option(help="Grasps tried per instance (grasp-quality data)")] = 0,
    products: Annotated[Path | None, typer.Option(help="YAML of your own products")] = None,
    only_products: Annotated[bool, typer.Option("--only-products", help="Only the products in --products")] = False,
    size: Annotated[int, typer.Option(help="Image size in pixels")] = 416,
    copies: Annotated[str, typer.Option(help="Copies of the target per bin, LOW,HIGH")] = "2,8",
    distractors: Annotated[str, typer.Option(help="Other products per bin, LOW,HIGH")] = "0,3",
    held_out: Annotated[str, typer.Option(help="Categories for the zero-shot test split")] = "",
    targets: Annotated[str, typer.Option(help="Products or categories to fill bins with")] = "",
    randomise: Annotated[bool, typer.Option("--randomise", hidden=True, help="Randomise lighting and colours per world (older; see --domain)")] = False,
    domain: Annotated[str, typer.Option(help="default, random, shifted or a domain YAML")] = "default",
    sensor: Annotated[str, typer.Option(help="Depth: perfect, realistic (structured light: holes, noise, tilt), stereo, tof "
                                            "or a sensor YAML")] = "perfect",
    address: Annotated[str | None, typer.Option(help="Ray cluster HOST:PORT, or local")] = None,
    val_fraction: Annotated[float, typer.Option(help="Share of worlds in the val split")] = 0.1,
    scenes_per_world: Annotated[int, typer.Option(help="Scenes per compiled world (one product)")] = 8,
    photo_views: Annotated[int, typer.Option(help="Randomised studio photos per product")] = 0,
    gripper: Annotated[str, typer.Option(help="The hand's tools: jaws, suction or both (grasp trials with each)")] = "jaws",
    robot: Annotated[str, typer.Option(help="Who makes the label grasps: floating (the gripper alone) or panda (the arm: "
                                            "'pickable' by this arm; slower)")] = "floating",
    cell: Annotated[Path | None, typer.Option(help="Your cell file: its hand (tools, jaws, cup; on the arm its tool point) "
                                                   "makes the grasp trials and labels (replaces --gripper)")] = None,
    seed: Annotated[int, seed_option("Seed")] = 0,
    settings: Annotated[list[str] | None, typer.Option("--set", metavar="KEY=VALUE", help="Any other setting (binpick train --list)")] = None,
) -> None:
    """Generate bin scenes (resumes after a kill), shop photos, COCO files and a data-set card."""
    from binpick.core.config import from_dict
    from binpick.core.jobs import open_job, run_job
    from binpick.warehouse.generation import GenerateConfig

    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {str(out)!r} is a file, not a data-set folder")
    flags = {"out": str(out), "scenes": scenes, "policies": [p for p in policies.split(",") if p], "workers": workers,
             "grasp_trials": grasp_trials,
             "image_size": size, "copies": list(parse_pair(copies, "copies")), "distractors": list(parse_pair(distractors, "distractors")),
             "held_out_categories": [c for c in held_out.split(",") if c], "randomise": randomise, "domain": domain, "sensor": sensor,
             "targets": [t for t in targets.split(",") if t], "products": str(products) if products else None,
             "only_products": only_products, "val_fraction": val_fraction, "scenes_per_world": scenes_per_world, "photo_views": photo_views,
             "robot": robot, "gripper": gripper, "cell": str(cell) if cell else None, "seed": seed}
    config = from_dict(GenerateConfig, flags | parse_settings(settings), where="data generate")  # validated once
    with job_progress(out, f"binpick data generate --out {out} (the same options), or binpick train --resume {out}") as callback:
        stats = run_job(open_job(settings=config, task="data", address=address), callback, address)
    _print_stats(stats, out)
    empty = [split for split in ("train", "val") if not stats["splits"].get(split)]
    if empty:
        warn(f"no {' and no '.join(empty)} scenes: a detector needs both; give --scenes-per-world 1 and a "
             "--val-fraction that leaves each some scenes")


@data_app.command("show")
def data_show(
    data: Annotated[Path, typer.Argument(help="Data-set folder")],
    scene: Annotated[int, typer.Option(help="Scene index")] = 0,
    out: Annotated[Path, typer.Option(help="Folder for scene_<index>.png")] = Path("."),
    policy: Annotated[str | None, typer.Option(help="Colour pickability by this policy (default: the first)")] = None,
) -> None:
    """Draw a scene's boxes: green pickable, red unpickable, blue the query, grey other products."""
    from binpick.viz.bins import labelled_scene
    from binpick.warehouse.coco import read_scene

    path = check_png_path(output_folder(out) / f"scene_{scene:06d}.png")
    record, policies = read_scene(data, scene)
    if policy is not None and policy not in policies:
        raise ConfigError(f"--policy {policy!r}: this data set was labelled by {', '.join(policies) or 'no policy'}")
    save_png(labelled_scene(data, record, policy or (policies[0] if policies else None)), path)
    console.print(f"scene {scene} ({record['target']}, {len(record['annotations'])} instances) -> {path}")


@data_app.command("export")
def data_export(
    data: Annotated[Path, typer.Argument(help="Data-set folder")],
    out: Annotated[Path, typer.Option(help="Folder for the files (one sub-folder per scene when several)")],
    scene: Annotated[list[int] | None, typer.Option(metavar="INDEX", help="Scene index (repeat for several; default: 0)")] = None,
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
    from binpick.warehouse.coco import dataset_stats, load_records, open_dataset

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

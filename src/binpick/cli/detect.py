"""Repeated object detection: `binpick detect train|pickability|eval|predict`, `binpick grasp train`."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from binpick.cli.app import (
    ConfigSetOption,
    ResumeOption,
    RunsOption,
    RuntimeOption,
    console,
    detect_app,
    fmt_metric,
    grasp_app,
    output_folder,
    progress,
    save_png,
    warn,
)
from binpick.cli.train import run_task
from binpick.core.errors import ConfigError
from binpick.core.files import atomic_write_json


@detect_app.command("train")
def detect_train(
    config: Annotated[Path | None, typer.Argument(help="YAML config (see configs/detection/rod_*.yaml)")] = None,
    resume: ResumeOption = None,
    runs: RunsOption = Path("runs"),
    settings: ConfigSetOption = None,
) -> None:
    """Train a detector: checkpoints each epoch, TensorBoard, metrics.json and model.safetensors in runs/<name>/<time>/."""

    trainer, metrics = run_task("detect", config, resume, runs, settings,
                                before_run=lambda job: console.print(f"{len(job.train_set)} training tasks"))
    final = metrics["final"]
    console.print(f"val AP50 {fmt_metric(final.get('ap50'))}, mAP {fmt_metric(final.get('map'))}; wrote {trainer.run_dir / 'model.safetensors'}")


@detect_app.command("pickability")
def detect_pickability(
    config: Annotated[Path | None, typer.Argument(help="YAML config (see configs/detection/pickability_crop.yaml)")] = None,
    resume: ResumeOption = None,
    runs: RunsOption = Path("runs"),
    settings: ConfigSetOption = None,
) -> None:
    """Teach a detector a second look at each detection (will the policy pick this copy?): windows cut
    once, a checkpoint each epoch, TensorBoard, the best val ROC AUC kept; model.safetensors in
    runs/<name>/<time>/ is the detector with its pickability head."""
    trainer, metrics = run_task("pickability", config, resume, runs, settings)
    console.print(f"best val ROC AUC {fmt_metric(metrics['best_val_auc'])}; wrote {trainer.run_dir / 'model.safetensors'} "
                  f"(binpick detect eval {trainer.run_dir} --data ...)")


@grasp_app.command("train")
def grasp_train(
    config: Annotated[Path | None, typer.Argument(help="YAML config (see configs/grasping/grasp_quality.yaml)")] = None,
    resume: ResumeOption = None,
    runs: RunsOption = Path("runs"),
    settings: ConfigSetOption = None,
) -> None:
    """Train the grasp-quality network on a data set with --grasp-trials: a checkpoint each epoch,
    TensorBoard, the best val ROC AUC kept, model.safetensors in runs/<name>/<time>/."""
    trainer, metrics = run_task("grasp_quality", config, resume, runs, settings)
    console.print(f"best val ROC AUC {fmt_metric(metrics['best_val_auc'])}; wrote {trainer.run_dir / 'model.safetensors'} "
                  f"(use it with binpick pick --grasp learnt --grasp-weights)")


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
        output_folder(out)
    detector = Detector.load(run, pickability=pickability)
    with progress() as callback:
        metrics = detector.val(data, targets, callback=callback)
    table = Table(title=f"{run} on {data} ({metrics['tasks']} tasks, targets {metrics['targets']})")
    for column in ("ground truth", "AP50", "mAP"):
        table.add_column(column)
    table.add_row("targets", fmt_metric(metrics["ap50"]), fmt_metric(metrics["map"]))
    table.add_row("all instances", fmt_metric(metrics["ap50_all"]), fmt_metric(metrics["map_all"]))
    table.add_row("unpickable (lower is better)", fmt_metric(metrics["ap50_unpickable"]), fmt_metric(metrics["map_unpickable"]))
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
    image: Annotated[Path | None, typer.Argument(help="Scene image (PNG/JPEG)")] = None,
    sample: Annotated[bool, typer.Option("--sample", help="The sample frame that ships with binpick: its colour, depth and shop photo")] = False,
    weights: Annotated[Path | None, typer.Option(help="Run folder, model.safetensors or a shipped name (default: the shipped model for the query kind)")] = None,
    query_box: Annotated[str | None, typer.Option(help="Known instance x,y,w,h in pixels")] = None,
    photo: Annotated[Path | None, typer.Option(help="Shop photo of the product to look for (photo-conditioned models)")] = None,
    depth: Annotated[Path | None, typer.Option(help="The scene's depth: 16-bit PNG in mm or .npy in metres (detectors that read depth)")] = None,
    out: Annotated[Path | None, typer.Option(help="Folder for detections.json and overlay.png (query blue, detections orange with scores)")] = None,
    heatmap: Annotated[bool, typer.Option("--heatmap", help="Also heatmap.png in --out: the ROD levels' max heatmaps, with a colour bar")] = False,
    min_score: Annotated[float, typer.Option(help="Detections below this score are not printed or drawn")] = 0.3,
    pickability: Annotated[bool, typer.Option(help="Re-score with the weights' pickability head, if they hold one (it needs --depth)")] = True,
    runtime: RuntimeOption = "torch",
) -> None:
    """Find the other instances of the query; prints JSON boxes (x, y, w, h) and scores."""
    from binpick.core.config import check_range
    from binpick.detection import Detector
    from binpick.detection.detector import PICKING
    from binpick.detection.predict import parse_box

    check_range("--min-score", min_score, 0.0, 1.0)
    if sample:
        from binpick.samples import SAMPLE_FRAME

        image, depth = image or SAMPLE_FRAME / "rgb.png", depth or SAMPLE_FRAME / "depth.png"
        photo = photo if photo is not None or query_box is not None else SAMPLE_FRAME / "photo.png"
    if image is None:
        raise ConfigError("give the scene IMAGE (or --sample for the frame that ships with binpick)")
    if heatmap and out is None:
        raise ConfigError("--heatmap writes heatmap.png into --out: give --out FOLDER")
    folder = None if out is None else output_folder(out)
    detector = Detector.load(weights or (PICKING if photo is not None else "rod_tiny_320"), pickability=pickability, runtime=runtime)
    box = parse_box(query_box) if query_box is not None else None
    import warnings

    with warnings.catch_warnings(record=True) as notes:
        warnings.simplefilter("always")
        # scored down to 0.01 (greedy NMS keeps the same boxes above min_score), so a miss can say how close it came
        prediction = detector.predict(image, box, photo, min_score=min(min_score, 0.01), depth=depth)
    for note in notes:
        console.print(f"note: {note.message}", style="yellow")
    found = prediction.to_json(min_score)  # as drawn: what still scores min_score after a head's second look
    print(json.dumps(found))
    if not found:
        best = max((float(s) for s in prediction.scores), default=None)
        warn(f"no detection scores {min_score}" + ("" if best is None else f"; the best scores {best:.3f}: "
             f"--min-score {max(0.0, float(f'{best:.2f}') - 0.01):.2f} shows it"))
    if folder is not None:
        atomic_write_json(folder / "detections.json", {"image": str(image), "min_score": min_score, "detections": found})
        save_png(prediction.plot(min_score), folder / "overlay.png", "--out")
        written = ["detections.json", "overlay.png"]
        if heatmap:
            save_png(prediction.plot_heatmaps(), folder / "heatmap.png", "--out")
            written.append("heatmap.png")
        console.print(f"wrote {', '.join(written)} in {folder}")


@detect_app.command("export")
def detect_export(
    weights: Annotated[Path, typer.Argument(help="Run folder, model.safetensors or a shipped name (rod_photo_learnt_tiny_320)")],
    out: Annotated[Path, typer.Option(help="Folder for <name>.onnx")] = Path("."),
    format: Annotated[str, typer.Option(help="Deployment format: onnx")] = "onnx",
) -> None:
    """Export a photo-conditioned detector for deployment (ONNX; run it with --runtime onnx or ONNX Runtime)."""
    from binpick.detection import Detector

    folder = output_folder(out)
    detector = Detector.load(weights)
    path = detector.export(format, folder)
    console.print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB): inputs images, photo_0..{len(detector.network.spec.photo_sizes) - 1}"
                  f"{', depth' if detector.network.spec.depth else ''}; outputs boxes (xyxy pixels), scores")

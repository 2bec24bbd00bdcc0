"""Grasps that fit each instance: the grasp-quality model and three grasp policies.

    binpick data generate --out runs/data/grasp_trials_realistic --scenes 800 --policies '' --grasp-trials 4 \\
        --copies 3,6 --distractors 2,3 --held-out can,mug,toy --workers 2 --sensor realistic   # trials (resumable)
    binpick data generate --out runs/data/grasp_trials_perfect --scenes 400 --policies '' --grasp-trials 4 \\
        --copies 3,6 --distractors 2,3 --held-out can,mug,toy --workers 2 --seed 1                  # perfect depth too
    python experiments/grasp.py train                  # configs/grasping/grasp_quality.yaml: trains, ships the weights
    python experiments/grasp.py eval --data runs/data/grasp_trials_realistic --data runs/data/grasp_trials_perfect \\
        [--bins 40]                                   # results/grasp.json: both kinds of depth
    binpick data generate --out runs/data/bins_learnt --scenes 1000 --policies learnt --workers 2 \
        --held-out can,mug,toy --set split_rule=random                         # pickability by the learnt policy
    python experiments/grasp.py pickability                                     # fine-tunes ROD on it, before/after
    binpick detect pickability configs/detection/pickability_photo_learnt_window.yaml --runs runs/grasp   # the shipped second look
    binpick detect pickability configs/detection/pickability_photo_learnt.yaml --runs runs/grasp   # one that also sees the photo
    python experiments/grasp.py pickability --head RUN [--head RUN]             # ... a row per head
    binpick train configs/data/grasp_trials_both_realistic.yaml                # trials with the jaws and the suction cup
    python experiments/grasp.py suction      # configs/grasping/suction_quality.yaml: trains, ships the suction model
    python experiments/grasp.py jaws         # the jaws' model trained further on them (boxes at their share), shipped if no worse
    python experiments/grasp.py calibrate    # or: the shipped jaws model's probabilities calibrated on those trials alone
    python experiments/grasp.py tools        # results/grasp.json held_out_trials_by_tool: AUC and calibration error per tool

``eval`` reports (a) the model's ROC AUC on the held-out categories' trials (test split: products it
never trained on), next to the analytic score's; (b) top-1 success: in new bins of held-out products,
every visible copy (≥ 50% visible) is grasped by each policy's first choice (fixed yaw, analytic,
learnt) from the same saved state, lifted, held and carried at the pick pipeline's speed; (c)
planning time per order: depth -> points -> candidates and scores for three detections, on 2 cores. Writes results/grasp.json and the grasp section of docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import _common  # noqa: E402
from rod import run_folder, finished  # noqa: E402  (the newest run folder of a name; has it written its weights)

DATA = _common.ROOT / "runs" / "data" / "grasp_trials_realistic"
RUNS = _common.ROOT / "runs" / "grasp"
HELD_OUT = ["can", "mug", "toy"]
SEED = 40_000  # bins away from the data set's and the pick benchmark's
POLICIES = ["fixed", "analytic", "learnt"]


def train() -> None:
    """The shipped model's recipe (configs/grasping/grasp_quality.yaml), resumed if its newest run stopped."""
    from binpick.core.config import load_config
    from binpick.grasping.quality import SHIPPED, GraspQuality
    from binpick.grasping.training import QualityTrainConfig, QualityTrainer
    from binpick.cli.terminal import RichCallback

    folder = run_folder(RUNS, "grasp_quality")
    if folder is not None and not finished(folder):
        trainer = QualityTrainer.resume(folder)
    else:
        trainer = QualityTrainer.new(load_config(QualityTrainConfig, _common.recipe("grasp_quality")[0]), RUNS)
    with RichCallback() as callback:
        metrics = trainer.run(callback)
    print(f"best val AUC {metrics['best_val_auc']} after {metrics['epochs']} epochs in {trainer.run_dir}", flush=True)
    model = GraspQuality.load(trainer.run_dir / "model.safetensors")
    SHIPPED.parent.mkdir(parents=True, exist_ok=True)
    model.save(SHIPPED, {"run": str(trainer.run_dir.relative_to(_common.ROOT)), "held_out_categories": HELD_OUT})
    print(f"shipped {SHIPPED.relative_to(_common.ROOT)} ({SHIPPED.stat().st_size / 1024:.0f} KiB)", flush=True)


def train_and_ship(tool: str, name: str) -> None:
    """configs/grasping/<name>.yaml (resumed if its newest run stopped), then shipped as ``tool``'s model
    where it is no worse on the held-out trials (test split: categories it never trained on) than the one
    shipped (or none is); the comparison is kept with the weights."""
    from binpick.core.config import load_config
    from binpick.grasping.quality import SHIPPED as JAWS
    from binpick.grasping.suction_quality import SHIPPED as SUCTION
    from binpick.grasping.training import QualityTrainConfig, QualityTrainer, load_model, load_trials
    from binpick.core.metrics import calibration_error, roc_auc
    from binpick.cli.terminal import RichCallback

    shipped = JAWS if tool == "jaws" else SUCTION
    folder = run_folder(RUNS, name)
    if folder is not None and not finished(folder):
        trainer = QualityTrainer.resume(folder)
    else:
        trainer = QualityTrainer.new(load_config(QualityTrainConfig, _common.recipe(name)[0]), RUNS)
    with RichCallback() as callback:
        metrics = trainer.run(callback)
    print(f"best val AUC {metrics['best_val_auc']} after {metrics['epochs']} epochs in {trainer.run_dir}; "
          f"calibration {metrics['calibration']}", flush=True)
    candidate = load_model(tool, trainer.run_dir / "model.safetensors")
    test = load_trials(trainer.config.data_sets, "test", tool=tool)
    scored = {"candidate": candidate.probabilities(test.maps, test.features)}
    if shipped.is_file():
        scored["shipped"] = load_model(tool, shipped).probabilities(test.maps, test.features)
    def rounded(value):
        return None if value is None else round(value, 4)

    figures = {key: {"auc": rounded(roc_auc(test.labels, p)), "ece": rounded(calibration_error(test.labels, p))}
               for key, p in scored.items()}
    if figures["candidate"]["auc"] is None:
        raise SystemExit(f"the held-out {tool} trials hold one outcome only ({len(test)} trials): no AUC to compare; more scenes")
    print(f"held-out {tool} trials ({len(test)}): {figures}", flush=True)
    if "shipped" in figures and figures["shipped"]["auc"] is not None and figures["candidate"]["auc"] < figures["shipped"]["auc"]:
        raise SystemExit(f"not shipped: the candidate's held-out AUC {figures['candidate']['auc']:.4f} is below the shipped "
                         f"model's {figures['shipped']['auc']:.4f}")
    shipped.parent.mkdir(parents=True, exist_ok=True)
    candidate.save(shipped, {"run": str(trainer.run_dir.relative_to(_common.ROOT)), "held_out_categories": HELD_OUT,
                             "compared_on": {"trials": len(test), "data": trainer.config.data_sets, **figures}})
    print(f"shipped {shipped.relative_to(_common.ROOT)} ({shipped.stat().st_size / 1024:.0f} KiB)", flush=True)


def calibrate_jaws(data: list[Path]) -> None:
    """The shipped jaws model's probabilities calibrated (Platt scaling on the val trials of ``data``; its
    ranking, and so its AUC, unchanged), its calibration error before and after on their test trials."""
    from binpick.grasping.quality import SHIPPED, GraspQuality
    from binpick.grasping.training import calibrate, load_trials
    from binpick.core.metrics import calibration_error, roc_auc

    model = GraspQuality.load(SHIPPED)
    model.meta.pop("calibration", None)
    fitted = calibrate(model, load_trials([str(d) for d in data], "val", tool="jaws"))
    test = load_trials([str(d) for d in data], "test", tool="jaws")
    before = GraspQuality.load(SHIPPED)
    before.meta.pop("calibration", None)
    model.meta["calibration"] = {**fitted, "data": [str(d.relative_to(_common.ROOT) if d.is_absolute() else d) for d in data]}
    raw, calibrated = before.probabilities(test.maps, test.features), model.probabilities(test.maps, test.features)
    print(f"jaws, {len(test)} held-out trials: AUC {roc_auc(test.labels, raw):.4f} -> {roc_auc(test.labels, calibrated):.4f}, "
          f"ECE {calibration_error(test.labels, raw):.4f} -> {calibration_error(test.labels, calibrated):.4f}", flush=True)
    model.save(SHIPPED)
    print(f"calibration written into {SHIPPED.relative_to(_common.ROOT)}: {model.meta['calibration']}", flush=True)


def tool_trials(data: list[Path]) -> dict:
    """Each tool's shipped model on the held-out trials of ``data`` (test split: categories it never trained
    on): ROC AUC, expected calibration error and the reliability bins."""
    from binpick.grasping.quality import SHIPPED as JAWS, GraspQuality
    from binpick.grasping.suction_quality import SHIPPED as SUCTION, SuctionQuality
    from binpick.grasping.training import load_trials
    from binpick.core.metrics import calibration_error, reliability, roc_auc

    rows = {}
    for tool, path, kind in (("jaws", JAWS, GraspQuality), ("suction", SUCTION, SuctionQuality)):
        if not path.is_file():
            continue
        trials = load_trials([str(d) for d in data], "test", tool=tool)
        if not len(trials):
            continue
        p = kind.load(path).probabilities(trials.maps, trials.features)
        auc = roc_auc(trials.labels, p)
        rows[tool] = {"trials": len(trials), "success_rate": round(float(trials.labels.mean()), 4),
                      "roc_auc": None if auc is None else round(auc, 4), "ece": round(calibration_error(trials.labels, p), 4),
                      "reliability": reliability(trials.labels, p)}
    return rows


def section_grasp_tools(result: dict) -> str:
    """The grasp_tools section of docs/RESULTS.md: each tool's shipped quality model on held-out trials, and its
    reliability, from results/grasp.json's ``held_out_trials_by_tool``."""
    rows = result["held_out_trials_by_tool"]
    lines = ["### The jaws' and the suction cup's quality models on held-out trials", "",
             "`python experiments/grasp.py tools` → `results/grasp.json` → `held_out_trials_by_tool`: each shipped model on the "
             f"trials of held-out product categories (can, mug, toy; test split of `{', '.join(rows.get('data', []))}`), made by "
             "the hand that carries both tools on depth as a structured-light sensor gives it. Both models' probabilities are "
             "calibrated on the validation trials (Platt scaling); the planner ranks a detection's jaw and suction grasps by them.", "",
             "| tool | trials | succeeded | ROC AUC | expected calibration error |", "|---|---|---|---|---|"]
    for tool in ("jaws", "suction"):
        if tool in rows:
            row = rows[tool]
            lines.append(f"| {tool} | {row['trials']} | {row['success_rate']:.0%} | {row['roc_auc']:.3f} | {row['ece']:.3f} |")
    lines += ["", "Reliability (predicted → observed success, per bin of predicted probability with at least 10 trials): " + "; ".join(
        f"{tool}: " + ", ".join(f"{b['predicted']:.2f} → {b['observed']:.2f}" for b in rows[tool]["reliability"] if b["count"] >= 10)
        for tool in ("jaws", "suction") if tool in rows) + "."]
    lines += ["", "![Reliability of the two quality models](img/grasp_reliability.png)"]
    return "\n".join(lines)


def plot_reliability(rows: dict, path: Path) -> None:
    """The reliability diagram of each tool's model: observed against predicted success per bin (marker
    size: trials in the bin), the diagonal being perfect calibration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.6, 4.2), layout="constrained")
    ax.plot([0, 1], [0, 1], color="0.6", linestyle="--", linewidth=1, label="calibrated")
    for tool, colour in (("jaws", "tab:green"), ("suction", "tab:blue")):
        if tool not in rows:
            continue
        bins = rows[tool]["reliability"]
        ax.plot([b["predicted"] for b in bins], [b["observed"] for b in bins], color=colour, linewidth=1)
        ax.scatter([b["predicted"] for b in bins], [b["observed"] for b in bins], s=[8 + 0.2 * b["count"] for b in bins],
                   color=colour, label=f"{tool} (ECE {rows[tool]['ece']:.3f})", alpha=0.8)
    ax.set_xlabel("predicted success")
    ax.set_ylabel("observed success (held-out trials)")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.legend(loc="upper left", fontsize="small")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def held_out_auc(data: Path) -> dict:
    import numpy as np

    from binpick.grasping.quality import SHIPPED, GraspQuality
    from binpick.grasping.training import load_trials, roc_auc

    trials = load_trials(data, "test")
    model = GraspQuality.load(SHIPPED)
    scores = model.probabilities(trials.maps, trials.features)
    # the analytic policy's ingredients as a score: room for the fingers, a width that fits
    clearance, width = trials.features[:, 3], trials.features[:, 0]
    analytic = np.clip(clearance, -0.2, 0.6) - 4.0 * np.maximum(0.0, width - 0.93)
    return {"trials": len(trials), "success_rate": round(float(trials.labels.mean()), 4),
            "products": sorted(set(trials.products)), "roc_auc": {"learnt": round(roc_auc(trials.labels, scores), 4),
                                                                  "analytic": round(roc_auc(trials.labels, analytic), 4)}}


def top1(bins: int, sensor_name: str = "perfect") -> dict:
    import numpy as np

    from binpick.grasping import DepthFrame, GraspPlanner, PinholeCamera
    from binpick.grasping.quality import SHIPPED, GraspQuality
    from binpick.sim import default_library
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.gripper import lift_test, trial_timestep
    from binpick.sim.mjcf import CameraSpec
    from binpick.sim.sensor import load_sensor
    from binpick.core.depth import as_camera_depth

    sensor = load_sensor(sensor_name)
    library = default_library()
    products = [p.id for p in library.in_categories(HELD_OUT)]
    quality = GraspQuality.load(SHIPPED)
    planners = {name: GraspPlanner(name, quality if name == "learnt" else None) for name in POLICIES}
    outcomes: dict[str, list[bool]] = {name: [] for name in POLICIES}
    by_product: dict[str, dict[str, list[bool]]] = {}
    plan_ms: list[float] = []
    camera_spec = CameraSpec(size=416)
    for b in range(bins):
        seed = SEED + b
        rng = np.random.default_rng(seed)
        product = products[b % len(products)]
        others = [p for p in sorted(library.products) if p != product]
        distractors = [library[others[i]] for i in rng.choice(len(others), size=3, replace=False)]
        world = BinWorld(library[product], distractors, max_copies=6, camera=camera_spec, gripper=True, seed=seed, sensor=sensor)
        try:
            scene = world.scene(int(rng.integers(3, 7)), int(rng.integers(2, 4)), seed)
            world.set_guards(False)
            camera = PinholeCamera.from_record(scene.camera)
            mine = sorted((i for i in scene.instances if i.product_id == product and i.visible_fraction >= 0.5),
                          key=lambda i: -i.visible_fraction)
            depth = as_camera_depth(scene.depth)  # as a camera's 16-bit frame holds it
            started = time.perf_counter()  # an order's planning: the frame once (holes, plane), then up to three detections
            frame = DepthFrame.from_depth(depth, camera)
            for instance in mine[:3]:
                planners["learnt"].choose(frame, instance.bbox)
            plan_ms.append(1000 * (time.perf_counter() - started))
            for instance in mine:
                for name, planner in planners.items():
                    choice, tips = plan_grasp(planner, frame, instance.bbox, scene, camera_spec)
                    success = False
                    if tips is not None:
                        world.restore(scene.state)
                        with trial_timestep(world.model):
                            success = lift_test(world, instance.slot, tips, choice.chosen.yaw, choice.chosen.top, carry=True)
                    outcomes[name].append(success)
                    by_product.setdefault(product, {n: [] for n in POLICIES})[name].append(success)
        finally:
            world.close()
        print(f"{sensor_name} bin {b + 1}/{bins}: " + ", ".join(f"{n} {np.mean(v):.0%}" for n, v in outcomes.items() if v), flush=True)
    return {"sensor": sensor_name, "bins": bins, "instances": len(outcomes["fixed"]), "products": products,
            "top1_success": {n: round(float(np.mean(v)), 4) for n, v in outcomes.items()},
            "top1_by_product": {p: {n: f"{sum(v)}/{len(v)}" for n, v in groups.items()} for p, groups in sorted(by_product.items())},
            "plan_ms_median": round(float(np.median(plan_ms)), 1), "plan_ms_p95": round(float(np.percentile(plan_ms, 95)), 1)}


def evaluate(data: list[Path], bins: int) -> None:
    import json

    import torch

    from binpick.grasping.quality import SHIPPED, GraspQuality

    torch.set_num_threads(2)
    meta = GraspQuality.load(SHIPPED).meta
    previous = json.loads((_common.RESULTS / "grasp.json").read_text()) if (_common.RESULTS / "grasp.json").is_file() else {}
    by_sensor = {sensor: top1(bins, sensor) for sensor in ("perfect", "realistic")}
    result = {"weights": str(SHIPPED.relative_to(_common.ROOT)), "training": {k: meta.get(k) for k in ("train_trials", "train_success_rate", "val_auc", "epoch", "run", "data")},
              "held_out_trials": held_out_auc(data[0]), "held_out_trials_by_data": {path.name: held_out_auc(path) for path in data},
              **by_sensor["perfect"],
              "top1_success_by_sensor": {sensor: row["top1_success"] for sensor, row in by_sensor.items()},
              "top1_by_sensor": by_sensor, "targets": {"plan_ms_median": 100, "realistic_learnt": 0.8, "realistic_below_perfect": 0.05}}
    if "pickability" in previous:
        result["pickability"] = previous["pickability"]
    result["peak_rss_mib"] = round(_common.peak_rss_mib(), 1)
    result["load_average"] = round(os.getloadavg()[0], 2)
    _common.write_result("grasp", result)
    _common.write_section_of("grasp", section_grasp, "grasp.json")
    print({k: result[k] for k in ("top1_success", "plan_ms_median")}, result["held_out_trials"]["roc_auc"], flush=True)


def section_grasp(result: dict) -> str:
    """The grasp section of docs/RESULTS.md (policies, the quality model, pickability under the learnt policy),
    from results/grasp.json."""
    trials = result["held_out_trials"]
    lines = ["## Grasp policies and the grasp-quality model (Dex-Net 2.0 / GG-CNN's setting)", "",
             f"`python experiments/grasp.py eval --bins {result['bins']}` → `results/grasp.json`. Candidates come from depth "
             "alone (`binpick.grasping`), made ready once per frame (holes inpainted, noise smoothed, the support plane fitted): the "
             "instance's region of a watershed of heights above that plane that matches its box, 12 yaws over 180° and across its "
             "principal minor axis, the jaws centred on its extent and shifted 1 cm either way along the closing direction, "
             "fingertips as deep as the fingers have room for (at most 7 cm under the top, at least 1.5 cm under its middle; lifted "
             "clear of a neighbour where that keeps them 1.5 cm under the top); a candidate is rejected when it is wider than the "
             "open jaws or a finger's footprint meets a surface more than 3 cm above the tips, judged on the pixels the sensor read. "
             "Realistic depth: the same bins seen by the `realistic` sensor (holes, noise, a camera tilted up to 20°, a tote up to "
             "3° off level). Top-1 success: "
             "each policy's first choice, executed from the same saved state, must lift, hold and carry the product at the "
             "pick pipeline's speed. Policies: **fixed** (jaws along y, the grasp before the planner existed; on realistic depth "
             "its candidate's fingertips, the old grasp point needing a camera straight down), **analytic** (minor axis where "
             "elongated, then clearance), **learnt** (a GQ-CNN-style network on a 32×32 height map in the grasp's frame "
             f"plus width, depth and clearance; {result['training'].get('train_trials')} simulated training trials on realistic "
             "and perfect depth).", "",
             "| measure | fixed | analytic | learnt |", "|---|---|---|---|",
             *[f"| top-1 success, held-out products, {sensor} depth ({row['instances']} instances in {row['bins']} bins) | "
               f"{row['top1_success']['fixed']:.0%} | {row['top1_success']['analytic']:.0%} | {row['top1_success']['learnt']:.0%} |"
               for sensor, row in result.get("top1_by_sensor", {"perfect": result}).items()],
             *[f"| ROC AUC on held-out products' trials, `{name}` ({row['trials']} trials, {row['success_rate']:.0%} succeeded) | – | "
               f"{row['roc_auc']['analytic']:.3f} | {row['roc_auc']['learnt']:.3f} |"
               for name, row in result.get("held_out_trials_by_data", {"trials": trials}).items()], "",
             f"Planning per order (the depth frame, candidates and scores for three detections), 2 cores: median "
             f"**{result['plan_ms_median']} ms**, p95 {result['plan_ms_p95']} ms on perfect depth"
             + (f", {result['top1_by_sensor']['realistic']['plan_ms_median']} / {result['top1_by_sensor']['realistic']['plan_ms_p95']} ms "
                "on realistic depth" if "top1_by_sensor" in result else "") + ". "
             f"Held-out products: {', '.join(result['products'])}. Per product (fixed / analytic / learnt): "
             + "; ".join(f"{p.split('/')[-1]} {g['fixed']} / {g['analytic']} / {g['learnt']}" for p, g in result["top1_by_product"].items())
             + f". Peak RSS {result['peak_rss_mib']:.0f} MiB."]
    if "pickability" in result:
        p = result["pickability"]

        def cell(label: str, split: str, key: str) -> str:
            value = p[label][split].get(key)
            return "–" if value is None else f"{value:.3f}"

        lines += ["", "Pickability under the learnt policy (thesis §6.3; measured with the grasp planner and model before depth "
                  "as sensors give it, whose learnt policy labelled `bins_learnt`): the shipped photo-query ROD, trained on Policy 1 "
                  "(jaws along y) labels, fine-tuned 4 epochs on bins whose instances the learnt policy tried "
                  f"(`python experiments/grasp.py pickability`: trained on `{p.get('train')}`, {p.get('train_scenes')} scenes; "
                  f"measured on the val and test scenes of `{p['data']}`). AP50 against the instances the learnt "
                  "policy picks (higher is better) and against those it cannot pick (lower: the detector prefers what the "
                  "policy can pick):", "",
                  "| detector | seen: AP50 pickable | unpickable | all copies | AUC | first on pickable | held out: AP50 pickable | "
                  "unpickable | all copies | AUC | first on pickable |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        named = [("before", "shipped (Policy 1 labels)"), ("after", "fine-tuned on learnt-policy labels")]
        heads = [label for label in p if label.startswith("head_")]

        def sees(head: dict) -> str:
            return "the window and the shop photo" if head["query"] else "the window alone"

        for label in heads:
            named.append((label, f"fine-tuned + a pickability head on learnt-policy labels that sees {sees(p[label])}"
                                 f"{' (shipped)' if p[label]['shipped'] else ''}"))
        for label, name in named:
            lines.append(f"| {name} | {cell(label, 'seen', 'ap50')} | {cell(label, 'seen', 'ap50_unpickable')} | "
                         f"{cell(label, 'seen', 'ap50_all')} | {cell(label, 'seen', 'pickable_auc')} | {cell(label, 'seen', 'first_on_pickable')} | "
                         f"{cell(label, 'held_out', 'ap50')} | {cell(label, 'held_out', 'ap50_unpickable')} | {cell(label, 'held_out', 'ap50_all')} | "
                         f"{cell(label, 'held_out', 'pickable_auc')} | {cell(label, 'held_out', 'first_on_pickable')} |")
        for label in heads:
            h, after = p[label], p["after"]
            change = ", ".join(f"{name} AP50 {after[split]['ap50']:.3f} → {h[split]['ap50']:.3f}, unpickable "
                               f"{after[split]['ap50_unpickable']:.3f} → {h[split]['ap50_unpickable']:.3f}"
                               for split, name in (("seen", "seen"), ("held_out", "held out")))
            lines += ["", f"The head that sees {sees(h)} (run "
                          f"`{h['run']}`, `{h['weights']}`; proposals {h['proposals']}, distractors {h['distractors']}; "
                          f"{'shipped' if h['shipped'] else 'not shipped'}), against the fine-tune alone: {change}."]
        lines += ["", "AUC: per labelled copy, the best score of a detection on it (0 if none), pickable against unpickable "
                  "copies: how far the detector prefers what the policy can pick, apart from how well it finds the product at "
                  "all; AP50 on the unpickable copies rises with both. First on pickable: in the bins holding both pickable and "
                  f"unpickable copies ({p['after']['seen'].get('contested_bins')} seen, {p['after']['held_out'].get('contested_bins')} "
                  "held out), the share whose top detection is a pickable copy (the copy a picker tries first; the "
                  "rest land on unpickable copies or on nothing). "
                  "The labels come from trials with the tote's drop guards off, as the pipeline grasps "
                  "(`warehouse.dataset.trial_ready`); with them on, 45% of instances were labelled pickable instead of 68%."]
    return "\n".join(lines)


def pickability(heads_given: list[str] | None = None) -> None:
    """Thesis §6.3 with binpick's new policy: the shipped photo-query ROD (trained on Policy 1 labels)
    fine-tuned on pickability by the learnt grasp policy; AP against the instances it can pick and
    against those it cannot, before and after, on seen (val) and held-out (test) products. The
    fine-tuned weights are its run's (``runs/grasp/rod_finetune_photo_learnt``, finished here if it
    stopped) or, without that folder, the shipped ``rod_photo_learnt_tiny_320`` (that run's weights in
    float16; its head switched off). ``heads_given``: runs of ``configs/detection/pickability_photo_learnt.yaml``
    (or ``newest``): the fine-tuned detector with a second look at each detection, a row each."""
    import json

    import torch
    import yaml

    from binpick.detection.config import DetectConfig
    from binpick.core.config import load_config
    from binpick.detection.train import DetectorTrainer
    from binpick.cli.terminal import RichCallback

    torch.set_num_threads(2)
    name = "rod_finetune_photo_learnt"
    from binpick.detection.detector import PICKING, shipped_weights

    picking = shipped_weights(PICKING)
    folder = run_folder(RUNS, name)
    if folder is None:
        run_dir, weights = None, picking
    else:
        if finished(folder):
            run_dir = folder
        else:
            trainer = DetectorTrainer.resume(folder) if folder is not None else DetectorTrainer.new(
                load_config(DetectConfig, _common.recipe(name)[0]), RUNS)
            with RichCallback() as callback:
                trainer.run(callback)
            run_dir = trainer.run_dir
        weights = run_dir / ("best.safetensors" if (run_dir / "best.safetensors").is_file() else "model.safetensors")
    from rod import collect_on, keep  # the detector benchmark's evaluation (pycocotools, same tasks)

    from binpick.detection.evaluate import copy_scores, first_choices, summarise
    from binpick.detection.train import detector_detect
    from binpick.detection.weights_file import load_detector
    from binpick.grasping.training import roc_auc

    def measured(model, split: str) -> dict:
        tasks = collect_on(detector_detect(model), data, split, "pickable:learnt", model.image_size, query="photo",
                           framed=model.spec.frames_photos, depth=model.spec.reads_depth)
        labels, scores = copy_scores(tasks)
        return keep(summarise(tasks, model.image_size)) | {
            "pickable_auc": round(roc_auc(labels, scores), 4), "copies": len(labels), "pickable_share": round(float(labels.mean()), 4),
            "mean_score_pickable": round(float(scores[labels == 1].mean()), 4),
            "mean_score_unpickable": round(float(scores[labels == 0].mean()), 4)} | first_choices(tasks)

    data = _common.ROOT / "runs" / "data" / "bins_learnt"
    shipped = shipped_weights("rod_photo_tiny_320")
    rows = {}
    measure = [("before", shipped), ("after", weights)]
    heads = {}  # row label -> (run folder, weights file)
    for given in heads_given or []:
        head_dir = run_folder(RUNS, "pickability_photo_learnt") if given == "newest" else Path(given)
        found = [head_dir / n for n in ("model.safetensors", "best.safetensors") if head_dir is not None and (head_dir / n).is_file()]
        if not found:
            raise SystemExit(f"no run of configs/detection/pickability_photo_learnt.yaml with weights at {given}: "
                             "binpick detect pickability configs/detection/pickability_photo_learnt.yaml --runs runs/grasp")
        label = "head_" + head_dir.resolve().parent.name  # the run's config name
        heads[label] = (head_dir.resolve(), found[0])  # the finished run's head, or the best so far of one stopped
        measure.append((label, found[0]))
    for label, path in measure:
        model = load_detector(path)
        if label == "after" and model.pickability is not None:
            model = model.without_pickability()  # the fine-tune alone (the shipped file also holds its head, a row below)
        rows[label] = {split: measured(model, split) for split in ("val", "test")}
        print(label, json.dumps({s: {k: rows[label][s][k] for k in ("ap50", "ap50_unpickable", "pickable_auc", "first_on_pickable")} for s in rows[label]}),
              flush=True)
    path = _common.RESULTS / "grasp.json"
    result = json.loads(path.read_text())
    earlier = result.get("pickability") or {}
    if run_dir is not None:
        train = (yaml.safe_load((run_dir / "config.yaml").read_text()) or {}).get("data", {}).get("train")
        train_facts = {"train": train, "train_scenes": len(json.loads((_common.ROOT / train).read_text())["images"]),
                       "run": str(run_dir.relative_to(_common.ROOT))}
    else:  # the shipped fine-tune: its run's facts as recorded when it was measured from the run
        train_facts = {k: earlier[k] for k in ("train", "train_scenes", "run") if k in earlier}
    result["pickability"] = {"targets": "pickable:learnt", "data": "runs/data/bins_learnt", **train_facts,
                             "after_weights": str(weights.relative_to(_common.ROOT)),
                             **{label: {"seen": rows[label]["val"], "held_out": rows[label]["test"]} for label in rows}}
    import hashlib

    def digest(file: Path) -> str:
        return hashlib.sha256(file.read_bytes()).hexdigest()

    picking_digest = digest(picking)
    for label, (head_dir, file) in heads.items():
        config = yaml.safe_load((head_dir / "config.yaml").read_text()) or {}
        result["pickability"][label] |= {"run": str(head_dir.relative_to(_common.ROOT)), "weights": file.name,
                                         "query": bool(config.get("query")), "distractors": bool(config.get("distractors")),
                                         "proposals": config.get("proposals"), "train": config.get("train"),
                                         "shipped": digest(file) == picking_digest}
    _common.write_result("grasp", {k: v for k, v in result.items() if k not in ("benchmark", "machine")})
    _common.write_section_of("grasp", section_grasp, "grasp.json")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("phase", choices=["train", "eval", "pickability", "suction", "jaws", "calibrate", "tools"])
    parser.add_argument("--data", type=Path, action="append", help="eval: data sets of grasp trials whose held-out "
                                                                  "products' trials to score (repeatable; default: the realistic one)")
    parser.add_argument("--bins", type=int, default=40)
    parser.add_argument("--head", action="append", help="pickability: also the fine-tuned detector with a pickability head, a run "
                                                        "of configs/detection/pickability_photo_learnt.yaml (a folder, or 'newest' under runs/grasp); repeatable")
    args = parser.parse_args()
    os.chdir(_common.ROOT)
    both = [_common.ROOT / "runs" / "data" / "grasp_trials_both_realistic"]
    if args.phase == "train":
        train()
    elif args.phase == "pickability":
        pickability(args.head)
    elif args.phase == "suction":
        train_and_ship("suction", "suction_quality")
    elif args.phase == "jaws":
        train_and_ship("jaws", "grasp_quality_boxes")
    elif args.phase == "calibrate":
        calibrate_jaws(args.data or both)
    elif args.phase == "tools":
        import json

        path = _common.RESULTS / "grasp.json"
        result = json.loads(path.read_text()) if path.is_file() else {}
        for key in ("benchmark", "machine", "provenance"):
            result.pop(key, None)
        result["held_out_trials_by_tool"] = {"data": [str(d.relative_to(_common.ROOT)) for d in (args.data or both)],
                                             **tool_trials(args.data or both)}
        _common.write_result("grasp", result)
        plot_reliability(result["held_out_trials_by_tool"], _common.ROOT / "docs" / "img" / "grasp_reliability.png")
        _common.write_section_of("grasp_tools", section_grasp_tools, "grasp.json")
        print(json.dumps(result["held_out_trials_by_tool"], indent=1)[:3000], flush=True)
    else:
        evaluate(args.data or [DATA], args.bins)


if __name__ == "__main__":
    main()


def plan_grasp(planner, frame, box, scene, overhead):
    """The planner's grasp for a detection and its fingertips' position (world xyz). The fixed policy
    keeps the grasp point and depth it had before the planner existed, so its rows stay comparable,
    where that grasp point can be had (perfect depth from a camera straight above the tote)."""
    from binpick.grasping import GraspPolicyName
    from binpick.warehouse.grasping import fixed_policy_tips, legacy_view

    choice = planner.choose(frame, box)
    if choice.chosen is None:
        return choice, None
    if planner.policy is GraspPolicyName.FIXED and legacy_view(scene):
        return choice, fixed_policy_tips(box, scene.depth, overhead)
    return choice, choice.chosen.position

"""Generate warehouse bin data sets: COCO-format annotations of every instance, which ones each
grasp policy can pick (trial grasps from the saved scene state), shop photos and query crops.

Layout of a data set folder::

    dataset.json            what was asked for (validated on resume) and the product list
    images/000123.png       overhead RGB;  depth/000123.png  depth in millimetres (uint16)
    scenes/000123.json      one scene's annotations: written last, atomically, so a scene exists
                            exactly when its shard does and a killed run resumes without losing or
                            duplicating scenes
    photos/<product>.png    shop photos (external conditioning, §6.3)
    queries/000123.png      crop of the query instance (the in-image query of §5.3)
    annotations.json, annotations_<split>.json    COCO files, merged from the shards at the end
    CARD.md                 the data-set card with counts

COCO categories are products (a category is what "repeated" means); their ``supercategory`` is the
product category used for zero-shot splits. Each annotation carries ``visible_fraction``,
``is_target``, ``is_query`` and ``pickable`` {policy: true/false} for the target product's instances.
"""

from __future__ import annotations

import json
import os
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from binpick.errors import ConfigError, InputFileError
from binpick.files import atomic_write_json, atomic_write_text, read_json_object, require_fields
from binpick.runs import SILENT, RunCallback
from binpick.sim.products import ProductLibrary, default_library, load_products

FORMAT = "binpick-bins-1"


@dataclass(frozen=True)
class GenerateConfig:
    out: str
    scenes: int = 100
    policies: list[str] = field(default_factory=lambda: ["x", "y"])  # empty: no labels
    grasp_trials: int = 0  # per visible instance: random grasp candidates from depth, executed (grasp-quality data)
    label_trials: int = 1  # grasps per instance and policy for its pickability label: the policy's own, then jittered (majority)
    label_jitter: float = 0.002  # m: how far the extra label grasps move the jaws' centre (below a pixel of the camera)
    workers: int = 2
    image_size: int = 416
    copies: tuple[int, int] = (2, 8)  # K instances of the target product
    distractors: tuple[int, int] = (0, 3)  # other products in the bin
    held_out_categories: list[str] = field(default_factory=list)  # zero-shot test split
    targets: list[str] = field(default_factory=list)  # product ids or categories to order (default: all)
    val_fraction: float = 0.1
    split_rule: str = "even"  # which worlds go to val: "even" (every 1/val_fraction-th, stable as a set grows) or "random"
    scenes_per_world: int = 8  # scenes made from one compiled model (compiling + renderers ≈ 1 s)
    randomise: bool = False  # lighting, table and tote colours per world (before domains existed)
    domain: str = "default"  # default | random | shifted | a domain YAML file (binpick.sim.domain)
    sensor: str = "perfect"  # perfect | realistic | a sensor YAML file (binpick.sim.sensor): the depth camera's faults
    address: str | None = None  # a Ray cluster (HOST:PORT) or "local" (Ray on this machine): scene workers as Ray tasks
    products: str | None = None  # a user's products YAML (added to the built-in library)
    only_products: bool = False  # use only the user's products
    photo_size: int = 256
    photo_views: int = 0  # randomised studio photos per product besides the canonical one (photos/<product>/<k>.png)
    seed: int = 0

    def __post_init__(self) -> None:
        from binpick.config import check_range

        check_range("scenes", self.scenes, 1, 10_000_000, integer=True)
        check_range("workers", self.workers, 1, 256, integer=True)
        check_range("grasp_trials", self.grasp_trials, 0, 100, integer=True)
        check_range("label_trials", self.label_trials, 1, 25, integer=True)
        check_range("label_jitter", self.label_jitter, 0.0, 0.02)
        check_range("image_size", self.image_size, 32, 2048, integer=True)
        check_range("photo_views", self.photo_views, 0, 64, integer=True)
        check_range("scenes_per_world", self.scenes_per_world, 1, 1000, integer=True)
        check_range("val_fraction", self.val_fraction, 0.0, 1.0)
        from binpick.config import check_choice

        check_choice("split_rule", self.split_rule, ("even", "random"))
        object.__setattr__(self, "copies", tuple(self.copies))  # frozen: normalised once, here
        object.__setattr__(self, "distractors", tuple(self.distractors))
        if not 1 <= self.copies[0] <= self.copies[1] <= 16:
            raise ConfigError(f"copies must be a range within 1..16, got {self.copies}")
        if not 0 <= self.distractors[0] <= self.distractors[1] <= 8:
            raise ConfigError(f"distractors must be a range within 0..8, got {self.distractors}")
        from binpick.sim.domain import load_domain

        object.__setattr__(self, "_domain", load_domain(self.domain))  # a bad name or file: one line, now
        from binpick.sim.sensor import load_sensor

        object.__setattr__(self, "_sensor", load_sensor(self.sensor))
        if self.address not in (None, "local"):
            from binpick.cluster import check_ray_address

            check_ray_address(self.address)
        from binpick.warehouse.policies import check_policies

        check_policies(self.policies)

    def comparable(self) -> dict[str, Any]:
        """What must match for a resume to add to the same data set (not scenes or workers)."""
        from binpick.sim.domain import domain_dict

        data = asdict(self)
        for key in ("out", "scenes", "workers", "address"):
            data.pop(key)
        data["copies"], data["distractors"] = list(self.copies), list(self.distractors)
        if not self.photo_views:  # data sets made before photo views resume as they were
            data.pop("photo_views")
        data["domain_values"] = domain_dict(self.domain_config)  # so an edited domain file is noticed on resume
        if self.sensor_config.realistic:  # perfect depth adds nothing: data sets made before sensors resume as they were
            from binpick.sim.sensor import sensor_dict

            data["sensor_values"] = sensor_dict(self.sensor_config)
        else:
            data.pop("sensor")
        return data

    @property
    def domain_config(self):
        """The :class:`binpick.sim.domain.DomainConfig` that ``domain`` names (loaded once)."""
        return self._domain

    @property
    def sensor_config(self):
        """The :class:`binpick.sim.sensor.SensorConfig` that ``sensor`` names (loaded once)."""
        return self._sensor


_LIBRARIES: dict[str, ProductLibrary] = {}


def build_library(config: GenerateConfig) -> ProductLibrary:
    """The products of a data set (cached per process: workers build it once, not once per world)."""
    key = json.dumps([config.seed, config.products, config.only_products, sorted(config.held_out_categories)])
    if key not in _LIBRARIES:
        _LIBRARIES[key] = _build_library(config)
    return _LIBRARIES[key]


def _build_library(config: GenerateConfig) -> ProductLibrary:
    library = ProductLibrary() if config.only_products else default_library(seed=config.seed)
    if config.products:
        library = load_products(config.products, library)
    if config.only_products and not config.products:
        raise ConfigError("only_products needs --products YAML")
    library.in_categories(config.held_out_categories)  # names an unknown category in one line
    for name in config.targets:
        if name not in library.products and name not in library.categories:
            raise ConfigError(f"unknown product or category {name!r} in targets; categories: {', '.join(library.categories)}")
    return library


def target_products(config: GenerateConfig, library: ProductLibrary) -> list[str]:
    """Products that can be the ordered (repeated) one: all, or those named in ``targets``."""
    if not config.targets:
        return sorted(library.products)
    return sorted(p.id for p in library if p.id in config.targets or p.category in config.targets)


# ---------------------------------------------------------------------- the output folder
def prepare_output(config: GenerateConfig, library: ProductLibrary) -> Path:
    """Create the folder, or check that an existing one is this same data set (then it resumes)."""
    out = Path(config.out)
    manifest = out / "dataset.json"
    if out.exists() and not out.is_dir():
        raise ConfigError(f"output {str(out)!r} is a file, not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not manifest.is_file():
            raise ConfigError(f"output folder {str(out)!r} is not empty and is not a binpick data set; choose another")
        existing = open_dataset(out)
        # settings added later take their defaults; a set made before split_rule existed split at random
        stored = {**GenerateConfig(out="").comparable(), "split_rule": "random", **existing["config"]}
        asked = config.comparable()
        more_views = False
        if not (config.domain_config.random_products and not config.products):
            # a fixed library's studio photos are per product, not per scene: a resume may add some, and
            # one that asks for fewer keeps those there (randomised worlds make theirs with their scenes)
            views = max(stored.get("photo_views", 0), asked.get("photo_views", 0))
            more_views = views > stored.get("photo_views", 0)
            stored, asked = stored | {"photo_views": views}, asked | {"photo_views": views}
        if existing.get("format") != FORMAT or stored != asked:
            raise ConfigError(f"{str(out)!r} holds a data set made with other settings; choose another folder")
        if config.scenes > (existing.get("scenes") or 0) or more_views:  # what a resume finishes
            atomic_write_json(manifest, existing | {"scenes": max(config.scenes, existing.get("scenes") or 0),
                                                    "config": stored}, indent=None)
        return out
    try:
        for sub in ("images", "depth", "scenes", "photos", "queries"):
            (out / sub).mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ConfigError(f"cannot write to {str(out)!r}: {error.strerror}") from None
    products = [{"id": p.id, "category": p.category} for p in library]
    manifest_data = {"format": FORMAT, "config": config.comparable(), "products": products, "scenes": config.scenes}
    atomic_write_json(manifest, manifest_data, indent=None)
    return out


def _write_png(path: Path, array: np.ndarray) -> None:
    from binpick.files import atomic_write_bytes

    atomic_write_bytes(path, _png_bytes(array))


# ---------------------------------------------------------------------- what each world holds
def random_world_products(config: GenerateConfig, library: ProductLibrary, world: int) -> list:
    """A randomised world's own products (target first, then distractors), made for it alone: a
    domain with ``random_products`` sees thousands of distinct products over a data set."""
    from binpick.sim.products import random_product

    domain = config.domain_config
    rng = np.random.default_rng([config.seed, world, 7])
    seen = [p for p in library if p.category not in config.held_out_categories]
    return [random_product(f"random/{world:06d}_{k}", rng, seen, domain.textures, domain.product_scale)
            for k in range(1 + config.distractors[1])]


def world_plan(config: GenerateConfig, library: ProductLibrary, world: int) -> tuple[str, list[str], str]:
    """The target product, distractor products and split of world ``world`` (deterministic)."""
    if config.domain_config.random_products:
        ids = [p.id for p in random_world_products(config, library, world)]
        return ids[0], ids[1:], "val" if val_world(world, config.val_fraction) else "train"
    rng = np.random.default_rng([config.seed, world])
    candidates = target_products(config, library)
    target = candidates[rng.integers(len(candidates))]
    others = [p for p in sorted(library.products) if p != target]
    count = min(config.distractors[1], len(others))
    distractors = [others[i] for i in rng.choice(len(others), size=count, replace=False)] if count else []
    category = library[target].category
    if category in config.held_out_categories:
        split = "test"
    elif config.split_rule == "random":  # data sets made before binpick 0.2 (bins_2000 among them)
        split = "val" if rng.uniform() < config.val_fraction else "train"
    else:
        split = "val" if val_world(world, config.val_fraction) else "train"
    return target, distractors, split


def val_world(world: int, fraction: float) -> bool:
    """World ``world`` goes to val when the running count of ``fraction`` per world passes a whole
    number (half a step early): exactly that share of worlds, spread evenly, the first already at
    world 1 for fraction 0.25 or world 4 for 0.1, and a world keeps its split when a set grows."""
    return int((world + 1) * fraction + 0.5) > int(world * fraction + 0.5)


def missing_scenes(config: GenerateConfig, world: int, out: Path) -> list[int]:
    """Indices of the world's scenes that have no scene file yet (a scene exists once its JSON does)."""
    first = world * config.scenes_per_world
    return [i for i in range(first, min(first + config.scenes_per_world, config.scenes))
            if not (out / "scenes" / f"{i:06d}.json").is_file()]


def generate_world(config: GenerateConfig, world: int, out: Path) -> list[dict[str, Any]]:
    """Make and write the missing scenes of one world; returns their records (for progress)."""
    records = []
    for files, record in world_scenes(config, world, missing_scenes(config, world, out)):
        write_scene(out, files, record)
        records.append(record)
    return records


def write_scene(out: Path, files: dict[str, bytes], record: dict[str, Any]) -> None:
    """A scene's images first, its JSON last and atomically: the scene now exists (resume relies on it)."""
    from binpick.files import atomic_write_bytes, inside

    for name, data in files.items():  # names a worker sent: written only inside the data set
        target = inside(out, name, "scene file")
        if name.startswith("photos/") and target.is_file():
            continue
        atomic_write_bytes(target, data)
    atomic_write_json(out / "scenes" / f"{record['index']:06d}.json", record, indent=None)


def world_sim(config: GenerateConfig, world: int, library: ProductLibrary | None = None, gripper: bool | None = None):
    """``(sim, products, split)`` of one world: its compiled bin with the ordered product first. The
    seed comes from ``config.seed`` and ``world``, so the world is the same wherever it is rebuilt."""
    from binpick.sim.bin_scene import BinWorld
    from binpick.sim.mjcf import CameraSpec

    library = library or build_library(config)
    target, distractors, split = world_plan(config, library, world)
    if config.domain_config.random_products:
        own = {p.id: p for p in random_world_products(config, library, world)}
        products = [own[target]] + [own[d] for d in distractors]
    else:
        products = [library[target]] + [library[d] for d in distractors]
    gripper = (bool(config.policies) or config.grasp_trials > 0) if gripper is None else gripper
    sim = BinWorld(products[0], products[1:], max_copies=config.copies[1],
                   camera=CameraSpec(size=config.image_size), randomise_lighting=config.randomise,
                   gripper=gripper, seed=config.seed * 1_000_003 + world, domain=config.domain_config,
                   sensor=config.sensor_config)
    return sim, products, split


def world_scene(sim, config: GenerateConfig, world: int, index: int):
    """``(scene, rng)``: scene ``index`` of a world's sim, and the generator it drew from (labelling
    goes on drawing from it)."""
    rng = np.random.default_rng([config.seed, world, index])
    copies = int(rng.integers(config.copies[0], config.copies[1] + 1))
    extra = int(rng.integers(config.distractors[0], config.distractors[1] + 1))
    return sim.scene(copies, extra, seed=int(rng.integers(2**31))), rng


def world_scenes(config: GenerateConfig, world: int, indices: list[int]):
    """Yield ``(files, record)`` for scenes ``indices`` of one world: encoded images by relative path
    and the scene's annotations. Writes nothing, so Ray tasks on other machines can run it."""
    from binpick.warehouse.policies import make_policies

    if not indices:
        return
    sim, products, split = world_sim(config, world)
    policies = make_policies(config.policies)
    try:
        photo = {}
        if config.domain_config.random_products:  # a world's own product has its own shop photos
            photo = {path: _png_bytes(image) for path, image in product_photos(config, products[0], world)}
        for index in indices:
            scene, rng = world_scene(sim, config, world, index)
            record = scene_record(scene, index, split, config)
            label_pickability(sim, scene, record, policies, rng, config.label_trials, config.label_jitter)
            if config.grasp_trials:
                record_grasp_trials(sim, scene, record, config.grasp_trials, rng)
            files = {**photo, f"images/{index:06d}.png": _png_bytes(scene.rgb),
                     f"depth/{index:06d}.png": _png_bytes(np.clip(scene.depth * 1000.0, 0, 65535).astype(np.uint16))}
            query = next((a for a in record["annotations"] if a["is_query"]), None)
            if query is not None:
                x, y, w, h = (int(round(v)) for v in query["bbox"])
                files[f"queries/{index:06d}.png"] = _png_bytes(scene.rgb[y:y + h, x:x + w])
            yield files, record
    finally:
        sim.close()


def _png_bytes(array: np.ndarray) -> bytes:
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, format="PNG", compress_level=1)  # fast; PNG stays lossless
    return buffer.getvalue()


def scene_record(scene, index: int, split: str, config: GenerateConfig) -> dict[str, Any]:
    annotations = [{"slot": i.slot, "product": i.product_id, "category": i.category, "is_target": i.is_target,
                    "bbox": list(i.bbox), "area": i.area, "visible_fraction": round(i.visible_fraction, 4),
                    "position": list(i.position), "pickable": {}, "is_query": False} for i in scene.instances]
    return {"index": index, "file_name": f"images/{index:06d}.png", "depth_file": f"depth/{index:06d}.png",
            "width": config.image_size, "height": config.image_size, "split": split, "target": scene.target_id,
            "seed": scene.seed, "annotations": annotations, "picked_by": None, "camera": scene.camera,
            **({"sensor": scene.sensor} if scene.sensor else {})}


def trial_ready(sim) -> None:
    """Trials run as the pick pipeline grasps: with the tote's invisible drop guards off. The guards
    keep products in the tote while a scene settles, but a trial's carry takes the product out over
    the walls. With them on, the learnt policy's trials on fully visible instances lifted box_00 64%,
    cylinder_04 68% and shape_940 52% of the time, against 82%, 82% and 64% with them off, which is
    what the pipeline places (82%, 82%, 61%): labels and grasp trials counted grasps the robot makes
    as failures, most of them of tall products and of instances near a wall."""
    sim.set_guards(False)


def label_offsets(trials: int, jitter: float, rng: np.random.Generator) -> list[tuple[float, float]]:
    """Where a label's grasps put the jaws' centre, relative to the policy's choice: the policy's own
    grasp, then a cross at ``jitter``, then random points within it."""
    cross = [(0.0, 0.0), (jitter, 0.0), (-jitter, 0.0), (0.0, jitter), (0.0, -jitter)]
    extra = [tuple(v) for v in rng.uniform(-jitter, jitter, size=(max(0, trials - len(cross)), 2))]
    return (cross + extra)[:trials]


def grasp_outcomes(sim, state, policy, slot: int, offsets: list) -> list[bool]:
    """Whether ``policy``'s grasp on instance ``slot`` held, from the saved ``state``, once per jaws'
    offset (None: the plain call, so a user's policy without ``offset`` still labels data)."""
    held = []
    for offset in offsets:
        sim.restore(state)
        held.append(bool(policy.attempt(sim, slot) if offset is None else policy.attempt(sim, slot, offset)))
    return held


def label_pickability(sim, scene, record: dict[str, Any], policies, rng: np.random.Generator,
                      trials: int = 1, jitter: float = 0.002) -> None:
    """Thesis §5.4.4: try target instances in random order until one is picked (the query); then,
    from the saved scene state, attempt every remaining instance — with each policy.

    With ``trials`` > 1 each instance gets that many grasps per policy, the jaws' centre moved by
    up to ``jitter``: the label is the majority and ``pickable_rate`` the share that held. One grasp's
    outcome is not quite a property an image shows: moving Policy y's jaws by 2 mm (under a pixel)
    changed it for 18 of 168 target instances of binpick's default bins (11 of the 84 that held, 7 of
    the 84 that did not; 15 worlds, 2 scenes each: ``benchmarks/label_noise.py``).
    """
    targets = [a for a in record["annotations"] if a["is_target"]]
    if not targets:
        return
    trial_ready(sim)
    order = [targets[i] for i in rng.permutation(len(targets))]
    offsets = label_offsets(trials, jitter, rng) if trials > 1 else [None]
    for policy in policies:
        if hasattr(policy, "prepare"):  # planned grasps read the scene's depth once
            policy.prepare(scene)
        for annotation in order:
            held = grasp_outcomes(sim, scene.state, policy, annotation["slot"], offsets)
            annotation["pickable"][policy.name] = sum(held) * 2 > len(held)
            if trials > 1:
                annotation.setdefault("pickable_rate", {})[policy.name] = round(sum(held) / len(held), 3)
    first_policy = policies[0].name if policies else None
    picked = next((a for a in order if first_policy and a["pickable"][first_policy]), None)
    query = picked or order[0]
    query["is_query"] = True
    record["picked_by"] = first_policy if picked is not None else None


TRIAL_OFFSET = 0.012  # random shifts of the jaws' centre (m) beside the even-squeeze positions
TRIAL_VISIBLE = 0.3  # instances less visible than this get no trials (depth shows too little of them)


def record_grasp_trials(sim, scene, record: dict[str, Any], trials: int, rng: np.random.Generator) -> None:
    """Grasp-quality data (Dex-Net 2.0's recipe, on binpick's bins): per visible instance, ``trials``
    candidates from depth alone (:func:`binpick.grasping.grasp_candidates`: all yaws, the even-squeeze
    centre and random shifts), three in four drawn among the feasible ones, each executed from the
    saved scene state; the outcome is whether that instance rose and stayed in the jaws through a
    carry at the pick pipeline's speed."""
    from binpick.grasping import DepthFrame, JawGripper, PinholeCamera, grasp_candidates
    from binpick.sim.gripper import lift_test, trial_timestep

    frame = DepthFrame.from_depth(scene.depth, PinholeCamera.from_record(scene.camera))
    trial_ready(sim)
    results = []
    for annotation in record["annotations"]:
        if annotation["visible_fraction"] < TRIAL_VISIBLE:
            continue
        offsets = rng.uniform(-TRIAL_OFFSET, TRIAL_OFFSET, size=(2, 2))
        _, candidates = grasp_candidates(frame, annotation["bbox"], JawGripper(), offsets=offsets)
        if not candidates:
            continue
        feasible = [c for c in candidates if c.rejected is None]
        for _ in range(trials):
            pool = feasible if feasible and rng.random() < 0.75 else candidates
            candidate = pool[int(rng.integers(len(pool)))]
            sim.restore(scene.state)
            with trial_timestep(sim.model):
                success = lift_test(sim, annotation["slot"], candidate.position, candidate.yaw, candidate.top, carry=True)
            results.append({"slot": annotation["slot"], "product": annotation["product"], **candidate.to_json(),
                            "top": round(candidate.top, 4), "support": round(candidate.support, 4), "success": success})
    record["grasp_trials"] = results


# ---------------------------------------------------------------------- the whole run
class DataGeneration:
    """A data set as a job (:class:`binpick.runs.Job`): ``DataGeneration.new(config)`` checks the
    products and the output folder, ``DataGeneration.resume(folder)`` continues a killed run with the
    settings it was started with, ``run(callback)`` makes the missing scenes, photos and COCO files."""

    def __init__(self, config: GenerateConfig) -> None:
        self.config = config
        self.library = build_library(config)
        self.run_dir = prepare_output(config, self.library)
        done = len(list((self.run_dir / "scenes").glob("*.json")))
        if done > config.scenes:
            raise ConfigError(f"{str(self.run_dir)!r} already holds {done} scenes, more than --scenes {config.scenes}: "
                              f"nothing to generate (give --scenes {done} or more to add to it, or another --out)")
        self.done = done

    @classmethod
    def new(cls, config: GenerateConfig, runs: Path | None = None) -> DataGeneration:
        """The data set goes to ``config.out`` (``runs`` is not used: a data set is its own folder)."""
        return cls(config)

    @classmethod
    def resume(cls, run_dir: Path, workers: int | None = None) -> DataGeneration:
        """Continue the data set in ``run_dir`` with the settings it was started with."""
        manifest = open_dataset(run_dir)
        settings = {k: v for k, v in manifest["config"].items() if k in GenerateConfig.__dataclass_fields__}
        scenes = manifest.get("scenes") or len(list(Path(run_dir, "scenes").glob("*.json")))
        config = GenerateConfig(**{**settings, "out": str(run_dir), "scenes": int(scenes),
                                   "workers": workers or GenerateConfig.workers})
        return cls(config)

    def run(self, callback: RunCallback = SILENT) -> dict[str, Any]:
        config, out = self.config, self.run_dir
        worlds = range(-(-config.scenes // config.scenes_per_world))
        with callback.task("scenes", config.scenes, min(self.done, config.scenes)) as task:
            if config.address is not None:
                self._run_on_ray(worlds, task)
            elif config.workers == 1:
                for world in worlds:
                    task.update(advance=len(generate_world(config, world, out)))
            else:
                import multiprocessing

                context = multiprocessing.get_context("spawn")  # MuJoCo/EGL contexts do not survive fork
                with context.Pool(config.workers) as pool:
                    for records in pool.imap_unordered(_generate_world_job, [(config, w, out) for w in worlds]):
                        task.update(advance=len(records))
        photos = write_photos(config, self.library, out, callback)
        return finalise(out) | {"photos": photos}


    def _run_on_ray(self, worlds: range, task) -> None:
        """Worlds as Ray tasks (this machine's private cluster, or one at ``address``): each task
        returns its scenes' files, which only this process writes, so a task lost with its machine
        is retried by Ray and a killed run resumes exactly as with local processes."""
        from binpick.cluster import start_ray

        config = self.config
        owns = start_ray(None if config.address == "local" else config.address, config.workers)
        import ray

        remote = ray.remote(num_cpus=1, max_retries=3)(_ray_world)
        try:
            pending = [remote.remote(config, world, indices) for world in worlds
                       if (indices := missing_scenes(config, world, self.run_dir))]
            while pending:
                ready, pending = ray.wait(pending, num_returns=1)
                for files, record in ray.get(ready[0]):
                    write_scene(self.run_dir, files, record)
                    task.update(advance=1)
        finally:
            if owns:
                ray.shutdown()


def _ray_world(config: GenerateConfig, world: int, indices: list[int]) -> list[tuple[dict[str, bytes], dict[str, Any]]]:
    os.environ.setdefault("MUJOCO_GL", "egl")
    return list(world_scenes(config, world, indices))


def generate(config: GenerateConfig, callback: RunCallback = SILENT) -> dict[str, Any]:
    """Generate (or finish) a data set: worlds in parallel processes, then COCO files and the card."""
    return DataGeneration.new(config).run(callback)


def _generate_world_job(arguments) -> list[dict[str, Any]]:
    os.environ.setdefault("MUJOCO_GL", "egl")
    return generate_world(*arguments)


def product_photos(config: GenerateConfig, product, world: int | None = None):
    """Yield ``(relative path, image)`` for a product's shop photos: the canonical one (the user's own
    photo where the products YAML gives one), then ``photo_views`` taken in randomised studios
    (:func:`binpick.sim.photos.random_photo_style`; drawn from the world's seed, or the product's id)."""
    from binpick.sim.photos import random_photo_style, shop_photo

    if product.photo is not None:
        from binpick.sim.products import read_photo

        yield f"photos/{product.name}.png", read_photo(product.photo)
    else:
        yield f"photos/{product.name}.png", shop_photo(product, config.photo_size)
    import zlib

    key = world if world is not None else zlib.crc32(product.id.encode())
    for k in range(config.photo_views):
        style = random_photo_style(np.random.default_rng([config.seed, key, 11, k]))
        yield f"photos/{product.name}/{k}.png", shop_photo(product, config.photo_size, style=style)


def write_photos(config: GenerateConfig, library: ProductLibrary, out: Path, callback: RunCallback = SILENT) -> int:
    if config.domain_config.random_products and not config.products:
        return len(list((out / "photos").glob("*.png")))  # each world wrote its own product's photos
    missing = [p for p in library if not (out / "photos" / f"{p.name}.png").is_file()
               or any(not (out / "photos" / p.name / f"{k}.png").is_file() for k in range(config.photo_views))]
    with callback.task("shop photos", len(missing)) as task:
        for product in missing:
            for path, image in product_photos(config, product):
                _write_png(out / path, image)
            task.update(advance=1)
    return len(library)


def open_dataset(data: Path) -> dict[str, Any]:
    """The manifest of a data-set folder, or one clear line saying why it is not one."""
    manifest = Path(data) / "dataset.json"
    if not manifest.is_file():
        raise ConfigError(f"{str(data)!r} is not a binpick data set (no dataset.json)")
    content = read_json_object(manifest, "data-set manifest", {"format": str, "config": dict, "products": list})
    if content["format"] != FORMAT:
        raise ConfigError(f"{manifest} is not a {FORMAT} data set")
    require_fields(content["config"], {"policies": list}, f"data-set manifest {str(manifest)!r}")
    if not all(isinstance(p, dict) and isinstance(p.get("id"), str) and isinstance(p.get("category"), str)
               for p in content["products"]):
        raise InputFileError(f"data-set manifest {str(manifest)!r} is damaged: a product has no id or category")
    return content


_RECORD = {"index": int, "file_name": str, "depth_file": str, "width": int, "height": int, "split": str, "target": str,
           "seed": int, "annotations": list, "picked_by": (str, type(None))}
_ANNOTATION = {"slot": int, "product": str, "is_target": bool, "is_query": bool, "bbox": list, "area": (int, float),
               "visible_fraction": (int, float), "pickable": dict}


def read_record(path: Path) -> dict[str, Any]:
    """One scene's JSON, checked field by field: a damaged file is one line that says how to redo it."""
    where = f"scene file {str(path)!r}"
    try:
        record = read_json_object(path, "scene file")
        require_fields(record, _RECORD, where)
        for annotation in record["annotations"]:
            if not isinstance(annotation, dict):
                raise InputFileError(f"{where} is damaged: an annotation is not an object")
            require_fields(annotation, _ANNOTATION, where)
            box = annotation["bbox"]
            if len(box) != 4 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in box):
                raise InputFileError(f"{where} is damaged: a bbox is not 4 numbers")
    except InputFileError as error:
        raise InputFileError(f"{error}; delete it and run generate again to redo that scene") from None
    return record


def read_scene(data: Path, index: int) -> tuple[dict[str, Any], list[str]]:
    manifest = open_dataset(data)
    path = Path(data) / "scenes" / f"{index:06d}.json"
    if not path.is_file():
        raise ConfigError(f"scene {index} is not in {data} (scenes 0..{manifest['config'].get('scenes', '?')} may still be generating)")
    return read_record(path), manifest["config"]["policies"]


# ---------------------------------------------------------------------- COCO files and the card
def load_records(out: Path) -> list[dict[str, Any]]:
    return [read_record(path) for path in sorted((Path(out) / "scenes").glob("*.json"))]


def to_coco(records: list[dict[str, Any]], library_products: list[dict[str, str]]) -> dict[str, Any]:
    library_products = list(library_products)
    listed = {p["id"] for p in library_products}
    for record in records:  # a randomised world's own products are not in the library
        for a in record["annotations"]:
            if a["product"] not in listed:
                listed.add(a["product"])
                library_products.append({"id": a["product"], "category": a.get("category", "random")})
    category_ids = {p["id"]: i + 1 for i, p in enumerate(library_products)}
    coco = {"info": {"description": "binpick warehouse bins", "format": FORMAT},
            "categories": [{"id": category_ids[p["id"]], "name": p["id"], "supercategory": p["category"]} for p in library_products],
            "images": [], "annotations": []}
    next_id = 1
    for record in records:
        image_id = record["index"] + 1
        query_id = None
        for a in record["annotations"]:
            x, y, w, h = a["bbox"]
            coco["annotations"].append({
                "id": next_id, "image_id": image_id, "category_id": category_ids[a["product"]], "bbox": [x, y, w, h],
                "area": a["area"], "iscrowd": 0, "instance_id": a["slot"], "visible_fraction": a["visible_fraction"],
                "is_target": a["is_target"], "is_query": a["is_query"], "pickable": a["pickable"],
                **({"pickable_rate": a["pickable_rate"]} if "pickable_rate" in a else {})})  # label_trials > 1
            if a["is_query"]:
                query_id = next_id
            next_id += 1
        coco["images"].append({"id": image_id, "file_name": record["file_name"], "depth_file": record["depth_file"],
                               "width": record["width"], "height": record["height"], "split": record["split"],
                               "target_product": record["target"], "query_annotation_id": query_id,
                               "picked_by": record["picked_by"], "seed": record["seed"],
                               **({"camera": record["camera"]} if record.get("camera") else {})})
    return coco


def finalise(out: Path) -> dict[str, Any]:
    """Merge the scene shards into COCO files (all, and one per split) and write the card."""
    out = Path(out)
    manifest = open_dataset(out)
    records = load_records(out)
    coco = to_coco(records, manifest["products"])
    atomic_write_json(out / "annotations.json", coco, indent=None)
    for split in ("train", "val", "test"):
        ids = {image["id"] for image in coco["images"] if image["split"] == split}
        atomic_write_json(out / f"annotations_{split}.json", coco | {
            "images": [i for i in coco["images"] if i["id"] in ids],
            "annotations": [a for a in coco["annotations"] if a["image_id"] in ids]}, indent=None)
    stats = dataset_stats(records, manifest["config"]["policies"])
    atomic_write_text(out / "CARD.md", card(stats, manifest))
    return stats


def dataset_stats(records: list[dict[str, Any]], policies: list[str]) -> dict[str, Any]:
    """Instances per image, pickable fraction per policy and category, and how often the policies disagree."""
    instances = [len(r["annotations"]) for r in records]
    targets = [a for r in records for a in r["annotations"] if a["is_target"]]
    labelled = [a for a in targets if all(p in a["pickable"] for p in policies)] if policies else []
    by_category: dict[str, dict[str, float]] = defaultdict(dict)
    for policy in policies:
        groups: dict[str, list[bool]] = defaultdict(list)
        for a in labelled:
            groups[a["category"]].append(a["pickable"][policy])
        for category, values in groups.items():
            by_category[category][policy] = round(float(np.mean(values)), 4)
    differs = [len({a["pickable"][p] for p in policies}) > 1 for a in labelled] if len(policies) > 1 else []
    splits = Counter(r["split"] for r in records)
    trials = [t["success"] for r in records for t in r.get("grasp_trials", [])]
    return {"scenes": len(records), "instances": int(sum(instances)),
            "grasp_trials": len(trials), "grasp_trial_success": round(float(np.mean(trials)), 4) if trials else None,
            "instances_per_image": round(float(np.mean(instances)), 3) if records else 0.0,
            "target_instances_per_image": round(len(targets) / max(1, len(records)), 3),
            "labelled_instances": len(labelled),
            "pickable_fraction": {p: round(float(np.mean([a["pickable"][p] for a in labelled])), 4) for p in policies} if labelled else {},
            "pickable_fraction_by_category": dict(sorted(by_category.items())),
            "pickability_differs_fraction": round(float(np.mean(differs)), 4) if differs else None,
            "scenes_with_a_pick": sum(r["picked_by"] is not None for r in records),
            "splits": dict(splits), "categories": dict(Counter(a["category"] for a in targets))}


def card(stats: dict[str, Any], manifest: dict[str, Any]) -> str:
    config = manifest["config"]
    lines = ["# binpick warehouse bins — data-set card", "",
             f"Generated by `binpick data generate` ({FORMAT}); seed {config['seed']}, {config['image_size']} px overhead RGB-D,",
             f"{config['copies'][0]}–{config['copies'][1]} copies of one product plus {config['distractors'][0]}–{config['distractors'][1]} "
             f"distractor products per bin; grasp policies: {', '.join(config['policies']) or 'none'}.", "",
             "| | |", "|---|---|",
             f"| scenes | {stats['scenes']} (splits: {', '.join(f'{k} {v}' for k, v in sorted(stats['splits'].items()))}) |",
             f"| instances | {stats['instances']} ({stats['instances_per_image']} per image, {stats['target_instances_per_image']} of the target) |",
             f"| labelled target instances | {stats['labelled_instances']} |"]
    for policy, fraction in stats["pickable_fraction"].items():
        lines.append(f"| pickable by policy {policy} | {fraction:.1%} |")
    if stats.get("grasp_trials"):
        lines.append(f"| grasp trials (candidates from depth, executed with a carry) | {stats['grasp_trials']}, "
                     f"{stats['grasp_trial_success']:.1%} held |")
    if stats["pickability_differs_fraction"] is not None:
        lines.append(f"| pickability differs between policies | {stats['pickability_differs_fraction']:.1%} |")
    if stats["pickable_fraction_by_category"]:
        policies = config["policies"]
        lines += ["", "Pickable fraction by product category:", "", "| category | " + " | ".join(policies) + " |",
                  "|---|" + "---|" * len(policies)]
        for category, fractions in stats["pickable_fraction_by_category"].items():
            lines.append(f"| {category} | " + " | ".join(f"{fractions.get(p, float('nan')):.0%}" for p in policies) + " |")
    return "\n".join(lines) + "\n"

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

import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from binpick.core.errors import ConfigError
from binpick.core.files import atomic_write_json
from binpick.core.runs import SILENT, RunCallback, new_folder, removed_on_error
from binpick.sim.products import ProductLibrary
from binpick.warehouse.coco import finalise, open_dataset
from binpick.warehouse.generation import FORMAT, GenerateConfig, build_library, target_products
from binpick.warehouse.labels import label_pickability, record_grasp_trials


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
    from binpick.core.files import atomic_write_bytes

    atomic_write_bytes(path, _png_bytes(array))


# ---------------------------------------------------------------------- what each world holds
def random_world_products(config: GenerateConfig, library: ProductLibrary, world: int) -> list:
    """A randomised world's own products (target first, then distractors), made for it alone: a
    domain with ``random_products`` sees thousands of distinct products over a data set."""
    from binpick.sim.products import RANDOM_ID_PREFIX, random_product

    domain = config.domain_config
    rng = np.random.default_rng([config.seed, world, 7])
    seen = [p for p in library if p.category not in config.held_out_categories]
    return [random_product(f"{RANDOM_ID_PREFIX}{world:06d}_{k}", rng, seen, domain.textures, domain.product_scale)
            for k in range(1 + config.distractors[1])]


def world_plan(config: GenerateConfig, library: ProductLibrary, world: int) -> tuple[str, list[str], str]:
    """The target product, distractor products and split of world ``world`` (deterministic)."""
    if config.domain_config.random_products:
        ids = [p.id for p in random_world_products(config, library, world)]
        return ids[0], ids[1:], "val" if val_world(world, config.val_fraction, world_count(config)) else "train"
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
        split = "val" if val_world(world, config.val_fraction, world_count(config)) else "train"
    return target, distractors, split


def val_world(world: int, fraction: float, worlds: int | None = None) -> bool:
    """World ``world`` goes to val when the running count of ``fraction`` per world passes a whole
    number (half a step early): exactly that share of worlds, spread evenly, the first already at
    world 1 for fraction 0.25 or world 4 for 0.1, and a world keeps its split when a set grows. A set
    of ``worlds`` too few to reach its first val world gives one to val (when it has two), so a small
    set still has something to validate on: the last but one, which is whole (only the last world
    can be short of scenes), so a set that grows later never splits one world across train and val."""
    def even(w: int) -> bool:
        return int((w + 1) * fraction + 0.5) > int(w * fraction + 0.5)

    if even(world):
        return True
    return (worlds is not None and fraction > 0 and worlds >= 2 and world == worlds - 2
            and not any(even(w) for w in range(worlds)))


def world_count(config: GenerateConfig) -> int:
    return -(-config.scenes // config.scenes_per_world)


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
    from binpick.core.files import atomic_write_bytes, inside

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
    gripper = config.gripper if gripper is True else gripper
    robot = None
    jaws, cup, tcp = config.hand
    if gripper and config.robot == "panda":  # the arm makes the label grasps (it brings its own gripper)
        from binpick.sim.robot_arm import PANDA, RobotArm

        robot, gripper = RobotArm.carrying(PANDA, config.gripper, jaws, cup, tcp, config.arm_base), False
    sim = BinWorld(products[0], products[1:], max_copies=config.copies[1],
                   camera=CameraSpec(size=config.image_size), randomise_lighting=config.randomise,
                   gripper=gripper, seed=config.seed * 1_000_003 + world, domain=config.domain_config,
                   sensor=config.sensor_config, robot=robot, jaws=jaws, cup=cup)
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
    policies = make_policies(config.policies, config.robot, sim.arm, config.hand[0])
    try:
        photo = {}
        if config.domain_config.random_products:  # a world's own product has its own shop photos
            photo = {path: _png_bytes(image) for path, image in product_photos(config, products[0], world)}
        for index in indices:
            scene, rng = world_scene(sim, config, world, index)
            record = scene_record(scene, index, split, config)
            label_pickability(sim, scene, record, policies, rng, config.label_trials, config.label_jitter)
            if config.grasp_trials:
                record_grasp_trials(sim, scene, record, config.grasp_trials, rng, config.gripper, *config.hand[:2])
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


class DataGeneration:
    """A data set as a job (:class:`binpick.core.runs.Job`): ``DataGeneration.new(config)`` checks the
    products and the output folder, ``DataGeneration.resume(folder)`` continues a killed run with the
    settings it was started with, ``run(callback)`` makes the missing scenes, photos and COCO files."""

    TASK = "data"  # its kind of job (binpick.core.jobs)

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
    def new(cls, config: GenerateConfig, runs: Path = Path("runs")) -> DataGeneration:
        """The data set goes to ``config.out``, the folder other configs read it from by name; a config
        without one makes a new folder under ``runs`` (``runs/data/<time>``)."""
        if config.out:
            return cls(config)
        with removed_on_error(new_folder(Path(runs) / "data")) as folder:  # a bad config leaves no empty folder
            return cls(replace(config, out=str(folder)))

    @classmethod
    def resume(cls, run_dir: Path, workers: int | None = None) -> DataGeneration:
        """Continue the data set in ``run_dir`` with the settings it was started with."""
        manifest = open_dataset(run_dir)
        settings = {k: v for k, v in manifest["config"].items() if k in GenerateConfig.__dataclass_fields__}
        scenes = manifest.get("scenes") or len(list(Path(run_dir, "scenes").glob("*.json")))
        config = GenerateConfig(**{**settings, "out": str(run_dir), "scenes": int(scenes),
                                   "workers": workers or GenerateConfig.workers})
        return cls(config)

    def run(self, callback: RunCallback = SILENT, address: str | None = None) -> dict[str, Any]:
        """Generate the missing scenes (here, or with ``address`` on a Ray cluster: ``local``, ``auto``,
        ``HOST:PORT``, as every job takes it; the config's own ``address`` otherwise), then the photos
        and the COCO files."""
        if address is not None:
            self.config = replace(self.config, address=address)
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

                from binpick.core.processes import worker_context

                context = worker_context(__name__)  # MuJoCo/EGL contexts do not survive a fork of this process
                # workers ignore Ctrl-C (it reaches the whole process group): this process stops them
                with context.Pool(config.workers, initializer=_ignore_ctrl_c) as pool:
                    results = pool.imap_unordered(_generate_world_job, [(config, w, out) for w in worlds])
                    for _ in worlds:
                        while True:
                            try:
                                records = results.next(timeout=1.0)
                                break
                            except multiprocessing.TimeoutError:
                                task.update()  # a stop asked for meanwhile is raised here
                        task.update(advance=len(records))
        photos = write_photos(config, self.library, out, callback)
        return finalise(out) | {"photos": photos}


    def _run_on_ray(self, worlds: range, task) -> None:
        """Worlds as Ray tasks (this machine's private cluster, or one at ``address``): each task
        returns its scenes' files, which only this process writes, so a task lost with its machine
        is retried by Ray and a killed run resumes exactly as with local processes."""
        from binpick.core.cluster import start_ray

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


def _ignore_ctrl_c() -> None:
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


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
        from binpick.sim.own_products import read_photo

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

"""Repeated-instance samples from any COCO-format data set (thesis §5.4, §5.4.4, §6.3).

A *task* is one image, one known instance of a category (the query) and the boxes to find: the
other instances of that category, or only those a given grasp policy could pick. Images qualify when
they hold at least two instances of a category (or, in the pickable setting, a picked instance).
For plain COCO files a random instance is the query, drawn anew each epoch (§5.4); for binpick's
warehouse data the instance the robot really picked is the query when targets are the pickable ones
(§5.4.4). With ``query: photo`` the query is the product's shop photo instead (§6.3), and the boxes to
find include the instance that was the query: the photo does not say which copy the robot picked.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image

from binpick.core.depth import read_depth
from binpick.detection.augment import (  # noqa: F401  (moved there; imported from here too)
    augment,
    camera_effects,
    crop_resize,
    query_photo,
    to_tensor,
)
from binpick.detection.depth import depth_input
from binpick.core.errors import ConfigError
from binpick.core.files import (  # read_image: re-exported for callers of detection.data
    read_image,
    read_json,
)


@dataclass
class Task:
    image_id: int
    file: Path
    category_id: int
    query: dict[str, Any] | None  # the annotation known; None: draw one at random each epoch
    annotations: list[dict[str, Any]]  # every instance of the category in the image
    photo: Path | None = None
    depth: Path | None = None  # the image's depth (16-bit millimetres), where the data set has one
    others: list[dict[str, Any]] = field(default_factory=list)  # instances of other products in the image
    views: tuple[Path, ...] = ()  # more shop photos of the product (randomised studios), for training


def check_coco(coco: dict[str, Any], path: Path) -> None:
    """The fields binpick reads, with their types: a damaged or hand-edited file is one line naming the
    first bad entry, before any training or evaluation starts."""
    def fail(where: str, what: str, value: Any) -> None:
        raise ConfigError(f"{path}: {where} must be {what}, got {str(value)[:60]!r}")

    def integer(value: Any) -> bool:
        return isinstance(value, int) and not isinstance(value, bool)

    for key in ("images", "annotations", "categories"):
        if not isinstance(coco[key], list):
            fail(key, "a list", type(coco[key]).__name__)
    def twice(kind: str, value: Any) -> None:
        raise ConfigError(f"{path}: {kind} id {value} appears twice: ids must be unique")

    categories = set()
    for i, category in enumerate(coco["categories"]):
        if not isinstance(category, dict) or not integer(category.get("id")) or not isinstance(category.get("name"), str):
            fail(f"categories[{i}]", "an object with an integer id and a string name", category)
        if not isinstance(category.get("supercategory", ""), str):
            fail(f"categories[{i}].supercategory", "a string", category["supercategory"])
        if category["id"] in categories:
            twice("category", category["id"])
        categories.add(category["id"])
    sizes: dict[int, tuple[Any, Any]] = {}
    for i, image in enumerate(coco["images"]):
        if not isinstance(image, dict) or not integer(image.get("id")) or not isinstance(image.get("file_name"), str):
            fail(f"images[{i}]", "an object with an integer id and a string file_name", image)
        for key in ("width", "height"):
            value = image.get(key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= 100_000
                                      or value != int(value)):
                fail(f"images[{i}].{key}", "a whole number of pixels from 1 to 100000", value)
        if image["id"] in sizes:
            twice("image", image["id"])
        sizes[image["id"]] = (image.get("width"), image.get("height"))
    annotation_ids = set()
    for i, annotation in enumerate(coco["annotations"]):
        where = f"annotations[{i}]"
        if not isinstance(annotation, dict):
            fail(where, "an object", annotation)
        for key in ("image_id", "category_id"):
            if not integer(annotation.get(key)):
                fail(f"{where}.{key}", "an integer", annotation.get(key))
        if annotation["category_id"] not in categories:
            fail(f"{where}.category_id", "the id of a listed category", annotation["category_id"])
        box = annotation.get("bbox")
        if (not isinstance(box, list) or len(box) != 4
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in box)
                or box[2] <= 0 or box[3] <= 0):
            fail(f"{where}.bbox", "[x, y, width, height]: 4 finite numbers, width and height > 0", box)
        if "id" in annotation and not integer(annotation["id"]):
            fail(f"{where}.id", "an integer", annotation["id"])
        if "id" in annotation:
            if annotation["id"] in annotation_ids:
                twice("annotation", annotation["id"])
            annotation_ids.add(annotation["id"])
        if annotation["image_id"] not in sizes:
            raise ConfigError(f"{path}: {where} has image_id {annotation['image_id']}, but no image has that id")
        width, height = sizes[annotation["image_id"]]
        if width is not None and height is not None and (box[0] < -1 or box[1] < -1 or box[0] + box[2] > width + 1
                                                         or box[1] + box[3] > height + 1):  # a pixel of slack: inclusive boxes
            raise ConfigError(f"{path}: {where}.bbox {box} lies outside its {width}x{height} image")
        if not isinstance(annotation.get("pickable", {}), (dict, type(None))):
            fail(f"{where}.pickable", "a mapping of policy to true/false", annotation["pickable"])
        if not isinstance(annotation.get("iscrowd", 0), (int, bool)):
            fail(f"{where}.iscrowd", "0 or 1", annotation["iscrowd"])


def trained_products(annotations: str | Path) -> list[str]:
    """Names of the categories a detector trained on this COCO file was asked to find: in binpick's
    bins, those that were a scene's ordered product (held-out products can still appear there as
    distractors); in other COCO files, every category with a box."""
    path = Path(annotations)
    coco = read_json(path, "annotations file")
    check_coco(coco, path)
    flagged = any("is_target" in a for a in coco["annotations"])
    used = {a["category_id"] for a in coco["annotations"] if a.get("is_target") or not flagged}
    return sorted(c["name"] for c in coco["categories"] if c["id"] in used)


def pickable_by(annotation: dict[str, Any], policy: str) -> bool | None:
    value = (annotation.get("pickable") or {}).get(policy)
    return None if value is None else bool(value)


def ambiguous_for(annotation: dict[str, Any], policy: str) -> bool:
    """Held in some but not all of its trial grasps (``label_trials`` > 1): a label no image can
    settle, since a shift of the jaws by under a pixel decides it (the `label_noise` note (docs/notes.md))."""
    rate = (annotation.get("pickable_rate") or {}).get(policy)
    return rate is not None and 0.0 < float(rate) < 1.0


class RepeatedInstances:
    """Tasks of a COCO file. ``targets``: ``all`` or ``pickable:<policy>``."""

    def __init__(self, annotations: str | Path, images: str | Path | None = None, targets: str = "all",
                 exclude_categories: list[str] | None = None, only_categories: list[str] | None = None,
                 photos: str | Path | None = None) -> None:
        path = Path(annotations)
        if not path.exists():
            hint = (f"; make the data set with: binpick data generate --out {path.parent}"
                    if path.name.startswith("annotations_") and not (path.parent / "dataset.json").is_file() else "")
            raise ConfigError(f"annotations file {str(path)!r} does not exist{hint}")
        coco = read_json(path, "annotations file")
        if not isinstance(coco, dict) or not {"images", "annotations", "categories"} <= set(coco):
            raise ConfigError(f"{path}: not a COCO detection file (needs images, annotations and categories)")
        check_coco(coco, path)
        self.root = Path(images) if images else path.parent
        self.photos = Path(photos) if photos else path.parent / "photos"
        self._view_cache: dict[str, tuple[Path, ...]] = {}  # product -> its other photos, listed once
        self.targets = targets
        self.policy = targets.split(":", 1)[1] if targets.startswith("pickable:") else None
        if targets != "all" and not self.policy:
            raise ConfigError(f"targets must be 'all' or 'pickable:<policy>', got {targets!r}")
        self.categories = {c["id"]: c for c in coco["categories"]}
        excluded = self._category_ids(exclude_categories or [])
        only = self._category_ids(only_categories) if only_categories else None
        by_image: dict[int, dict[int, list[dict]]] = {}
        for a in coco["annotations"]:
            if a.get("iscrowd", 0):
                continue
            by_image.setdefault(a["image_id"], {}).setdefault(a["category_id"], []).append(a)
        self.path = path
        self.tasks: list[Task] = []
        self.scene_seeds: set[int] = set()  # the generator's seed of every scene that gives a task
        for image in coco["images"]:
            for category, annotations in sorted(by_image.get(image["id"], {}).items()):
                if category in excluded or (only is not None and category not in only):
                    continue
                others = [a for c, items in by_image[image["id"]].items() if c != category for a in items]
                task = self._task(image, category, annotations, others)
                if task is not None:
                    self.tasks.append(task)
                    if isinstance(image.get("seed"), int):
                        self.scene_seeds.add(image["seed"])
        if not self.tasks:
            raise ConfigError(f"{path}: no image holds two or more instances of a category"
                              f"{' with a picked query' if self.policy else ''} (after exclusions)")
        missing = sorted({str(task.file) for task in self.tasks if not task.file.is_file()})
        if missing:
            raise ConfigError(f"{path}: {len(missing)} image file(s) it names do not exist, e.g. {missing[0]!r} "
                              "(are the images beside the annotations, or give data.images?)")

    def _category_ids(self, names: list[str]) -> set[int]:
        """Category ids named by COCO name or supercategory (a product id or its category)."""
        ids = {i for i, c in self.categories.items() if c["name"] in names or c.get("supercategory") in names}
        known = {c["name"] for c in self.categories.values()} | {c.get("supercategory") for c in self.categories.values()}
        unknown = [n for n in names if n not in known]
        if unknown:
            raise ConfigError(f"unknown category {unknown[0]!r}; known: {', '.join(sorted(k for k in known if k)[:20])}")
        return ids

    def _task(self, image: dict, category: int, annotations: list[dict], others: list[dict]) -> Task | None:
        from binpick.core.files import inside

        file = inside(self.root, image["file_name"], "image")
        name = self.categories[category]["name"].replace("/", "_")
        photo = self.photos / f"{name}.png"
        photo = photo if photo.is_file() else None
        views = self._views(name)
        depth = inside(self.root, image["depth_file"], "depth image") if isinstance(image.get("depth_file"), str) else None
        if self.policy:
            query = next((a for a in annotations if a.get("is_query")), None)
            if query is None or all(pickable_by(a, self.policy) is None for a in annotations if a is not query):
                return None  # nothing picked here, or no labels for this policy
            return Task(image["id"], file, category, query, annotations, photo, depth, others, views)
        if len(annotations) < 2:
            return None
        return Task(image["id"], file, category, None, annotations, photo, depth, others, views)

    def _views(self, name: str) -> tuple[Path, ...]:
        """The product's other shop photos: ``photos/<product>/*.png`` (``--photo-views``), listed once."""
        if name not in self._view_cache:
            folder = self.photos / name
            self._view_cache[name] = tuple(sorted(folder.glob("*.png"))) if folder.is_dir() else ()
        return self._view_cache[name]

    def __len__(self) -> int:
        return len(self.tasks)

    def boxes(self, task: Task, query: dict | None) -> dict[str, np.ndarray]:
        """Ground truth of a task, xyxy pixels: ``targets`` to find, ``all`` instances but ``query``,
        ``unpickable`` ones (for Tables 5.5/5.6), ``ambiguous`` ones (their trial grasps disagreed) and
        ``certain``: the targets that are not ambiguous (with one grasp per instance: none, and all);
        ``other_products``: the instances of other products in the image."""
        others = [a for a in task.annotations if a is not query]

        def xyxy(items):
            return np.array([[a["bbox"][0], a["bbox"][1], a["bbox"][0] + a["bbox"][2], a["bbox"][1] + a["bbox"][3]]
                             for a in items], dtype=np.float32).reshape(-1, 4)

        if self.policy:
            targets = [a for a in others if pickable_by(a, self.policy)]
            unpickable = [a for a in others if pickable_by(a, self.policy) is False]
            ambiguous = [a for a in others if ambiguous_for(a, self.policy)]
            certain = [a for a in targets if not ambiguous_for(a, self.policy)]
        else:
            targets, unpickable, ambiguous, certain = others, [], [], others
        return {"targets": xyxy(targets), "all": xyxy(others), "unpickable": xyxy(unpickable),
                "certain": xyxy(certain), "ambiguous": xyxy(ambiguous), "other_products": xyxy(task.others)}


def check_disjoint(train: RepeatedInstances, val: RepeatedInstances) -> None:
    """Val must not score scenes the model trained on. The generator makes the same scene from the
    same seed and world in every data set made with one ``--seed``, and which worlds go to val depends
    on the split rule, so the train split of one such set can hold the val scenes of another."""
    if train.path.resolve() == val.path.resolve():
        return  # one file for both on purpose (an overfitting check)
    shared = train.scene_seeds & val.scene_seeds
    if shared:
        raise ConfigError(f"data.train ({train.path}) and data.val ({val.path}) share {len(shared)} of "
                          f"{len(val.scene_seeds)} val scenes (made from the same generator seed and world): val would "
                          "score images the model trained on; generate one of the sets with another --seed")


class TaskDataset(torch.utils.data.Dataset):
    """Tensors for training and evaluation: the image resized to ``size``, the query (box in that
    image, its crop, or the shop photo) and the boxes to find. ``augment`` applies box-safe flips,
    zoom and colour jitter. ``frame_photos`` crops shop photos to their product (models with
    ``photo_sizes``, binpick.detection.photos). ``depth`` adds each image's height map (models that
    read depth, binpick.detection.depth), moved by the same flips and zoom."""

    def __init__(self, source: RepeatedInstances, size: int, query_mode: str = "crop", query_size: int = 96,
                 augment: bool = False, seed: int = 0, photometric: bool = False, frame_photos: bool = False,
                 depth: bool = False) -> None:
        if query_mode not in ("crop", "photo"):
            raise ConfigError(f"query must be 'crop' or 'photo', got {query_mode!r}")
        self.source, self.size, self.query_mode, self.query_size = source, size, query_mode, query_size
        self.augment, self.seed, self.epoch, self.photometric = augment, seed, 0, photometric
        self.with_photo = False  # also the shop photo, for joint training of crop and photo queries
        self.frame_photos = frame_photos
        self.depth = False
        if depth:
            self.add_depth()
        self._photos: dict[Path, np.ndarray] = {}  # query-sized photos, read once per category
        if query_mode == "photo":
            missing = [t for t in source.tasks if t.photo is None]
            if missing:
                raise ConfigError(f"no shop photo for category {source.categories[missing[0].category_id]['name']!r} "
                                  f"in {str(source.photos)!r}")

    def add_depth(self) -> None:
        """From now on, samples hold each image's height map; every image must have a depth file."""
        missing = [t for t in self.source.tasks if t.depth is None or not t.depth.is_file()]
        if missing:
            raise ConfigError(f"this detector reads depth, but image {str(missing[0].file)!r} has no depth file "
                              f"({len(missing)} of {len(self.source.tasks)} tasks; COCO images need a depth_file)")
        self.depth = True

    def set_epoch(self, epoch: int) -> None:
        """A new epoch draws new random queries and augmentations (deterministically)."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, index: int) -> dict[str, Any]:
        rng = np.random.default_rng([self.seed, self.epoch, index])
        task = self.source.tasks[index]
        query = task.query if task.query is not None else task.annotations[rng.integers(len(task.annotations))]
        image = read_image(task.file)
        # a shop photo names no instance: every copy is to be found, the one the robot picked included
        boxes = self.source.boxes(task, None if self.query_mode == "photo" else query)
        qx, qy, qw, qh = query["bbox"]
        query_box = np.array([qx, qy, qx + qw, qy + qh], dtype=np.float32)
        image, query_box, boxes = self._resize(image, query_box, boxes)
        heights = depth_input(read_depth(task.depth), self.size) if self.depth else None
        if self.augment:
            image, query_box, boxes, heights = augment(image, query_box, boxes, rng, heights)
            if self.photometric:
                image = camera_effects(image, rng)
        photo = None
        if self.query_mode == "photo" or self.with_photo:
            if task.photo is None:
                raise ConfigError(f"no shop photo for category {self.source.categories[task.category_id]['name']!r}")
            path = task.photo  # training draws among the randomised studios' photos too, three times in four
            if self.augment and task.views and rng.uniform() < 0.75:
                path = task.views[rng.integers(len(task.views))]
            photo = self.photo(path)
            if self.augment and self.photometric:
                photo = camera_effects(photo, rng)
        query_image = photo if self.query_mode == "photo" else crop_resize(image, query_box, self.query_size)
        extra = {"photo": to_tensor(photo)} if self.with_photo else {}
        if heights is not None:
            extra["depth"] = torch.from_numpy(np.ascontiguousarray(heights))[None]
        return {**extra, "image": to_tensor(image), "query_box": torch.from_numpy(query_box), "query_image": to_tensor(query_image),
                "targets": torch.from_numpy(boxes["targets"]), "all": torch.from_numpy(boxes["all"]),
                **{key: torch.from_numpy(boxes[key]) for key in ("unpickable", "certain", "ambiguous", "other_products")}, "image_id": task.image_id,
                "category_id": task.category_id, "index": index, "query_id": int(query.get("id", -1))}

    def photo(self, path: Path) -> np.ndarray:
        if path not in self._photos:
            self._photos[path] = query_photo(read_image(path, keep_alpha=True), self.query_size, self.frame_photos)
        return self._photos[path]

    def _resize(self, image: np.ndarray, query_box: np.ndarray, boxes: dict[str, np.ndarray]):
        height, width = image.shape[:2]
        scale = np.array([self.size / width, self.size / height] * 2, dtype=np.float32)
        image = np.asarray(Image.fromarray(image).resize((self.size, self.size), Image.BILINEAR))
        return image, query_box * scale, {k: v * scale for k, v in boxes.items()}


class RehearsedTasks(torch.utils.data.Dataset):
    """A fine-tuning set's tasks, then ``per_epoch`` tasks of a rehearsal set (every copy a target),
    drawn afresh each epoch from ``seed`` and the epoch: fine-tuning on one domain's bins keeps what
    pre-training on others taught (without it, fine-tuning the photo query on the default bins took its
    AP50 on the shifted set-up from 0.67 to 0.32). Only the main set's tasks count as ``source``."""

    def __init__(self, main: TaskDataset, rehearsal: TaskDataset, per_epoch: int, seed: int) -> None:
        self.main, self.rehearsal, self.per_epoch, self.seed = main, rehearsal, min(per_epoch, len(rehearsal)), seed
        self.source, self.size = main.source, main.size
        self.set_epoch(0)

    def set_epoch(self, epoch: int) -> None:
        self.main.set_epoch(epoch)
        self.rehearsal.set_epoch(epoch)
        rng = np.random.default_rng([self.seed, epoch, 17])
        self.drawn = rng.choice(len(self.rehearsal), self.per_epoch, replace=False)

    def __len__(self) -> int:
        return len(self.main) + self.per_epoch

    def __getitem__(self, index: int) -> dict[str, Any]:
        if index < len(self.main):
            return self.main[index]
        return self.rehearsal[int(self.drawn[index - len(self.main)])]


def collate(samples: list[dict[str, Any]]) -> dict[str, Any]:
    batch = {key: torch.stack([s[key] for s in samples]) for key in ("image", "query_box", "query_image", "photo", "depth") if key in samples[0]}
    for key in ("targets", "all", "unpickable", "certain", "ambiguous", "other_products", "image_id", "category_id", "index", "query_id"):
        batch[key] = [s[key] for s in samples]
    return batch

"""What a detector run trains on: its data sets (the training tasks, rehearsal mixed in, the val
tasks), the products and scene domains its weights learn (its own data's and those of the weights it
was fine-tuned from), the anchors fitted to its boxes, and the data loader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from binpick.core.errors import ConfigError, InputFileError
from binpick.core.files import read_json
from binpick.detection.config import DetectConfig
from binpick.detection.data import RehearsedTasks, RepeatedInstances, TaskDataset, check_disjoint, collate, trained_products
from binpick.detection.model import ANCHORS_PER_LEVEL
from binpick.detection.ops import box_iou
from binpick.detection.weights_file import read_detector_file, weights_path


def trained_domains(config: DetectConfig) -> list[str]:
    """The scene domains of the data a run was trained on: its own, plus those of the weights it was
    fine-tuned from (read from each data set's manifest, ``domain_values.name``)."""
    domains = []
    if config.train.init_from:
        try:
            domains += read_detector_file(weights_path(Path(config.train.init_from)))[1].get("trained_domains") or []
        except InputFileError:
            pass
    files = [config.data.train] + ([config.data.rehearse] if config.data.rehearse else [])
    return sorted(set(domains + [domain_of(file) for file in files]))


def domain_of(coco_file: str | Path) -> str:
    """The scene domain a binpick data set was made in (its manifest's ``domain_values.name``)."""
    manifest = Path(coco_file).parent / "dataset.json"
    if not manifest.is_file():
        return "external"  # a COCO file that binpick did not generate
    try:
        content = read_json(manifest, "data-set manifest")
        return (((content.get("config") or {}).get("domain_values") or {}).get("name", "default")
                if isinstance(content, dict) else "unknown")
    except InputFileError:
        return "unknown"


def learnt_products(config: DetectConfig) -> list[str]:
    """The products a run's weights have learnt: its own training set's, plus those of the weights it
    was fine-tuned from (a fine-tune on bins that lack a few products has still seen them)."""
    products = set(trained_products(config.data.train))
    if config.train.init_from:
        try:
            products |= set(read_detector_file(weights_path(Path(config.train.init_from)))[1].get("trained_products") or [])
        except InputFileError:
            pass
    return sorted(products)


# ---------------------------------------------------------------------- anchors
def kmeans_anchors(sizes: np.ndarray, clusters: int = 3 * ANCHORS_PER_LEVEL, iterations: int = 50, seed: int = 0) -> np.ndarray:
    """YOLOv3's anchor priors: k-means of box sizes (w, h) under the 1 - IoU distance, smallest first."""
    rng = np.random.default_rng(seed)
    sizes = np.asarray(sizes, dtype=np.float64)
    if len(sizes) < clusters:
        raise ConfigError(f"need at least {clusters} boxes to fit anchors, got {len(sizes)}")
    centres = sizes[rng.choice(len(sizes), clusters, replace=False)]
    for _ in range(iterations):
        boxes = torch.tensor(np.c_[np.zeros((len(sizes), 2)), sizes])
        anchors = torch.tensor(np.c_[np.zeros((clusters, 2)), centres])
        nearest = box_iou(boxes, anchors).argmax(1).numpy()
        updated = np.array([np.median(sizes[nearest == k], axis=0) if np.any(nearest == k) else centres[k] for k in range(clusters)])
        if np.allclose(updated, centres):
            break
        centres = updated
    return centres[np.argsort(centres.prod(1))]


def fit_anchors(dataset: TaskDataset) -> torch.Tensor:
    """Anchors from the training boxes, in the pixels of the resized images the model sees."""
    from binpick.core.files import opened_image

    with opened_image(dataset.source.tasks[0].file, "training image") as image:
        scale = dataset.size / float(max(image.size))  # a data set's images share one size
    sizes = [a["bbox"][2:4] for task in dataset.source.tasks for a in task.annotations]
    return torch.tensor(kmeans_anchors(np.array(sizes) * scale), dtype=torch.float32).view(3, ANCHORS_PER_LEVEL, 2)


# ---------------------------------------------------------------------- the run
def make_datasets(config: DetectConfig) -> tuple[TaskDataset, TaskDataset]:
    data = config.data
    train_source = RepeatedInstances(data.train, data.images, data.targets, exclude_categories=data.exclude_categories)
    val_source = RepeatedInstances(data.val, data.images, data.targets)
    check_disjoint(train_source, val_source)
    query_mode = config.model.query
    framed = bool(config.model.photo_sizes)
    train = TaskDataset(train_source, data.load_size, query_mode, data.query_size, augment=data.augment, seed=config.train.seed,
                        photometric=data.photometric, frame_photos=framed, depth=config.model.depth)
    val = TaskDataset(val_source, data.image_size, query_mode, data.query_size, augment=False, seed=config.train.seed + 1,
                      frame_photos=framed, depth=config.model.depth)
    if data.rehearse:
        rehearsal = TaskDataset(RepeatedInstances(data.rehearse, None, "all"), data.load_size, query_mode, data.query_size,
                                augment=data.augment, seed=config.train.seed + 2, photometric=data.photometric,
                                frame_photos=framed, depth=config.model.depth)
        if domain_of(data.rehearse) == domain_of(data.val):  # another domain's scene from the same seed is another scene
            check_disjoint(rehearsal.source, val_source)
        train = RehearsedTasks(train, rehearsal, data.rehearse_per_epoch, config.train.seed)
    return train, val


def loader(dataset: TaskDataset, batch_size: int, shuffle: bool, workers: int, seed: int) -> torch.utils.data.DataLoader:
    generator = torch.Generator().manual_seed(seed)
    return torch.utils.data.DataLoader(dataset, batch_size=batch_size, shuffle=shuffle, num_workers=workers,
                                       collate_fn=collate, generator=generator, persistent_workers=False)

"""Configuration of a detector run (one YAML per experiment in ``configs/detection/rod_*.yaml``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from binpick.core.config import check_range
from binpick.detection.losses import LossWeights
from binpick.detection.model import ModelSpec
from binpick.core.errors import ConfigError


@dataclass(frozen=True)
class DataConfig:
    train: str = "runs/data/bins_2000/annotations_train.json"  # a COCO file (binpick's or anyone's)
    val: str = "runs/data/bins_2000/annotations_val.json"
    images: str | None = None  # image root; default: the COCO file's folder
    targets: str = "pickable:y"  # all | pickable:<policy> (y = the thesis's Policy 1, x = Policy 2)
    exclude_categories: list[str] = field(default_factory=list)  # zero-shot: names or supercategories
    image_size: int = 256
    query_size: int = 96  # side of the query image (TDID's target crop, or the shop photo)
    augment: bool = True
    photometric: bool = False  # also sensor noise, blur and JPEG artefacts (another camera's images)
    train_sizes: list[int] = field(default_factory=list)  # [low, high]: multi-scale training, a size per batch
    # rehearsal while fine-tuning: tasks drawn afresh each epoch from a second COCO file (every copy a
    # target), e.g. the pre-training's randomised bins, so fine-tuning on one domain keeps the others
    rehearse: str | None = None
    rehearse_per_epoch: int = 0

    def __post_init__(self) -> None:
        check_range("data.image_size", self.image_size, 64, 1024, integer=True)
        check_range("data.rehearse_per_epoch", self.rehearse_per_epoch, 0, 10_000_000, integer=True)
        if bool(self.rehearse) != (self.rehearse_per_epoch > 0):
            raise ConfigError("data.rehearse and data.rehearse_per_epoch go together: a COCO file and how many of its tasks per epoch")
        if self.image_size % 32:
            raise ConfigError(f"data.image_size must be a multiple of 32, got {self.image_size}")
        check_range("data.query_size", self.query_size, 32, 512, integer=True)
        if self.train_sizes:
            if len(self.train_sizes) != 2 or self.train_sizes[0] > self.train_sizes[1]:
                raise ConfigError(f"data.train_sizes must be [low, high], got {self.train_sizes}")
            for i, size in enumerate(self.train_sizes):
                check_range(f"data.train_sizes[{i}]", size, 64, 1024, integer=True)
                if size % 32:
                    raise ConfigError(f"data.train_sizes[{i}] must be a multiple of 32, got {size}")

    @property
    def load_size(self) -> int:
        """Side of the images the training loader makes (the largest training size)."""
        return max([self.image_size, *self.train_sizes])


@dataclass(frozen=True)
class TrainConfig:
    epochs: int = 30
    batch_size: int = 8
    lr: float = 1e-3
    weight_decay: float = 5e-4
    warmup_steps: int = 200
    workers: int = 1  # data-loading processes
    threads: int = 2  # torch threads for the model
    eval_every: int = 5  # epochs
    fast_cpu: bool = True  # bf16 autocast + channels_last: 1.8x faster training on this CPU
    device: str = "cpu"  # cpu | cuda (a GPU, where one is at hand; nothing depends on one)
    init_from: str | None = None  # detector weights to start from (fine-tuning a pre-trained model)
    keep_best: bool = False  # the final weights are those of the best val AP50 (early stopping)
    patience: int = 0  # stop after this many evaluations without a better val AP50 (0: never)
    max_minutes: float = 0.0  # stop (and save) after this long; 0: no limit
    checkpoint_minutes: float = 15.0  # also checkpoint within an epoch this often (0: once per epoch): a kill loses less
    seed: int = 0

    def __post_init__(self) -> None:
        from binpick.core.config import check_choice

        check_choice("train.device", self.device, ("cpu", "cuda"))
        check_range("train.patience", self.patience, 0, 10_000, integer=True)
        check_range("train.max_minutes", self.max_minutes, 0, 1e6)
        check_range("train.checkpoint_minutes", self.checkpoint_minutes, 0, 1e6)
        check_range("train.epochs", self.epochs, 1, 10_000, integer=True)
        check_range("train.batch_size", self.batch_size, 1, 512, integer=True)
        check_range("train.lr", self.lr, 0, 1, low_inclusive=False)
        check_range("train.workers", self.workers, 0, 64, integer=True)
        check_range("train.threads", self.threads, 1, 256, integer=True)
        check_range("train.eval_every", self.eval_every, 1, 10_000, integer=True)


@dataclass(frozen=True)
class ModelConfig:
    backbone: str = "tiny"
    method: str = "rod"
    layout: str = "RRR"
    scales: list[float] = field(default_factory=lambda: [0.5, 1.0, 2.0])
    query: str = "crop"
    photo_sizes: list[float] = field(default_factory=list)  # see ModelSpec.photo_sizes
    depth: bool = False  # see ModelSpec.depth

    def spec(self) -> ModelSpec:
        spec = ModelSpec(self.backbone, self.method, self.layout, tuple(self.scales), self.query, tuple(self.photo_sizes),
                         self.depth)
        spec.check()
        return spec


@dataclass(frozen=True)
class DetectConfig:
    name: str = "rod"
    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    loss: LossWeights = field(default_factory=LossWeights)
    train: TrainConfig = field(default_factory=TrainConfig)

    def __post_init__(self) -> None:
        self.model.spec()

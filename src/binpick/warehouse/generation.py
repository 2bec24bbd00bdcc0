"""What a data set is made of: the generation config (validated once) and the product library it draws from."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

from binpick.core.errors import ConfigError
from binpick.sim.own_products import load_products
from binpick.sim.products import ProductLibrary, default_library

FORMAT = "binpick-bins-1"


@dataclass(frozen=True)
class GenerateConfig:
    out: str = ""  # the data set's folder; empty: a new folder under --runs (runs/data/<time>)
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
    robot: str = "floating"  # what the label grasps are made by: floating (the gripper alone) or panda (the arm, slower)
    gripper: str = "jaws"  # the hand's tools (jaws, suction, both): grasp trials are made with each tool it carries
    cell: str | None = None  # a cell file (binpick.cell): its hand (tools, jaws, cup; on the arm, its tool point) makes the trials and labels
    seed: int = 0

    def __post_init__(self) -> None:
        from binpick.core.config import check_range

        check_range("scenes", self.scenes, 1, 10_000_000, integer=True)
        check_range("workers", self.workers, 1, 256, integer=True)
        check_range("grasp_trials", self.grasp_trials, 0, 100, integer=True)
        check_range("label_trials", self.label_trials, 1, 25, integer=True)
        check_range("label_jitter", self.label_jitter, 0.0, 0.02)
        check_range("image_size", self.image_size, 32, 2048, integer=True)
        check_range("photo_views", self.photo_views, 0, 64, integer=True)
        check_range("scenes_per_world", self.scenes_per_world, 1, 1000, integer=True)
        check_range("val_fraction", self.val_fraction, 0.0, 1.0)
        from binpick.core.config import check_choice

        check_choice("split_rule", self.split_rule, ("even", "random"))
        check_choice("robot", self.robot, ("floating", "panda"))
        from binpick.grippers import GRIPPERS

        check_choice("gripper", self.gripper, GRIPPERS)
        object.__setattr__(self, "_cell", None)
        if self.cell is not None:
            from binpick.cell import load_cell

            cell = load_cell(self.cell, self.robot)  # a bad file, or one another arm cannot carry: one line, now
            if self.gripper not in ("jaws", cell.tools):  # jaws is the default: the file's tools replace it
                raise ConfigError(f"gripper {self.gripper!r} and cell {self.cell!r} (tools {cell.tools}) disagree: give one of them")
            object.__setattr__(self, "gripper", cell.tools)
            object.__setattr__(self, "_cell", cell)
        if self.gripper == "suction" and self.policies:
            raise ConfigError("the labelling policies grasp with jaws: give gripper: jaws or both, or policies: [] for suction trials alone")
        if self.robot == "panda" and self.grasp_trials:
            raise ConfigError("grasp_trials are made by the floating gripper (the grasp-quality data): set robot: floating, "
                              "or grasp_trials: 0 for labels made by the arm")
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
        if self.robot == "panda" and (self.domain_config.randomise or self.sensor_config.tilts_tote):
            raise ConfigError("robot: panda works in binpick's own cell (the default domain, a level tote): the arm's "
                              f"collision model does not follow domain {self.domain!r} or sensor {self.sensor!r}'s tote")
        if self.address not in (None, "local"):
            from binpick.core.cluster import check_ray_address

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
        if self.cell is None:  # and those made before cell files
            data.pop("cell")
        if self.robot == "floating":  # data sets made before the arm resume as they were
            data.pop("robot")
        if self.gripper == "jaws":  # data sets made before the suction cup resume as they were
            data.pop("gripper")
        data["domain_values"] = domain_dict(self.domain_config)  # so an edited domain file is noticed on resume
        if self.sensor_config.realistic:  # perfect depth adds nothing: data sets made before sensors resume as they were
            from binpick.sim.sensor import sensor_dict

            data["sensor_values"] = sensor_dict(self.sensor_config)
        else:
            data.pop("sensor")
        return data

    @property
    def hand(self):
        """(jaws, cup, tcp) of the hand that makes the trials and labels: the cell file's, else binpick's own."""
        from binpick.grippers import Jaws, SuctionCup

        cell = self._cell
        return (Jaws(), SuctionCup(), None) if cell is None else (cell.jaws, cell.cup, cell.tcp)

    @property
    def arm_base(self):
        """Where the labelling arm's base stands: the cell file's ``arm.base`` (None: binpick's cell's place)."""
        return None if self._cell is None else self._cell.base

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

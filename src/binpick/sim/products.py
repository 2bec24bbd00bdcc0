"""Products a bin can hold: meshes and textures that PyPI packages ship, procedural primitives, and
users' own products from a folder described by a YAML file (read by :mod:`binpick.sim.own_products`).

Sources (nothing is downloaded):
- ``robosuite`` (installed ``--no-deps``; only its asset files are read, the package is never
  imported): bottle, bread, can, cereal, lemon, milk, with their textures;
- ``pybullet_data``: duck, mug, lego, teddy, and a seeded draw from its 1000 ``random_urdfs``
  shapes (convex decompositions, merged into one mesh). Shapes thinner than 0.35 of their length
  are skipped: dropped eight at a time into a tote, thin sticks ended below the tote floor
  (22 of 32 copies of shape 966), while stubby ones lost 1 of 832 (with the stiffer product
  contacts of :mod:`binpick.sim.mjcf`);
- procedural boxes, cylinders and spheres with random colours and a printed check pattern.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from binpick.core.errors import ConfigError
from binpick.sim.mjcf_mesh import merged_obj


@dataclass(frozen=True)
class Product:
    """One stock-keeping unit. Sizes are metres; ``mesh`` is None for a primitive ``shape``."""

    id: str
    category: str
    mesh: Path | None = None
    shape: str | None = None  # box | cylinder | sphere (procedural products)
    size: tuple[float, ...] = ()  # primitive half-sizes (MuJoCo convention)
    scale: float = 1.0  # mesh scale
    texture: Path | None = None
    texrepeat: tuple[float, float] = (1.0, 1.0)
    texuniform: bool = False
    rgba: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0)
    mass: float = 0.15
    friction: float = 1.0
    photos: tuple[Path, ...] = ()  # the shop's own photos, if the user has them (views, studios)
    pattern: tuple[int, str] | None = None  # (seed, texture pool): a generated texture (domain randomisation)

    @property
    def name(self) -> str:
        return self.id.replace("/", "_")

    @property
    def photo(self) -> Path | None:
        """The user's first photo of the product (None: binpick renders its catalogue views)."""
        return self.photos[0] if self.photos else None


@dataclass
class ProductLibrary:
    products: dict[str, Product] = field(default_factory=dict)

    def __getitem__(self, product_id: str) -> Product:
        if product_id not in self.products:
            raise ConfigError(f"unknown product {product_id!r}{self._nearest(product_id)}")
        return self.products[product_id]

    def __len__(self) -> int:
        return len(self.products)

    def __iter__(self):
        return iter(self.products.values())

    @property
    def categories(self) -> list[str]:
        return sorted({p.category for p in self.products.values()})

    def in_categories(self, categories: list[str]) -> list[Product]:
        unknown = sorted(set(categories) - set(self.categories))
        if unknown:
            from binpick.core.config import did_you_mean

            raise ConfigError(f"unknown product category {unknown[0]!r}{did_you_mean(unknown[0], self.categories)}; "
                              f"known: {', '.join(self.categories)}")
        return [p for p in self.products.values() if p.category in categories]

    def add(self, product: Product) -> None:
        self.products[product.id] = product

    def resolve(self, name: str) -> list[str]:
        """Product ids for a name: a full id (``robosuite/cereal``), a short name when only one product
        has it (``cereal``), or a product category (``box``: every product in it), case ignored
        (``Mug``). Anything else is one line with the nearest name, if one is near."""
        if name in self.products:
            return [name]
        key = name.strip().lower()
        exact = [pid for pid in self.products if pid.lower() == key]
        if len(exact) == 1:
            return exact
        short = [pid for pid in self.products if pid.split("/")[-1].lower() == key]
        if len(short) == 1:
            return short
        if len(short) > 1:
            raise ConfigError(f"{name!r} is the short name of {', '.join(sorted(short))}: give the full id")
        category = [c for c in self.categories if c.lower() == key]
        if category:
            return sorted(p.id for p in self.products.values() if p.category == category[0])
        raise ConfigError(f"unknown product or category {name!r}{self._nearest(name)}")

    def _nearest(self, name: str) -> str:
        """`` (did you mean ...?)`` from ids, unique short names and categories; else where to look."""
        from binpick.core.config import did_you_mean

        shorts = [pid.split("/")[-1] for pid in self.products]
        names = [*self.products, *(s for s in shorts if shorts.count(s) == 1), *self.categories]
        containing = sorted(pid for pid in self.products if name.strip().lower() in pid.lower())[:6]
        if containing:
            return f" (did you mean {', '.join(containing)}?)"
        near = did_you_mean(name, names) or did_you_mean(name.split("/")[-1], names)
        return near or "; `binpick products list` shows them all"


def package_dir(name: str) -> Path | None:
    """Where an installed package's files are, without importing it (robosuite's import needs its deps)."""
    spec = importlib.util.find_spec(name)
    return Path(spec.submodule_search_locations[0]) if spec and spec.submodule_search_locations else None


# robosuite objects: (category, texture, texrepeat, texuniform, mass kg)
ROBOSUITE = {
    "bottle": ("bottle", "glass.png", (5, 5), True, 0.30),
    "bread": ("bakery", "bread.png", (15, 15), True, 0.10),
    "can": ("can", "soda.png", (5, 5), True, 0.35),
    "cereal": ("box", "cereal.png", (1, 1), False, 0.40),
    "lemon": ("fruit", "lemon.png", (60, 50), True, 0.10),
    "milk": ("carton", "ceramic.png", (1, 1), True, 0.40),
}
PYBULLET = {  # name: (category, mesh, texture, target longest side m)
    "duck": ("toy", "duck.obj", "duckCM.png", 0.08),
    "mug": ("mug", "objects/mug.obj", None, 0.10),
    "lego": ("toy", "lego/lego.obj", None, 0.06),
    "teddy": ("plush", "teddy2_VHACD_CHs.obj", None, 0.12),
}
MIN_ASPECT = 0.35  # random shapes: shortest / longest side


def mesh_extent(path: Path) -> np.ndarray:
    """Axis-aligned size of a mesh as MuJoCo loads it (its OBJ reader may keep fewer vertices than
    the file holds), so that ``scale`` normalises what is really simulated and rendered."""
    from xml.sax.saxutils import quoteattr

    import mujoco

    path = Path(path)
    if path.suffix.lower() not in (".obj", ".stl"):
        raise ConfigError(f"mesh {str(path)!r}: only .obj and .stl meshes are supported")
    inline = merged_obj(path) if path.suffix.lower() == ".obj" and path.is_file() else None
    source = f'vertex="{inline[0]}" face="{inline[1]}"' if inline else f"file={quoteattr(str(path))}"
    xml = f'<mujoco><asset><mesh name="m" {source}/></asset><worldbody><geom type="mesh" mesh="m"/></worldbody></mujoco>'
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except Exception as error:  # noqa: BLE001 - MuJoCo raises ValueError with a long message
        raise ConfigError(f"mesh {str(path)!r} cannot be loaded: {str(error).splitlines()[0]}") from None
    vertices = model.mesh_vert[model.mesh_vertadr[0]:model.mesh_vertadr[0] + model.mesh_vertnum[0]]
    if len(vertices) < 4:
        raise ConfigError(f"mesh {str(path)!r} has no usable vertices")
    return vertices.max(0) - vertices.min(0)


def product_dimensions(product: Product) -> tuple[float, float, float]:
    """The product's bounding-box sides (m), longest first: what a warehouse catalogue lists per SKU."""
    if product.shape == "box":
        sides = 2 * np.asarray(product.size[:3], dtype=float)
    elif product.shape == "cylinder":
        sides = np.array([2 * product.size[0], 2 * product.size[0], 2 * product.size[1]])
    elif product.shape == "sphere":
        sides = np.full(3, 2 * product.size[0])
    elif product.mesh is not None:
        sides = mesh_extent(product.mesh) * product.scale
    else:
        raise ConfigError(f"product {product.id!r} has neither a shape nor a mesh: no dimensions")
    first, second, third = sorted((float(v) for v in sides), reverse=True)
    return first, second, third


def _random_colour(rng: np.random.Generator) -> tuple[float, float, float, float]:
    hue = rng.uniform()
    colour = np.clip(np.abs(np.array([hue * 6 - 3, 2 - abs(hue * 6 - 2), 2 - abs(hue * 6 - 4)])) - [1, 0, 0], 0, 1)
    colour = 0.25 + 0.7 * colour * rng.uniform(0.6, 1.0)
    return (*np.round(colour, 3).tolist(), 1.0)


def random_shapes(data: Path, count: int, rng: np.random.Generator) -> list[Product]:
    """``count`` stubby shapes from pybullet's random pool, 5-9 cm long, in random colours."""
    products = []
    for index in rng.permutation(1000):
        if len(products) == count:
            break
        found = _stubby_shape(data, int(index))
        if found is not None:
            path, extent = found
            products.append(Product(f"pybullet/shape_{index:03d}", "random_shape", mesh=path,
                                    scale=float(rng.uniform(0.05, 0.09) / extent.max()), rgba=_random_colour(rng), mass=0.1))
    return products


def _stubby_shape(data: Path, index: int) -> tuple[Path, np.ndarray] | None:
    """Mesh file and extent of random shape ``index``, or None when it is thin (MIN_ASPECT) or
    unreadable (a few files hold non-finite vertices). Extents are cached per process."""
    path = data / "random_urdfs" / f"{index:03d}" / f"{index:03d}.obj"
    key = str(path)
    if key not in _EXTENTS:
        try:
            _EXTENTS[key] = mesh_extent(path)
        except ConfigError:
            _EXTENTS[key] = None
    extent = _EXTENTS[key]
    if extent is None or extent.min() / extent.max() < MIN_ASPECT:
        return None
    return path, extent


_EXTENTS: dict[str, np.ndarray | None] = {}


def default_library(procedural: int = 18, shapes: int = 12, seed: int = 0) -> ProductLibrary:
    """Every product that ships with the installed packages, ``shapes`` of pybullet's random shapes
    and ``procedural`` primitives (deterministic under ``seed``)."""
    rng = np.random.default_rng(seed)
    library = ProductLibrary()
    robosuite = package_dir("robosuite")
    if robosuite is not None:
        objects, textures = robosuite / "models" / "assets" / "objects", robosuite / "models" / "assets" / "textures"
        for name, (category, texture, repeat, uniform, mass) in ROBOSUITE.items():
            library.add(Product(f"robosuite/{name}", category, mesh=objects / "meshes" / f"{name}.obj",
                                texture=textures / texture, texrepeat=repeat, texuniform=uniform, mass=mass))
    data = package_dir("pybullet_data")
    if data is not None:
        for name, (category, mesh, texture, longest) in PYBULLET.items():
            path = data / mesh
            library.add(Product(f"pybullet/{name}", category, mesh=path, scale=float(longest / mesh_extent(path).max()),
                                texture=data / texture if texture else None, rgba=_random_colour(rng), mass=0.12))
        for product in random_shapes(data, shapes, rng):
            library.add(product)
    shapes = ["box", "cylinder", "sphere"]
    for i in range(procedural):
        shape = shapes[i % 3]
        if shape == "box":
            size = tuple(np.round(np.sort(rng.uniform(0.015, 0.05, 3))[::-1], 3).tolist())
        elif shape == "cylinder":
            size = tuple(np.round([rng.uniform(0.018, 0.035), rng.uniform(0.02, 0.05)], 3).tolist())
        else:
            size = (round(float(rng.uniform(0.02, 0.035)), 3),)
        library.add(Product(f"procedural/{shape}_{i:02d}", f"procedural_{shape}", shape=shape, size=size,
                            rgba=_random_colour(rng), mass=0.1))
    return library


PRIMITIVES = ("box", "cylinder", "sphere", "capsule", "ellipsoid")


def random_primitive(product_id: str, rng: np.random.Generator, scale: float = 1.0) -> Product:
    """A box, cylinder, sphere, capsule or ellipsoid 4–10 cm across (before ``scale``)."""
    shape = PRIMITIVES[rng.integers(len(PRIMITIVES))]
    if shape == "box":
        size = np.sort(rng.uniform(0.015, 0.05, 3))[::-1]
    elif shape == "cylinder":
        size = np.array([rng.uniform(0.018, 0.035), rng.uniform(0.02, 0.05)])
    elif shape == "sphere":
        size = np.array([rng.uniform(0.02, 0.035)])
    elif shape == "capsule":
        size = np.array([rng.uniform(0.018, 0.03), rng.uniform(0.01, 0.035)])
    else:
        size = np.sort(rng.uniform(0.02, 0.045, 3))[::-1]
    return Product(product_id, f"random_{shape}", shape=shape, size=tuple(np.round(size * scale, 4).tolist()), mass=0.1)


def random_pool_shape(product_id: str, rng: np.random.Generator, scale: float = 1.0) -> Product | None:
    """One of pybullet's 1000 random shapes (stubby ones only, see MIN_ASPECT), 5–10 cm long before
    ``scale``; None when pybullet_data is not installed."""
    data = package_dir("pybullet_data")
    if data is None:
        return None
    for _ in range(20):
        found = _stubby_shape(data, int(rng.integers(1000)))
        if found is not None:
            path, extent = found
            return Product(product_id, "random_shape", mesh=path, scale=float(rng.uniform(0.05, 0.1) * scale / extent.max()), mass=0.1)
    return None


RANDOM_ID_PREFIX = "random/"  # ids of the products that exist for one world of a randomised data set


def random_product(product_id: str, rng: np.random.Generator, seen: list[Product], pool: str,
                   scale: tuple[float, float] = (1.0, 1.0)) -> Product:
    """A "product" that exists for one world of a randomised data set: a random pybullet shape or a
    primitive with a generated texture (stripes, noise, a printed label, a material picture, ...), or
    now and then one of the ``seen`` library products (never a held-out one) at another scale."""
    from dataclasses import replace

    factor = float(rng.uniform(*scale)) if scale[1] > scale[0] else scale[0]
    draw = rng.uniform()
    if seen and draw < 0.15:
        product = seen[rng.integers(len(seen))]
        if product.mesh is not None:
            return replace(product, id=product_id, scale=product.scale * factor)
        return replace(product, id=product_id, size=tuple(s * factor for s in product.size))
    product = random_pool_shape(product_id, rng, factor) if draw < 0.6 else None
    if product is None:
        product = random_primitive(product_id, rng, factor)
    return replace(product, pattern=(int(rng.integers(2**31)), pool))

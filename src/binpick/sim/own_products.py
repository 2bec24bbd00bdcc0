"""Your own products: a YAML list next to their meshes, read once and checked (each mesh compiled in
MuJoCo, each photo opened) so that a bad entry is one line naming its file here, not an error in the
middle of data generation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from binpick.core.config import check_range
from binpick.core.errors import ConfigError
from binpick.core.files import parse_yaml, read_text
from binpick.sim.products import Product, ProductLibrary, mesh_extent


def load_products(path: str | Path, library: ProductLibrary | None = None) -> ProductLibrary:
    """Users' products: a YAML list next to their meshes, e.g.

        products:
          - {id: acme/soap, category: soap, mesh: soap.obj, texture: soap.png, longest_side: 0.09,
             mass: 0.2, friction: 1.0, photos: [soap_front.png, soap_top.png]}

    ``photos`` lists the shop's photos of the product (``photo: one.png`` for one); an order is matched
    against the best of them. Paths are relative to the YAML file. Each mesh is checked by compiling it in MuJoCo, so a bad one
    is reported with its file name here rather than in the middle of data generation."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"products file {str(path)!r} does not exist")
    text = read_text(path, "products file")
    data = parse_yaml(text, str(path)) or {}  # a key twice (``products:`` given twice), a bomb: one line
    entries = data.get("products") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{path}: expected a 'products:' list")
    library = library or ProductLibrary()
    allowed = {"id", "category", "mesh", "texture", "longest_side", "scale", "mass", "friction", "photo", "photos", "rgba", "replaces"}
    seen: set[str] = set()
    for index, entry in enumerate(entries):
        where = f"{path.name}: products[{index}]"
        if not isinstance(entry, dict) or "id" not in entry or "category" not in entry or "mesh" not in entry:
            raise ConfigError(f"{where} needs id, category and mesh")
        for key in ("id", "category"):
            value = entry[key]
            if isinstance(value, int) and not isinstance(value, bool):  # a barcode given as a number
                value = entry[key] = str(value)
            if not isinstance(value, str) or not value.strip() or len(value) > 128 or any(ord(c) < 32 for c in value):
                raise ConfigError(f"{where}.{key} must be a non-empty name of up to 128 characters on one line, got {str(value)[:40]!r}")
        if entry["id"] in seen:
            raise ConfigError(f"{where}: product id {entry['id']!r} appears twice in {path.name}: ids name one product each")
        seen.add(entry["id"])
        if entry["id"] in library.products and entry.get("replaces") is not True:
            raise ConfigError(f"{where}: product id {entry['id']!r} is a built-in product's: choose another id, or "
                              "add replaces: true to stand in for the built-in one")
        extra = sorted(set(entry) - allowed)
        if extra:
            raise ConfigError(f"{where} has no key {extra[0]!r} (allowed: {', '.join(sorted(allowed))})")
        for key in ("mesh", "texture", "photo"):
            if key in entry and not isinstance(entry[key], str):
                raise ConfigError(f"{where}.{key} must be a file name, got {entry[key]!r}")
        mesh = (path.parent / entry["mesh"]).resolve()
        if not mesh.is_file():
            raise ConfigError(f"{where}: mesh file {str(mesh)!r} does not exist")
        scale = check_range(f"{where}.scale", entry.get("scale", 1.0), 0.0, 1000.0, low_inclusive=False)
        if "longest_side" in entry:
            longest = check_range(f"{where}.longest_side", entry["longest_side"], 0.005, 0.5)
            scale = longest / float(mesh_extent(mesh).max())
        if "photo" in entry and "photos" in entry:
            raise ConfigError(f"{where}: give photo (one file) or photos (a list), not both")
        listed = [entry["photo"]] if "photo" in entry else entry.get("photos", [])
        if not isinstance(listed, list) or not all(isinstance(name, str) and name for name in listed) or len(listed) > 32:
            raise ConfigError(f"{where}.photos must be a list of up to 32 image file names, got {str(listed)[:60]!r}")
        optional: dict = {"texture": (path.parent / entry["texture"]).resolve()} if entry.get("texture") else {}
        files = {**({"texture": optional["texture"]} if optional else {}),
                 **{f"photos[{i}]": (path.parent / name).resolve() for i, name in enumerate(listed)}}
        for key, file in files.items():
            if not file.is_file():
                raise ConfigError(f"{where}: {key} file {str(file)!r} does not exist")
            read_photo(file)  # an image PIL cannot read is reported now, not after the scenes are made
        if listed:
            optional["photos"] = tuple((path.parent / name).resolve() for name in listed)
        rgba = entry.get("rgba", (0.8, 0.8, 0.8, 1.0))
        if not isinstance(rgba, (list, tuple)) or len(rgba) != 4:
            raise ConfigError(f"{where}.rgba must be 4 numbers in [0, 1], got {rgba!r}")
        rgba = tuple(check_range(f"{where}.rgba[{i}]", v, 0.0, 1.0) for i, v in enumerate(rgba))
        product = Product(str(entry["id"]), str(entry["category"]), mesh=mesh, scale=scale,
                          mass=check_range(f"{where}.mass", entry.get("mass", 0.15), 0.001, 100.0),
                          friction=check_range(f"{where}.friction", entry.get("friction", 1.0), 0.0, 10.0),
                          rgba=rgba, **optional)
        check_product_compiles(product)
        library.add(product)
    return library


def read_photo(path: Path):
    """RGB uint8 (H, W, 3) of a user's image file; one line naming the file if it cannot be read."""
    from binpick.core.files import opened_image

    with opened_image(path, "image") as image:
        return np.asarray(image.convert("RGB"))


def check_product_compiles(product: Product) -> None:
    """Compile the product alone in MuJoCo: a bad mesh names its file in one line."""
    import mujoco

    from binpick.sim.mjcf import product_assets, product_body

    xml = (f"<mujoco><asset>{product_assets(product, 'p')}</asset><worldbody>"
           f"{product_body(product, 'p', (0, 0, 0.1), (1, 0, 0, 0))}</worldbody></mujoco>")
    try:
        mujoco.MjModel.from_xml_string(xml)
    except Exception as error:  # noqa: BLE001 - MuJoCo raises ValueError with a long message
        raise ConfigError(f"mesh {str(product.mesh)!r} cannot be used: {str(error).splitlines()[0]}") from None
    extent = mesh_extent(product.mesh) * product.scale if product.mesh else None
    if extent is not None and not 0.005 < extent.max() < 0.5:
        raise ConfigError(f"mesh {str(product.mesh)!r} is {extent.max():.3f} m across after scaling; "
                          "set longest_side (metres) for it")

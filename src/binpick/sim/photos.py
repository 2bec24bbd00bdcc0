"""Shop photos (thesis §6.3): each product alone on a studio background — the external conditioning
image of an order.

:func:`shop_photo` renders the canonical photo (white studio, one key light, seen from 45°). A
warehouse's photos come from other studios: :func:`random_photo_style` draws a style (light level,
direction and colour, background colour or texture, viewpoint, how large the product is framed, a
cut-out RGBA or not) so a detector trained on randomised photos does not learn one studio's look.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from binpick.sim.mjcf import product_assets, product_geom
from binpick.sim.products import RANDOM_ID_PREFIX, Product
from binpick.sim.rendering import renderer as shared_renderer


@dataclass(frozen=True)
class PhotoStyle:
    """How one shop photo is taken. The defaults are the canonical studio photo."""

    azimuth: float = 135.0  # degrees about the vertical
    elevation: float = -35.0  # degrees (negative: looking down)
    distance: float = 3.2  # camera distance in the product's half-diagonals (smaller: framed larger)
    ambient: float = 0.5  # headlight ambient level
    diffuse: float = 0.4  # headlight diffuse level
    key: float = 0.5  # key light level
    key_direction: tuple[float, float, float] = (-0.3, 0.4, -1.0)
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)  # light colour
    background: tuple[float, float, float] = (0.97, 0.97, 0.97)
    background_seed: int | None = None  # a generated texture on the studio floor (None: plain)
    cut_out: bool = False  # RGBA, alpha marking the product's pixels (a shop's cut-out PNG)


CANONICAL = PhotoStyle()
# the views of each built-in product an order gives: the canonical photo and one from nearly above
CATALOGUE_VIEWS = (CANONICAL, PhotoStyle(azimuth=45.0, elevation=-70.0, distance=3.0))


def catalogue_photos(product: Product, size: int = 256) -> list[tuple[np.ndarray, np.ndarray]]:
    """(photo, product mask) for each of :data:`CATALOGUE_VIEWS`."""
    return [shop_photo(product, size, with_mask=True, style=style) for style in CATALOGUE_VIEWS]


def random_photo_style(rng: np.random.Generator) -> PhotoStyle:
    """A studio drawn at random: half the photos on a light plain background (as most shops), the rest
    on any colour or a texture; warm to cool light, dim to bright; side to near-top views."""
    light = rng.uniform(0.5, 1.4)
    kind = rng.uniform()
    if kind < 0.5:
        background = tuple(float(v) for v in np.clip(rng.uniform(0.85, 1.0) + rng.normal(0, 0.02, 3), 0, 1))
    else:
        background = tuple(float(v) for v in rng.uniform(0.05, 0.95, 3))
    tint = np.clip(np.array([1.0, 1.0, 1.0]) + rng.normal(0, 0.12, 3), 0.6, 1.0)
    direction = (rng.uniform(-1, 1), rng.uniform(-1, 1), -rng.uniform(0.5, 1.5))
    return PhotoStyle(azimuth=float(rng.uniform(0, 360)), elevation=float(rng.uniform(-80, -15)),
                      distance=float(rng.uniform(2.4, 4.5)), ambient=float(0.5 * light * rng.uniform(0.5, 1.2)),
                      diffuse=float(0.4 * light * rng.uniform(0.6, 1.3)), key=float(0.5 * light * rng.uniform(0.4, 1.4)),
                      key_direction=tuple(float(v) for v in direction), tint=tuple(float(v) for v in tint),
                      background=background, background_seed=int(rng.integers(2**31)) if kind >= 0.8 else None,
                      cut_out=bool(rng.uniform() < 0.3))


def _fmt(values) -> str:
    return " ".join(f"{float(v):.4g}" for v in values)


def shop_photo(product: Product, size: int = 256, with_mask: bool = False, style: PhotoStyle = CANONICAL):
    """(size, size, 3) uint8: the product resting upright on the studio floor, taken as ``style`` says
    ((size, size, 4) for a cut-out style, alpha 255 on the product). With ``with_mask``, also the
    (size, size) bool mask of the product's pixels.

    A photo is rendered once per process and copied after that (:data:`PHOTO_CACHE` of them): the same
    product in the same studio is the same picture, and every data set, order and export takes every
    product's photos again. Most of a photo's cost is the renderer's set-up (its textures uploaded), not
    the picture. A product whose mesh or texture file changed on disk is rendered again."""
    files = tuple((str(path), *_stamp(path)) for path in (product.mesh, product.texture) if path is not None)
    photo = _cached_photo(product, size, with_mask, style, files)
    return tuple(part.copy() for part in photo) if isinstance(photo, tuple) else photo.copy()


PHOTO_CACHE = 256  # photos kept per process (a 256 px cut-out and its mask: about 330 kB; 85 MB at most)


def _stamp(path: Path) -> tuple[int, int]:
    try:
        stat = Path(path).stat()
    except OSError:  # rendering says what is missing
        return (-1, -1)
    return (stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=PHOTO_CACHE)
def _cached_photo(product: Product, size: int, with_mask: bool, style: PhotoStyle, files: tuple):
    kept = _kept_on_disk(product, size, with_mask, style, files)
    photo = kept.read() if kept is not None else None
    if photo is None:
        photo = _render_photo(product, size, with_mask, style)
        if kept is not None:
            kept.write(photo)
    for part in photo if isinstance(photo, tuple) else (photo,):
        part.setflags(write=False)  # what the cache holds is never handed out itself
    return photo


# what a photo's pixels depend on besides its product and style: the renderer and binpick's scene code
RENDERING_CODE = ("photos.py", "mjcf.py", "mjcf_mesh.py", "domain.py", "products.py")


@functools.cache
def _rendering_digest() -> str:
    import hashlib

    digest = hashlib.sha256(f"{mujoco.__version__} {os.environ.get('MUJOCO_GL', '')}".encode())  # the GL backend rasterises
    for name in RENDERING_CODE:
        path = Path(__file__).with_name(name)
        digest.update(path.read_bytes() if path.is_file() else name.encode())
    return digest.hexdigest()[:16]


class _DiskPhoto:
    """A catalogue photo kept in binpick's cache folder (``photos``), so that other processes (each data
    set made, each order run) read it instead of rendering it again. Its name is the digest of all the
    picture depends on: the product (its files' sizes and times), the style, the size, MuJoCo's version
    and binpick's rendering code. A file that cannot be read is rendered again and replaced."""

    def __init__(self, path: Path, with_mask: bool) -> None:
        self.path, self.with_mask = path, with_mask

    def read(self):
        from binpick.core.errors import BinpickError
        from binpick.core.files import read_npz

        try:
            if not self.path.is_file():  # (a folder it may not search raises here too)
                return None
            arrays = read_npz(self.path, "cached photo")
            image = arrays["image"]
            return (image, arrays["mask"].astype(bool)) if self.with_mask else image
        except (BinpickError, KeyError, OSError, ValueError):
            return None

    def write(self, photo) -> None:
        import io

        from binpick.core.errors import BinpickError
        from binpick.core.files import atomic_write_bytes

        image, mask = photo if self.with_mask else (photo, None)
        buffer = io.BytesIO()
        np.savez_compressed(buffer, image=image, **({"mask": mask} if mask is not None else {}))
        try:
            atomic_write_bytes(self.path, buffer.getvalue())
        except (BinpickError, OSError):  # a read-only or full cache folder: the photo is only not kept
            pass


def _kept_on_disk(product: Product, size: int, with_mask: bool, style: PhotoStyle, files: tuple) -> _DiskPhoto | None:
    """Where a catalogue photo (a catalogue view of a product with its own files or a primitive shape) is
    kept; None for others: a randomised studio, or a domain-randomised product, is taken once."""
    if style not in CATALOGUE_VIEWS or product.pattern is not None or product.id.startswith(RANDOM_ID_PREFIX):
        return None
    import hashlib

    from binpick.core.files import cache_folder

    key = repr((product, size, with_mask, style, files, _rendering_digest()))
    return _DiskPhoto(cache_folder("photos") / f"{hashlib.sha256(key.encode()).hexdigest()[:32]}.npz", with_mask)


def _render_photo(product: Product, size: int, with_mask: bool, style: PhotoStyle):
    tint = np.asarray(style.tint)
    floor_texture = ('<texture name="studio_tex" type="2d" builtin="flat" rgb1="1 1 1" width="64" height="64"/>'
                     '<material name="studio" texture="studio_tex" texrepeat="4 4" rgba="1 1 1 1"/>'
                     if style.background_seed is not None else f'<material name="studio" rgba="{_fmt(style.background)} 1"/>')
    xml = f"""<mujoco><visual><global offwidth="{size}" offheight="{size}"/><quality shadowsize="2048"/>
  <headlight ambient="{_fmt(tint * style.ambient)}" diffuse="{_fmt(tint * style.diffuse)}"/></visual>
  <asset>{floor_texture}{product_assets(product, 'p')}</asset>
  <worldbody><light pos="{_fmt(-np.asarray(style.key_direction))}" dir="{_fmt(style.key_direction)}" diffuse="{_fmt(tint * style.key)}" castshadow="true"/>
    <geom type="plane" size="0 0 0.05" material="studio"/>
    <body name="product" pos="0 0 0.3">{product_geom(product, 'p')}</body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    _fill_patterns(model, product, style)
    data = mujoco.MjData(model)
    body = model.body("product").id
    geom = np.flatnonzero(model.geom_bodyid == body)[0]
    mujoco.mj_forward(model, data)

    def world_box() -> tuple[np.ndarray, np.ndarray]:  # centre and half-size of the world-aligned box
        rotation = data.geom_xmat[geom].reshape(3, 3)
        return data.geom_xpos[geom] + rotation @ model.geom_aabb[geom, :3], np.abs(rotation) @ model.geom_aabb[geom, 3:]

    centre, half = world_box()
    model.body_pos[body, 2] -= centre[2] - half[2] - 0.0005  # rest it on the floor
    mujoco.mj_forward(model, data)
    centre, half = world_box()
    extent = float(np.linalg.norm(half))
    renderer = shared_renderer(model, size, size)
    try:
        camera = mujoco.MjvCamera()
        camera.lookat[:] = centre
        camera.distance = style.distance * extent + 0.05
        camera.azimuth, camera.elevation = style.azimuth, style.elevation
        renderer.update_scene(data, camera=camera)
        rgb = renderer.render().copy()
        if not (with_mask or style.cut_out):
            return rgb
        renderer.enable_segmentation_rendering()
        segmentation = renderer.render()
        mine = np.flatnonzero(model.geom_bodyid == body)
        mask = np.isin(segmentation[..., 0], mine) & (segmentation[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM))
        image = np.dstack([rgb, np.where(mask, 255, 0).astype(np.uint8)]) if style.cut_out else rgb
        return (image, mask) if with_mask else image
    finally:
        renderer.close()


def _fill_patterns(model, product: Product, style: PhotoStyle) -> None:
    """Generated textures are pixels filled after compiling: the product's own (domain-randomised
    products) and the studio floor's."""
    from binpick.sim.domain import fill_texture, pattern

    if product.pattern is not None:
        fill_texture(model, model.texture("p_tex").id, pattern(np.random.default_rng(product.pattern[0]), product.pattern[1]))
    if style.background_seed is not None:
        fill_texture(model, model.texture("studio_tex").id, pattern(np.random.default_rng(style.background_seed), "train"))

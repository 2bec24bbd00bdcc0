"""Domain randomisation for bin scenes (Tobin et al. 2017; Tremblay et al. 2018): the ranges a
generator draws each world's and each scene's look from, so a detector learns repeated objects
rather than binpick's one renderer.

A :class:`DomainConfig` is a validated set of ranges (``[low, high]``, drawn uniformly). Three ways
to name one: ``default`` (today's fixed scene, so the thesis tables stay reproducible), ``random``
(the training ranges, ``binpick/sim/domains/random.yaml``) or a YAML file of one's own — for example
``binpick/sim/domains/shifted.yaml``, whose camera, tote and light values lie outside the training
ranges (the shifted-domain test set).

What varies per *world* (one compiled MuJoCo model): tote size and wall height, tote and table
textures, how many lights, the products and their textures and scales. Per *scene* (runtime model
fields, no recompiling): camera pose and intrinsics, light directions, colours and intensities,
ambient light, shadows, colour tints, clutter outside the tote. Per *image*, after rendering:
exposure, noise, blur and JPEG artefacts (where a domain asks for them; training applies its own in
the loader, where it is cheaper).
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, fields
from functools import lru_cache
from pathlib import Path

import numpy as np

from binpick.core.config import check_pair, check_range, load_named, ranges_dict
from binpick.core.errors import ConfigError

DOMAINS_DIR = Path(__file__).resolve().parent / "domains"  # the committed domains ship with the package
TEXTURE_SIZE = 64  # side of each generated texture face (pixels)
# robosuite's material textures; its product pictures (soda, cereal, ...) are left out so that no
# random product borrows the look of a held-out one
TRAIN_TEXTURES = ("brass-ambra", "clay", "cream-plaster", "dirt", "gray-felt", "gray-plaster", "gray-woodgrain",
                  "green-wood", "light-wood", "metal", "pink-plaster", "red-wood", "steel-brushed",
                  "steel-scratched", "white-plaster", "wood-varnished-panels", "yellow-plaster")
SHIFTED_TEXTURES = ("blue-wood", "dark-wood", "light-gray-floor-tile", "light-gray-plaster", "white-bricks", "wood-tiles")
PATTERNS = ("flat", "stripes", "checker", "noise", "label", "dots", "image")


# name: (low, high) bounds every range of that field must stay within
_BOUNDS = {
    "camera_height": (0.3, 3.0), "camera_tilt": (0.0, 70.0), "camera_yaw": (-180.0, 180.0), "camera_fovy": (15.0, 100.0),
    "principal_offset": (-0.2, 0.2), "look_offset": (-0.15, 0.15),
    "tote_half_x": (0.1, 0.35), "tote_half_y": (0.08, 0.3), "wall_height": (0.03, 0.3),
    "lights": (1, 3), "light_intensity": (0.0, 3.0), "light_elevation": (10.0, 90.0), "light_colour": (0.0, 1.0),
    "ambient": (0.0, 1.0), "shadows": (0.0, 1.0), "clutter": (0, 4),
    "product_scale": (0.3, 3.0), "product_colour": (0.0, 1.0),
    "exposure": (0.2, 5.0), "noise": (0.0, 60.0), "blur": (0.0, 5.0), "jpeg_quality": (5, 100),
}


@dataclass(frozen=True)
class DomainConfig:
    """Ranges ``[low, high]`` for everything a bin image's look depends on. Angles in degrees,
    lengths in metres. ``randomise: false`` means today's fixed scene whatever the ranges say."""

    name: str = "default"
    randomise: bool = False
    # camera, per scene: height of the camera above the table, tilt away from straight down, yaw of
    # the view about the vertical, vertical field of view, principal-point offset (fraction of the
    # image side, each axis) and where it aims (metres from the tote centre, each axis)
    camera_height: tuple[float, float] = (0.85, 0.85)
    camera_tilt: tuple[float, float] = (0.0, 0.0)
    camera_yaw: tuple[float, float] = (0.0, 0.0)
    camera_fovy: tuple[float, float] = (42.0, 42.0)
    principal_offset: tuple[float, float] = (0.0, 0.0)
    look_offset: tuple[float, float] = (0.0, 0.0)
    # tote and surroundings, per world
    tote_half_x: tuple[float, float] = (0.21, 0.21)
    tote_half_y: tuple[float, float] = (0.16, 0.16)
    wall_height: tuple[float, float] = (0.14, 0.14)
    textures: str = "train"  # which texture pool totes, tables and products draw from: train | shifted
    clutter: tuple[int, int] = (0, 0)  # objects on the table outside the tote, per scene
    # light, per scene (the number of lights per world)
    lights: tuple[int, int] = (1, 1)
    light_intensity: tuple[float, float] = (0.7, 0.7)
    light_elevation: tuple[float, float] = (80.0, 90.0)
    light_colour: tuple[float, float] = (0.0, 0.0)  # per-channel jitter of each light's colour
    light_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)  # a colour all lights share
    ambient: tuple[float, float] = (0.35, 0.35)
    shadows: float = 1.0  # probability that a light casts shadows
    # products: scale per world, colour jitter per scene
    product_scale: tuple[float, float] = (1.0, 1.0)
    product_colour: tuple[float, float] = (0.0, 0.0)
    random_products: bool = False  # each world's products drawn from the random pool with random textures
    # per image, after rendering (for test sets; training augments in the loader)
    exposure: tuple[float, float] = (1.0, 1.0)
    noise: tuple[float, float] = (0.0, 0.0)  # Gaussian noise std, 0..255 scale
    blur: tuple[float, float] = (0.0, 0.0)  # Gaussian blur sigma, pixels
    jpeg_quality: tuple[int, int] = (100, 100)  # 100: no compression

    def __post_init__(self) -> None:
        for item in fields(self):
            if item.name in _BOUNDS:
                low, high = _BOUNDS[item.name]
                if item.name == "shadows":
                    object.__setattr__(self, item.name, float(check_range(item.name, self.shadows, low, high)))
                    continue
                value = check_pair(item.name, getattr(self, item.name), low, high)
                if item.name in ("lights", "clutter", "jpeg_quality"):
                    if not all(float(v).is_integer() for v in value):
                        raise ConfigError(f"{item.name} must be a range of integers, got {list(value)}")
                    value = tuple(int(v) for v in value)
                object.__setattr__(self, item.name, value)
        tint = self.light_tint
        if not isinstance(tint, (list, tuple)) or len(tint) != 3:
            raise ConfigError(f"light_tint must be 3 numbers (r, g, b), got {tint!r}")
        object.__setattr__(self, "light_tint", tuple(float(check_range(f"light_tint[{i}]", v, 0.0, 2.0)) for i, v in enumerate(tint)))
        if self.textures not in ("train", "shifted"):
            raise ConfigError(f"textures must be 'train' or 'shifted', got {self.textures!r}")

    @property
    def post_processing(self) -> bool:
        return self.randomise and (self.exposure != (1.0, 1.0) or self.noise[1] > 0 or self.blur[1] > 0 or self.jpeg_quality[0] < 100)


def load_domain(name: str | Path) -> DomainConfig:
    """``default``, ``random``, ``shifted`` (the committed files) or the path of a YAML file."""
    return load_named(DomainConfig, name, DOMAINS_DIR, "default", "domain")


def domain_dict(domain: DomainConfig) -> dict:
    """JSON form (recorded in a data set's manifest and in weights trained on it)."""
    return ranges_dict(domain)


# ---------------------------------------------------------------------- draws
def uniform(rng: np.random.Generator, pair: tuple[float, float]) -> float:
    return float(rng.uniform(pair[0], pair[1])) if pair[1] > pair[0] else float(pair[0])


def integer(rng: np.random.Generator, pair: tuple[int, int]) -> int:
    return int(rng.integers(pair[0], pair[1] + 1))


@dataclass(frozen=True)
class CameraDraw:
    """One scene's camera: position, orientation (MuJoCo quaternion, camera looks along its -z) and
    intrinsics (fx, fy, cx, cy) in pixels for a square image of ``size``."""

    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    fovy: float
    principal: tuple[float, float]  # offset of the principal point from the image centre, pixels
    size: int

    def intrinsics(self) -> tuple[float, float, float, float]:
        f = 0.5 * self.size / math.tan(math.radians(self.fovy) / 2)
        centre = (self.size - 1) / 2
        return f, f, centre + self.principal[0], centre + self.principal[1]

    def extrinsics(self) -> list[list[float]]:
        """4×4 camera-to-world transform in the OpenCV convention (x right, y down, z forward)."""
        import mujoco

        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, np.array(self.quaternion))
        rotation = rotation.reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])  # MuJoCo camera: y up, looks along -z
        transform = np.eye(4)
        transform[:3, :3], transform[:3, 3] = rotation, self.position
        return np.round(transform, 6).tolist()


def draw_camera(domain: DomainConfig, rng: np.random.Generator, size: int, floor_top: float) -> CameraDraw:
    """A camera ``camera_height`` above the table, tilted and yawed, aimed near the tote floor."""
    height, tilt = uniform(rng, domain.camera_height), math.radians(uniform(rng, domain.camera_tilt))
    yaw, fovy = math.radians(uniform(rng, domain.camera_yaw)), uniform(rng, domain.camera_fovy)
    look = np.array([uniform(rng, domain.look_offset), uniform(rng, domain.look_offset), floor_top])
    heading = rng.uniform(0, 2 * math.pi)  # the side the camera leans from
    distance = (height - floor_top) / math.cos(tilt)
    position = look + distance * np.array([math.sin(tilt) * math.cos(heading), math.sin(tilt) * math.sin(heading), math.cos(tilt)])
    forward = (look - position) / np.linalg.norm(look - position)
    # image "up" starts as the world's +y seen from above, turned by yaw about the view axis
    up_hint = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
    right = np.cross(forward, up_hint)
    if np.linalg.norm(right) < 1e-6:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    import mujoco

    matrix = np.stack([right, up, -forward], axis=1)  # columns: camera x, y, z in the world
    quaternion = np.zeros(4)
    mujoco.mju_mat2Quat(quaternion, matrix.ravel())
    principal = tuple(float(uniform(rng, domain.principal_offset) * size) for _ in range(2))
    return CameraDraw(tuple(position.tolist()), tuple(quaternion.tolist()), fovy, principal, size)


def apply_camera(model, camera_id: int, draw: CameraDraw, sensor: float = 0.01) -> None:
    """Write a camera draw into the model's runtime camera fields (a camera declared with
    ``sensorsize``, so its intrinsics come from ``cam_intrinsic``)."""
    model.cam_pos[camera_id] = draw.position
    model.cam_quat[camera_id] = draw.quaternion
    focal = 0.5 * sensor / math.tan(math.radians(draw.fovy) / 2)
    # MuJoCo's principal point is in sensor units, measured against the image axes: negate both
    model.cam_intrinsic[camera_id] = [focal, focal, -draw.principal[0] / draw.size * sensor, -draw.principal[1] / draw.size * sensor]


def draw_lights(domain: DomainConfig, rng: np.random.Generator, model, count: int) -> None:
    """Directions, colours, intensities and shadows of the world's ``count`` lights; ambient light."""
    tint = np.array(domain.light_tint)
    for light in range(model.nlight):
        active = light < count
        model.light_active[light] = active
        if not active:
            continue
        elevation, azimuth = math.radians(uniform(rng, domain.light_elevation)), rng.uniform(0, 2 * math.pi)
        direction = -np.array([math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation)])
        model.light_dir[light] = direction
        model.light_pos[light] = -direction * 1.6
        colour = tint * (1 + rng.uniform(-1, 1, 3) * uniform(rng, domain.light_colour))
        model.light_diffuse[light] = np.clip(colour * uniform(rng, domain.light_intensity) / count, 0, 1.5)
        model.light_specular[light] = 0.1
        model.light_castshadow[light] = rng.uniform() < domain.shadows
    ambient = uniform(rng, domain.ambient)
    model.vis.headlight.ambient[:] = np.clip(ambient * tint, 0, 1)
    model.vis.headlight.diffuse[:] = np.clip(0.15 * ambient * tint, 0, 1)


# ---------------------------------------------------------------------- textures
@lru_cache(maxsize=64)
def _texture_image(path: str, size: int) -> np.ndarray:
    from PIL import Image

    from binpick.core.files import opened_image

    with opened_image(path, "texture") as image:
        return np.asarray(image.convert("RGB").resize((size * 2, size * 2), Image.BILINEAR))


def texture_files(pool: str) -> list[Path]:
    """robosuite's material textures of a pool (none if robosuite's assets are absent)."""
    from binpick.sim.products import package_dir

    root = package_dir("robosuite")
    if root is None:
        return []
    folder = root / "models" / "assets" / "textures"
    names = TRAIN_TEXTURES if pool == "train" else SHIFTED_TEXTURES
    return [folder / f"{name}.png" for name in names if (folder / f"{name}.png").is_file()]


def random_colour(rng: np.random.Generator, low: float = 0.05, high: float = 0.95) -> np.ndarray:
    return rng.uniform(low, high, 3)


def pattern(rng: np.random.Generator, pool: str, size: int = TEXTURE_SIZE, kind: str | None = None) -> np.ndarray:
    """A (size, size, 3) uint8 texture: flat, stripes, checker, noise, a printed label, dots, or a
    crop of one of the pool's material pictures."""
    kind = kind or PATTERNS[rng.integers(len(PATTERNS))]
    a, b = random_colour(rng) * 255, random_colour(rng) * 255
    ys, xs = np.mgrid[0:size, 0:size].astype(np.float32)
    if kind == "image":
        files = texture_files(pool)
        if files:
            image = _texture_image(str(files[rng.integers(len(files))]), size)
            x, y = rng.integers(0, size + 1, 2)
            tint = rng.uniform(0.6, 1.2, 3)
            return np.clip(image[y:y + size, x:x + size] * tint, 0, 255).astype(np.uint8)
        kind = "noise"
    if kind == "flat":
        weight = np.zeros((size, size))
    elif kind == "stripes":
        angle, period = rng.uniform(0, np.pi), rng.uniform(4, 20)
        weight = (np.sin((xs * np.cos(angle) + ys * np.sin(angle)) * 2 * np.pi / period) > 0).astype(np.float32)
    elif kind == "checker":
        cell = int(rng.integers(4, 17))
        weight = ((xs // cell + ys // cell) % 2).astype(np.float32)
    elif kind == "noise":
        coarse = rng.uniform(0, 1, (int(rng.integers(3, 12)),) * 2)
        from PIL import Image

        weight = np.asarray(Image.fromarray((coarse * 255).astype(np.uint8)).resize((size, size), Image.BICUBIC), dtype=np.float32) / 255
    elif kind == "dots":
        cell, radius = rng.uniform(6, 16), rng.uniform(1.5, 4)
        weight = (((xs % cell) - cell / 2) ** 2 + ((ys % cell) - cell / 2) ** 2 < radius ** 2).astype(np.float32)
    else:  # label: a band of another colour with a few dark "print" bars on it
        weight = np.zeros((size, size), dtype=np.float32)
        top, height = int(rng.integers(0, size // 2)), int(rng.integers(size // 5, size // 2))
        weight[top:top + height] = 1.0
        for _ in range(int(rng.integers(2, 6))):
            x0, w = int(rng.integers(0, size - 8)), int(rng.integers(3, 12))
            y0 = int(rng.integers(top, top + max(1, height - 4)))
            weight[y0:y0 + 3, x0:x0 + w] = 2.0
    colour = a[None, None] * (1 - np.clip(weight, 0, 1)[..., None]) + b[None, None] * np.clip(weight, 0, 1)[..., None]
    colour = np.where((weight > 1.5)[..., None], 25.0, colour)
    return colour.astype(np.uint8)


def fill_texture(model, texture_id: int, image: np.ndarray) -> None:
    """Overwrite a compiled texture's pixels (every face of a cube texture) before a renderer is made."""
    width, height = int(model.tex_width[texture_id]), int(model.tex_height[texture_id])
    channels = int(model.tex_nchannel[texture_id])
    start = int(model.tex_adr[texture_id])
    faces = height // width if height >= width else 1
    from PIL import Image

    face = np.asarray(Image.fromarray(image).resize((width, width if faces > 1 else height), Image.BILINEAR))
    data = np.concatenate([face] * faces, axis=0) if faces > 1 else face
    if channels == 4:
        data = np.concatenate([data, np.full(data.shape[:2] + (1,), 255, np.uint8)], axis=2)
    model.tex_data[start:start + data.size] = data.reshape(-1)


# ---------------------------------------------------------------------- images
def post_process(image: np.ndarray, domain: DomainConfig, rng: np.random.Generator) -> np.ndarray:
    """Exposure, sensor noise, blur and JPEG artefacts on a rendered image (uint8 RGB)."""
    from PIL import Image, ImageFilter

    out = image.astype(np.float32) * uniform(rng, domain.exposure)
    noise = uniform(rng, domain.noise)
    if noise > 0:
        out = out + rng.normal(0, noise, out.shape)
    result = Image.fromarray(np.clip(out, 0, 255).astype(np.uint8))
    blur = uniform(rng, domain.blur)
    if blur > 0.05:
        result = result.filter(ImageFilter.GaussianBlur(blur))
    quality = integer(rng, domain.jpeg_quality)
    if quality < 100:
        buffer = io.BytesIO()
        result.save(buffer, format="JPEG", quality=quality)
        buffer.seek(0)
        result = Image.open(buffer).convert("RGB")
    return np.asarray(result)

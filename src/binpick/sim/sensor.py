"""Depth as a real RGB-D sensor gives it: missing readings, noise, edges, quantisation, a tilted
camera and a tote that is not quite level.

The renderer's depth is perfect: every pixel read, exact, a camera straight above a level tote. A
structured-light or active-stereo camera differs in ways a grasp planner must survive:

- **missing readings** where the projector (or the second camera), offset from the camera by a
  baseline, cannot see the surface: a shadow beside every tall edge, on the side away from the
  projector (:func:`projector_shadow`); on dark, specular or transparent-looking surfaces and at grazing
  angles; in a band at the image border; and in random blobs;
- **axial noise** growing with distance (Nguyen, Izadi & Lovell 2012: sigma(z) = 1.2 mm +
  1.9 mm (z - 0.4 m)^2 for a structured-light sensor), **lateral noise** that moves edges by a pixel,
  **flying pixels** between foreground and background at depth edges, and **quantisation** of the
  disparity the sensor measures (and of the millimetres its 16-bit frame holds);
- **misregistration** of depth against colour by a pixel or two;
- the **camera tilted** away from straight down and the **tote tilted** a few degrees, with the
  calibration of the camera recorded beside the scene as a real set-up's would be.

A :class:`SensorConfig` holds ranges ``[low, high]`` drawn per scene (per world for the tote's
tilt). ``perfect`` keeps today's rendering bit for bit; ``realistic`` (``sensors/realistic.yaml``)
is a structured-light camera over a bin; a YAML file of one's own describes another sensor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from binpick.core.config import check_pair, load_named, ranges_dict
from binpick.core.errors import ConfigError
from binpick.sim.domain import uniform as _draw

SENSORS_DIR = Path(__file__).resolve().parent / "sensors"

# name: (low, high) every range of that field must stay within
_BOUNDS = {
    "baseline": (0.0, 0.3), "shadow_tolerance": (0.0, 5.0), "dark_level": (0.0, 1.0), "dark_dropout": (0.0, 1.0),
    "specular_level": (0.0, 1.0), "specular_dropout": (0.0, 1.0), "grazing_angle": (30.0, 90.0),
    "hard_instances": (0.0, 1.0), "hard_dropout": (0.0, 1.0), "border": (0, 100), "dropout": (0.0, 0.9),
    "blob_size": (1.0, 200.0), "noise_scale": (0.0, 10.0), "lateral_noise": (0.0, 5.0), "flying_pixels": (0.0, 1.0),
    "subpixel": (1, 64), "misregistration": (0, 10), "camera_tilt": (0.0, 45.0), "tote_tilt": (0.0, 5.0),
}
_INTEGER = ("border", "subpixel", "misregistration")


@dataclass(frozen=True)
class SensorConfig:
    """Ranges ``[low, high]`` of what a depth sensor does to the scene it sees (lengths in metres,
    angles in degrees, shares in [0, 1]). ``realistic: false`` means perfect depth, whatever the
    ranges say."""

    name: str = "perfect"
    realistic: bool = False
    # the projector (structured light) or second camera (stereo), offset along the camera's x axis
    baseline: tuple[float, float] = (0.05, 0.08)
    projector_side: str = "random"  # left | right | random: where the projector sits
    shadow_tolerance: tuple[float, float] = (0.5, 0.5)  # pixels of disparity before a point counts as hidden
    # surfaces the sensor cannot read: dark (colour luminance below dark_level), specular (above
    # specular_level), seen at more than grazing_angle from their normal, and whole instances of
    # dark/shiny material (hard_instances: the chance an instance is one; hard_dropout: the share of
    # its pixels lost)
    dark_level: tuple[float, float] = (0.08, 0.12)
    dark_dropout: tuple[float, float] = (0.5, 0.9)
    specular_level: tuple[float, float] = (0.97, 0.99)
    specular_dropout: tuple[float, float] = (0.5, 0.9)
    grazing_angle: tuple[float, float] = (75.0, 82.0)
    hard_instances: tuple[float, float] = (0.1, 0.2)
    hard_dropout: tuple[float, float] = (0.3, 0.7)
    border: tuple[int, int] = (2, 10)  # pixels lost at the image border (twice as many on the side away from the projector)
    dropout: tuple[float, float] = (0.0, 0.03)  # share of the image lost in random blobs
    blob_size: tuple[float, float] = (3.0, 12.0)  # their size in pixels
    # noise: sigma(z) = noise_scale * (1.2 mm + 1.9 mm (z - 0.4 m)^2)
    noise_scale: tuple[float, float] = (0.8, 1.5)
    lateral_noise: tuple[float, float] = (0.3, 0.7)  # pixels: edges move by about this much
    flying_pixels: tuple[float, float] = (0.2, 0.5)  # share of depth-edge pixels read between the two sides
    subpixel: tuple[int, int] = (8, 8)  # disparity measured in 1/subpixel pixels
    misregistration: tuple[int, int] = (0, 2)  # pixels between depth and colour
    # the set-up: camera tilt from straight down (a domain that draws its own camera keeps it) and
    # the tote's tilt from level
    camera_tilt: tuple[float, float] = (0.0, 0.0)
    tote_tilt: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        for item in fields(self):
            if item.name in _BOUNDS:
                low, high = _BOUNDS[item.name]
                object.__setattr__(self, item.name, check_pair(item.name, getattr(self, item.name), low, high, item.name in _INTEGER))
        if self.projector_side not in ("left", "right", "random"):
            raise ConfigError(f"projector_side must be one of 'left', 'right', 'random', got {self.projector_side!r}")

    @property
    def tilts_camera(self) -> bool:
        return self.realistic and self.camera_tilt[1] > 0

    @property
    def tilts_tote(self) -> bool:
        return self.realistic and self.tote_tilt[1] > 0


def load_sensor(name: str | Path) -> SensorConfig:
    """``perfect``, ``realistic`` (the committed files) or the path of a sensor YAML file."""
    return load_named(SensorConfig, name, SENSORS_DIR, "perfect", "sensor")


def sensor_dict(sensor: SensorConfig) -> dict:
    """JSON form (a data set's manifest records the sensor it was made with)."""
    return ranges_dict(sensor)


def tote_tilt(sensor: SensorConfig, rng: np.random.Generator) -> tuple[float, float]:
    """The tote's tilt as rotations (radians) about the world's x and y axes: a tilt from the
    sensor's range, about a horizontal axis of random heading."""
    if not sensor.tilts_tote:
        return 0.0, 0.0
    tilt, heading = math.radians(_draw(rng, sensor.tote_tilt)), rng.uniform(0, 2 * math.pi)
    return tilt * math.cos(heading), tilt * math.sin(heading)


def axial_sigma(z: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Nguyen, Izadi & Lovell (2012): a structured-light sensor's axial noise (m) at depth ``z`` (m)."""
    return scale * (0.0012 + 0.0019 * (z - 0.4) ** 2)


def projector_shadow(depth: np.ndarray, fx: float, baseline: float, side: int, tolerance: float = 0.5) -> np.ndarray:
    """Pixels the projector cannot light (True), for a projector ``baseline`` metres along the camera's
    x axis (``side`` +1: to the image's right, -1: left), rows being epipolar lines. A point's
    projector column is u - side * fx * b / z; a nearer point on the same projector ray appears
    further towards the projector's side, so a pixel is in shadow when some pixel on that side of its
    row maps to the same projector column or beyond."""
    z = np.where(depth > 0, depth, np.inf).astype(np.float64)
    u = np.arange(depth.shape[1], dtype=np.float64)[None, :]
    column = u - side * fx * baseline / z  # inf depth: column = u, never an occluder of anything
    if side > 0:  # occluders lie to the right: compare with the smallest projector column right of each pixel
        right = np.minimum.accumulate(column[:, ::-1], axis=1)[:, ::-1]
        beyond = np.concatenate([right[:, 1:], np.full((depth.shape[0], 1), np.inf)], axis=1)
        return (column > beyond + tolerance) & np.isfinite(z)
    left = np.maximum.accumulate(column, axis=1)
    before = np.concatenate([np.full((depth.shape[0], 1), -np.inf), left[:, :-1]], axis=1)
    return (column < before - tolerance) & np.isfinite(z)


def view_angles(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Degrees between each pixel's surface normal (from depth) and its viewing ray."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    h, w = depth.shape
    rays = np.stack(np.meshgrid((np.arange(w) - cx) / fx, (np.arange(h) - cy) / fy), axis=-1)
    points = np.concatenate([rays, np.ones((h, w, 1))], axis=-1) * depth[..., None]
    du, dv = np.gradient(points, axis=1), np.gradient(points, axis=0)
    normals = np.cross(du, dv)
    norms = np.linalg.norm(normals, axis=-1)
    view = points / np.maximum(np.linalg.norm(points, axis=-1, keepdims=True), 1e-9)
    cosine = np.abs(np.sum(normals * view, axis=-1)) / np.maximum(norms, 1e-12)
    return np.degrees(np.arccos(np.clip(cosine, 0.0, 1.0)))


def _blobs(shape: tuple[int, int], share: float, size: float, rng: np.random.Generator) -> np.ndarray:
    """Random blobs of about ``size`` pixels covering about ``share`` of an image."""
    if share <= 0:
        return np.zeros(shape, bool)
    import cv2

    small = (max(2, int(shape[1] / size)), max(2, int(shape[0] / size)))
    field = cv2.resize(rng.random((small[1], small[0])).astype(np.float32), (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)
    return field < np.quantile(field, share)


def _edges(depth: np.ndarray, jump: float = 0.01) -> np.ndarray:
    import cv2

    kernel = np.ones((3, 3), np.uint8)
    return (cv2.dilate(depth, kernel) - cv2.erode(depth, kernel)) > jump


def sense(rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, sensor: SensorConfig, rng: np.random.Generator,
          segmentation: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """The depth image (metres, 0 where the sensor has no reading) that ``sensor`` would give of a
    scene rendered perfectly as ``depth`` (float32, metres along the optical axis) with colour
    ``rgb`` and camera intrinsics ``K``; ``segmentation`` (instance per pixel, -1 for none) lets whole
    instances be of a material the sensor cannot read. Returns the depth and what was drawn."""
    import cv2

    if not sensor.realistic:
        return depth, {}
    depth = np.asarray(depth, dtype=np.float32)
    h, w = depth.shape
    fx = float(K[0, 0])
    baseline = _draw(rng, sensor.baseline)
    side = {"left": -1, "right": 1}.get(sensor.projector_side, int(rng.choice([-1, 1])))
    drawn = {"baseline": round(baseline, 4), "projector_side": "right" if side > 0 else "left"}
    # 1. lateral noise: edges move by a fraction of a pixel to a pixel (a smooth random displacement)
    lateral = _draw(rng, sensor.lateral_noise)
    if lateral > 0:
        grid_x, grid_y = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        shift = [cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 2.0) for _ in range(2)]
        shift = [s * (lateral / max(float(s.std()), 1e-6)) for s in shift]
        depth = cv2.remap(depth, grid_x + shift[0], grid_y + shift[1], cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    # 2. flying pixels: some edge pixels read a depth between the near and the far side
    edges = _edges(depth)
    flying = edges & (rng.random((h, w)) < _draw(rng, sensor.flying_pixels))
    if flying.any():
        kernel = np.ones((3, 3), np.uint8)
        near, far = cv2.erode(depth, kernel), cv2.dilate(depth, kernel)
        mix = rng.random((h, w)).astype(np.float32)
        depth = np.where(flying, near + mix * (far - near), depth)
    # 3. axial noise growing with distance, then the disparity's and the format's quantisation
    depth = depth + rng.normal(0, 1, (h, w)).astype(np.float32) * axial_sigma(depth, _draw(rng, sensor.noise_scale)).astype(np.float32)
    subpixel = int(round(_draw(rng, sensor.subpixel)))
    disparity = fx * baseline / np.maximum(depth, 1e-3)
    depth = (fx * baseline / np.maximum(np.round(disparity * subpixel) / subpixel, 1e-6)).astype(np.float32)
    # 4. missing readings
    missing = projector_shadow(depth, fx, baseline, side, _draw(rng, sensor.shadow_tolerance))
    drawn["shadow"] = round(float(missing.mean()), 4)
    luminance = (rgb[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)) / 255.0
    missing |= (luminance < _draw(rng, sensor.dark_level)) & (rng.random((h, w)) < _draw(rng, sensor.dark_dropout))
    missing |= (luminance > _draw(rng, sensor.specular_level)) & (rng.random((h, w)) < _draw(rng, sensor.specular_dropout))
    missing |= view_angles(depth, K) > _draw(rng, sensor.grazing_angle)
    if segmentation is not None:
        share = _draw(rng, sensor.hard_instances)
        for instance in np.unique(segmentation[segmentation >= 0]):
            if rng.random() < share:
                lost = _blobs((h, w), _draw(rng, sensor.hard_dropout), 4.0, rng)
                missing |= (segmentation == instance) & lost
    missing |= _blobs((h, w), _draw(rng, sensor.dropout), _draw(rng, sensor.blob_size), rng)
    border = int(round(_draw(rng, sensor.border)))
    if border:
        wide = 2 * border  # the edge away from the projector loses more: the projector does not reach it
        missing[:border], missing[-border:] = True, True
        if side > 0:
            missing[:, :wide], missing[:, -border:] = True, True
        else:
            missing[:, :border], missing[:, -wide:] = True, True
    depth = np.where(missing, np.float32(0.0), depth)
    # 5. depth registered to colour a pixel or two off
    if sensor.misregistration[1]:
        dx, dy = (int(round(_draw(rng, sensor.misregistration))) * int(rng.choice([-1, 1])) for _ in range(2))
        drawn["misregistration"] = [dx, dy]
        depth = np.roll(depth, (dy, dx), axis=(0, 1))
        if dy > 0:
            depth[:dy] = 0
        elif dy < 0:
            depth[dy:] = 0
        if dx > 0:
            depth[:, :dx] = 0
        elif dx < 0:
            depth[:, dx:] = 0
    drawn["missing"] = round(float(np.mean(depth <= 0)), 4)
    return depth.astype(np.float32), drawn

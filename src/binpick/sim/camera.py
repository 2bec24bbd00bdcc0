"""Cameras for every MuJoCo world (envs and bin scenes): image mode/size checks and an off-screen camera.

The image observation uses its own :class:`mujoco.Renderer`, separate from ``render()``, so a
policy's input (small, fixed camera) and a person's view (large, ``render_mode``) never interfere.
"""

from __future__ import annotations

import atexit
import gc
import os
import sys
import weakref
from dataclasses import dataclass

import numpy as np

from binpick.core.config import check_range
from binpick.core.errors import RenderingUnavailableError

IMAGE_MODES = ("rgb", "grey")
MIN_IMAGE_SIZE, MAX_IMAGE_SIZE = 16, 1024

GL_HELP = (
    "install the Debian packages 'libegl1 libegl-mesa0 libgl1-mesa-dri' and set MUJOCO_GL=egl "
    "(or install 'libosmesa6' and set MUJOCO_GL=osmesa)"
)


def check_image_size(name: str, size: int) -> int:
    """Square image side in pixels; small enough to fit memory, large enough to show the scene."""
    return check_range(name, size, MIN_IMAGE_SIZE, MAX_IMAGE_SIZE, integer=True)


def to_mode(rgb: np.ndarray, mode: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB -> the same for 'rgb', (H, W, 1) luma (ITU-R 601) for 'grey'."""
    if mode == "rgb":
        return rgb
    grey = rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)[..., None]


@dataclass(frozen=True)
class CameraPose:
    """A free camera looking at ``lookat`` from ``distance`` metres, angles in degrees (MjvCamera)."""

    lookat: tuple[float, float, float]
    distance: float
    azimuth: float
    elevation: float

    @property
    def forward(self) -> np.ndarray:
        """The unit vector from the camera towards its look-at point (MuJoCo's free-camera convention)."""
        azimuth, elevation = np.radians(self.azimuth), np.radians(self.elevation)
        return np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])

    def project(self, points: np.ndarray, fovy_degrees: float) -> np.ndarray:
        """World points (N, 3) -> where a square frame shows them, (N, 2) as (x right, y down) in [-1, 1]."""
        forward = self.forward
        eye = np.asarray(self.lookat) - self.distance * forward
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        rays = np.asarray(points, np.float64).reshape(-1, 3) - eye
        focal = 1.0 / np.tan(np.radians(fovy_degrees) / 2)
        return focal * np.stack([rays @ right, -(rays @ up)], axis=-1) / (rays @ forward)[:, None]


class MujocoCamera:
    """Renders RGB or grey frames of a MuJoCo model from a fixed free-camera pose.

    Each instance owns its renderer (on its thread's shared GL context under EGL,
    :mod:`binpick.sim.rendering`), made current before drawing, so several cameras (image
    observations, ``render()``) coexist in one process; gymnasium's own viewer did not.
    """

    def __init__(
        self, model, size: int | tuple[int, int], mode: str, pose: CameraPose, multisample: bool = True
    ) -> None:
        mujoco = import_mujoco()
        from binpick.sim.rendering import renderer

        width, height = (size, size) if isinstance(size, int) else size
        self.mode = mode
        visual = model.vis.global_
        visual.offwidth, visual.offheight = max(visual.offwidth, width), max(visual.offheight, height)
        # The GL context reads the MSAA sample count once, when it is made. Without MSAA a small
        # frame renders ~2.3x faster under Mesa llvmpipe (9.1 -> 4.0 ms for Fetch at 84 px).
        samples = model.vis.quality.offsamples
        if not multisample:
            model.vis.quality.offsamples = 0
        failure = None
        hook, sys.unraisablehook = sys.unraisablehook, lambda _: None
        try:  # mujoco's half-built GL context prints a traceback when freed: free it here, quietly
            try:
                self._renderer = renderer(model, height=height, width=width)
            except Exception as error:  # mujoco raises several types when no GL context can be made
                failure = rendering_error(error)
            gc.collect()
        finally:
            sys.unraisablehook = hook
            model.vis.quality.offsamples = samples
        if failure is not None:
            raise failure
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._camera.lookat[:] = pose.lookat
        self._camera.distance = pose.distance
        self._camera.azimuth = pose.azimuth
        self._camera.elevation = pose.elevation
        close_at_exit(self)

    def render(self, data) -> np.ndarray:
        self._renderer.update_scene(data, camera=self._camera)
        return to_mode(self._renderer.render().copy(), self.mode)

    def close(self) -> None:
        renderer, self._renderer = getattr(self, "_renderer", None), None
        if renderer is not None:
            renderer.close()


_LIVE_CAMERAS: weakref.WeakSet = weakref.WeakSet()
_EXIT_HOOK_REGISTERED = False


def close_at_exit(owner) -> None:
    """Close ``owner`` (anything holding MuJoCo renderers, with a ``close()``) before MuJoCo's own GL
    exit hook runs, unless it was closed already. Call it after creating the first renderer."""
    global _EXIT_HOOK_REGISTERED
    if not _EXIT_HOOK_REGISTERED:  # registered after MuJoCo's hook exists, so ours runs before it
        atexit.register(_close_live_cameras)
        _EXIT_HOOK_REGISTERED = True
    _LIVE_CAMERAS.add(owner)


def _close_live_cameras() -> None:
    """Free GL contexts before interpreter teardown, when freeing them raises noisy EGL errors."""
    for camera in list(_LIVE_CAMERAS):
        camera.close()


def import_mujoco():
    """``import mujoco``, which loads the OpenGL platform named by MUJOCO_GL and fails without it."""
    try:
        import mujoco
    except (ImportError, AttributeError, RuntimeError, OSError) as error:
        raise rendering_error(error, "load its OpenGL platform") from None
    return mujoco


def rendering_error(error: BaseException, what: str = "open an OpenGL context") -> RenderingUnavailableError:
    """One line that says rendering failed, under which MUJOCO_GL, and which packages fix it."""
    backend = os.environ.get("MUJOCO_GL", "<unset>")
    reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
    return RenderingUnavailableError(f"MuJoCo could not {what} (MUJOCO_GL={backend}: {reason}); to fix it, {GL_HELP}")

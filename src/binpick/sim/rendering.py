"""MuJoCo renderers that share one OpenGL context per thread (headless EGL).

:class:`mujoco.Renderer` makes an OpenGL context of its own, and under Mesa's software renderer the
first MuJoCo context made in a new OpenGL context costs about 0.2 s of CPU, the next ones in the
same OpenGL context about 0.04 s. binpick makes renderers all the time: two per bin world (a data set
makes one world per few scenes), one per environment with image observations, one per photo
studio. :func:`renderer` gives a :class:`mujoco.Renderer` whose OpenGL context is this thread's
shared one (made once per thread and process), so only the first renderer pays; what it renders is
the same, pixel for pixel. Other platforms (``MUJOCO_GL=osmesa`` or ``glfw``, whose contexts are
sized or windowed) get MuJoCo's own renderer.

A renderer is used in the thread that made it, as MuJoCo's own are (an OpenGL context is current in
one thread at a time)."""

from __future__ import annotations

import atexit
import os
import threading
import weakref

import mujoco

_THREAD = threading.local()
_MADE: weakref.WeakSet = weakref.WeakSet()  # every shared context of this process, freed at exit while EGL still runs
_FREED_AT_EXIT = False  # _free_all registered (once, after the first context: see shared_context)


def renderer(model: mujoco.MjModel, height: int = 240, width: int = 320) -> mujoco.Renderer:
    """A renderer of ``model`` at ``height`` x ``width``: on this thread's shared context under EGL."""
    if os.environ.get("MUJOCO_GL", "").lower() == "egl":
        return SharedContextRenderer(model, height, width)
    return mujoco.Renderer(model, height=height, width=width)


def shared_context():
    """This thread's OpenGL context (made on first use; a forked process makes its own)."""
    context = getattr(_THREAD, "context", None)
    if context is None or _THREAD.pid != os.getpid():
        from mujoco import gl_context

        context = gl_context.GLContext(1, 1)  # (EGL: the size is not used; MuJoCo renders into its own framebuffer)
        _THREAD.context, _THREAD.pid = context, os.getpid()
        global _FREED_AT_EXIT
        if not _FREED_AT_EXIT:  # registered after MuJoCo's own exit handler (which ends EGL), so it runs before it
            atexit.register(_free_all)
            _FREED_AT_EXIT = True
        _MADE.add(context)
    return context


def _free_all() -> None:
    """Free the shared contexts (a finished thread's too) before EGL is terminated at exit."""
    for context in list(_MADE):
        try:
            context.free()
        except Exception:  # noqa: BLE001 - nothing to do about a context EGL will not free at exit
            pass


class SharedContextRenderer(mujoco.Renderer):
    """:class:`mujoco.Renderer` (its scene, options and rendering) on :func:`shared_context`: its own
    MuJoCo context (the model's textures and offscreen framebuffer) in an OpenGL context it does not own."""

    def __init__(self, model: mujoco.MjModel, height: int = 240, width: int = 320, max_geom: int = 10000) -> None:
        self._gl_context = self._mjr_context = None
        for size, limit, name in ((width, model.vis.global_.offwidth, "width"), (height, model.vis.global_.offheight, "height")):
            if size > limit:
                raise ValueError(f"image {name} {size} > the model's offscreen framebuffer {name} {limit}")
        self._width, self._height, self._model = width, height, model
        self._scene = mujoco.MjvScene(model=model, maxgeom=max_geom)
        self._scene_option = mujoco.MjvOption()
        self._rect = mujoco.MjrRect(0, 0, width, height)
        context = shared_context()
        context.make_current()
        self._mjr_context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        self._gl_context = context  # made current before each render (mujoco.Renderer.render)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._mjr_context)
        self._mjr_context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._depth_rendering = self._segmentation_rendering = False

    def render(self, *, out=None):
        """:meth:`mujoco.Renderer.render`, into this renderer's framebuffer: the OpenGL context's bound
        framebuffer is whichever MuJoCo context bound it last (another renderer's, made or drawn since)."""
        if self._mjr_context is not None:
            self._gl_context.make_current()
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._mjr_context)
        return super().render(out=out)

    def close(self) -> None:
        """Free this renderer's MuJoCo context; the shared OpenGL context stays for the next renderer."""
        context, mjr = self._gl_context, self._mjr_context
        self._gl_context = self._mjr_context = None
        if mjr is not None:
            try:
                if context is not None:
                    context.make_current()  # its textures and framebuffer live in that context
                mjr.free()
            except Exception:  # noqa: BLE001 - at interpreter exit EGL may be gone: the process frees it all
                pass

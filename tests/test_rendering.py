"""Renderers on a shared OpenGL context render what MuJoCo's own renderers do, pixel for pixel, however
they are interleaved (what they save, the first MuJoCo context of each OpenGL context, is measured, not asserted)."""

from __future__ import annotations

import os
import threading

import mujoco
import numpy as np
import pytest

from binpick.sim.rendering import SharedContextRenderer, renderer

pytestmark = pytest.mark.skipif(os.environ.get("MUJOCO_GL") != "egl", reason="the shared context is EGL's (MUJOCO_GL=egl)")

XML = """<mujoco><visual><global offwidth="96" offheight="96"/></visual>
<asset><texture name="grid" type="2d" builtin="checker" rgb1=".2 .3 .4" rgb2=".8 .7 .1" width="64" height="64"/>
<material name="grid" texture="grid" texrepeat="4 4"/></asset>
<worldbody><light pos="0 0 2" castshadow="true"/><geom type="plane" size="1 1 .1" material="grid"/>
<body pos="0 0 .2"><freejoint/><geom type="box" size=".1 .07 .05" rgba=".9 .2 .2 1"/></body>
<body pos=".25 .1 .2"><freejoint/><geom type="sphere" size=".08" rgba=".2 .9 .3 1"/></body>
<camera name="top" pos="0 -.6 .9" xyaxes="1 0 0 0 .83 .55"/></worldbody></mujoco>"""


def images(r: mujoco.Renderer, data: mujoco.MjData) -> list[np.ndarray]:
    out = []
    for mode in ("rgb", "depth", "segmentation"):
        if mode == "depth":
            r.enable_depth_rendering()
        elif mode == "segmentation":
            r.enable_segmentation_rendering()
        r.update_scene(data, camera="top")
        out.append(r.render().copy())
        r.disable_depth_rendering()
        r.disable_segmentation_rendering()
    return out


def test_shared_context_renders_equal_mujocos_own_renderers_interleaved():
    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    big, small = renderer(model, 96, 96), renderer(model, 40, 40)  # two framebuffers in one OpenGL context
    assert isinstance(big, SharedContextRenderer) and big._gl_context is small._gl_context
    try:
        ours = [images(big, data), images(small, data), images(big, data)]  # each draws after the other made or drew
    finally:
        big.close()
    with mujoco.Renderer(model, 96, 96) as own_big, mujoco.Renderer(model, 40, 40) as own_small:
        theirs = [images(own_big, data), images(own_small, data)]
    for a, b in zip(ours[:2] + ours[2:], theirs + theirs[:1]):
        assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert ours[0][0].std() > 10 and len(np.unique(ours[0][2][..., 0])) >= 3  # a picture with the floor and both bodies
    assert np.array_equal(images(small, data)[0], theirs[1][0])  # closing one renderer leaves the others drawing
    small.close()


def test_each_thread_has_its_own_context_and_it_outlives_the_renderers_made_on_it():
    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    first = renderer(model, 64, 64)
    seen = {}

    def other_thread():
        r = renderer(model, 64, 64)
        seen["context"], seen["image"] = r._gl_context, images(r, data)[0]
        r.close()

    thread = threading.Thread(target=other_thread)
    thread.start()
    thread.join()
    assert seen["context"] is not first._gl_context  # an OpenGL context is current in one thread at a time
    assert np.array_equal(seen["image"], images(first, data)[0])
    context, image = first._gl_context, images(first, data)[0]
    first.close()
    again = renderer(model, 64, 64)  # the thread's context outlives the renderers made on it
    assert again._gl_context is context and np.array_equal(images(again, data)[0], image)
    again.close()

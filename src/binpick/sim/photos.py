"""Shop photos (thesis §6.3): each product alone on a plain background from one canonical view —
the external conditioning image of an order."""

from __future__ import annotations

import mujoco
import numpy as np

from binpick.sim.mjcf import product_assets, product_geom
from binpick.sim.products import Product


def shop_photo(product: Product, size: int = 256, with_mask: bool = False):
    """(size, size, 3) uint8: the product resting upright on a white studio floor, seen from 45°.
    With ``with_mask``, also the (size, size) bool mask of the product's pixels."""
    xml = f"""<mujoco><visual><global offwidth="{size}" offheight="{size}"/><quality shadowsize="2048"/>
  <headlight ambient="0.5 0.5 0.5" diffuse="0.4 0.4 0.4"/></visual>
  <asset><material name="studio" rgba="0.97 0.97 0.97 1"/>{product_assets(product, 'p')}</asset>
  <worldbody><light pos="0.3 -0.4 1.0" dir="-0.3 0.4 -1" diffuse="0.5 0.5 0.5" castshadow="true"/>
    <geom type="plane" size="0 0 0.05" material="studio"/>
    <body name="product" pos="0 0 0.3">{product_geom(product, 'p')}</body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
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
    renderer = mujoco.Renderer(model, size, size)
    try:
        camera = mujoco.MjvCamera()
        camera.lookat[:] = centre
        camera.distance = 3.2 * extent + 0.05
        camera.azimuth, camera.elevation = 135.0, -35.0
        renderer.update_scene(data, camera=camera)
        rgb = renderer.render().copy()
        if not with_mask:
            return rgb
        renderer.enable_segmentation_rendering()
        segmentation = renderer.render()
        mine = np.flatnonzero(model.geom_bodyid == body)
        return rgb, np.isin(segmentation[..., 0], mine) & (segmentation[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM))
    finally:
        renderer.close()


def contact_sheet(photos: dict[str, np.ndarray], columns: int = 8) -> np.ndarray:
    """Tile photos (same size) row by row, for docs."""
    images = list(photos.values())
    rows = -(-len(images) // columns)
    h, w, _ = images[0].shape
    sheet = np.full((rows * h, columns * w, 3), 255, np.uint8)
    for i, image in enumerate(images):
        sheet[(i // columns) * h:(i // columns + 1) * h, (i % columns) * w:(i % columns + 1) * w] = image
    return sheet


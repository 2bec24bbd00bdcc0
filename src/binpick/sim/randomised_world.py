"""The draws of a domain-randomised bin world (:class:`binpick.sim.domain.DomainConfig`): per world the
tote's size and walls, the lights and clutter beside the tote, generated textures; per scene the
camera, the lights, colour tints and where the clutter lies."""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np

from binpick.sim.mjcf import BIN_WALL, FLOOR_TOP, product_assets, product_body, random_world_xml
from binpick.sim.products import Product

PARK_X = 3.0  # unused slots and clutter wait here, on the table, out of view


class RandomisedWorld:
    """What :class:`binpick.sim.bin_scene.BinWorld` does when its domain is randomised (its ``domain``,
    ``camera``, ``model``, ``data``, ``camera_id``, ``tote_tilt`` and ``_seed`` are set before these run)."""

    def _random_world(self, assets: str, bodies: str, extra_worldbody: str, extra: str, rng: np.random.Generator) -> str:
        """Per-world draws: tote size and walls, number of lights, clutter objects beside the tote."""
        from binpick.sim.domain import integer, uniform
        from binpick.sim.products import random_primitive

        domain = self.domain
        self.half = (uniform(rng, domain.tote_half_x), uniform(rng, domain.tote_half_y))
        self.wall_height = uniform(rng, domain.wall_height)
        self.lights = integer(rng, domain.lights)
        self.clutter = [replace(random_primitive(f"clutter{i}", rng), pattern=(int(rng.integers(2**31)), domain.textures))
                        for i in range(domain.clutter[1])]
        for i, item in enumerate(self.clutter):
            assets += product_assets(item, f"c{i}")
            bodies += product_body(item, f"clutter{i}", (PARK_X, -0.5 - 0.25 * i, 0.1), (1, 0, 0, 0), f"c{i}")
        return random_world_xml(assets, bodies, self.camera.size, self.half, self.wall_height, max(self.lights, 1),
                                extra_worldbody, extra, self.tote_tilt)

    def _fill_textures(self, products: dict[str, Product], prefixes: dict[str, str]) -> None:
        from binpick.sim.domain import fill_texture, pattern

        rng = np.random.default_rng(self._seed)
        pool = self.domain.textures
        fill_texture(self.model, self.model.texture("table_tex").id, pattern(rng, pool))
        fill_texture(self.model, self.model.texture("tote_tex").id, pattern(rng, pool))
        named = [(prefixes[p.id], p) for p in products.values()] + [(f"c{i}", c) for i, c in enumerate(self.clutter)]
        for prefix, product in named:
            if product.pattern is not None:
                fill_texture(self.model, self.model.texture(f"{prefix}_tex").id, pattern(np.random.default_rng(product.pattern[0]), pool))
        self._materials = {name: self.model.material(name).id for name in ("table", "bin")}
        self._product_materials = [self.model.material(f"{prefixes[p.id]}_mat").id for p in products.values()
                                   if p.pattern is not None or p.texture is not None or p.shape is not None]
        self._base_rgba = self.model.mat_rgba.copy()

    def _randomise_scene(self, rng: np.random.Generator):
        """Per-scene draws: camera, lights, colour tints, clutter positions. Returns the camera."""
        from binpick.sim.domain import apply_camera, draw_camera, draw_lights, uniform

        domain = self.domain
        draw = draw_camera(domain, rng, self.camera.size, FLOOR_TOP)
        apply_camera(self.model, self.camera_id, draw)
        draw_lights(domain, rng, self.model, self.lights)
        rgba = self._base_rgba.copy()
        for name in ("table", "bin"):
            rgba[self._materials[name], :3] *= rng.uniform(0.6, 1.15, 3)
        jitter = uniform(rng, domain.product_colour)
        for material in self._product_materials:
            rgba[material, :3] *= 1 + rng.uniform(-1, 1, 3) * jitter
        self.model.mat_rgba[:] = np.clip(rgba, 0, 1)
        shown = int(rng.integers(domain.clutter[0], domain.clutter[1] + 1))
        hx, hy = self.half
        for i in range(len(self.clutter)):
            joint = self.model.body(f"clutter{i}").jntadr[0]
            adr = self.model.jnt_qposadr[joint]
            if i < shown:  # on the table, beside the tote, where a wide view may see it
                side = rng.integers(4)
                along = rng.uniform(-1, 1) * (hx if side < 2 else hy)
                out = rng.uniform(0.06, 0.2) + (hy if side < 2 else hx) + BIN_WALL
                x, y = (along, out if side == 0 else -out) if side < 2 else (out if side == 2 else -out, along)
                self.data.qpos[adr:adr + 3] = (x, y, float(self.model.geom_rbound[self.model.body(f"clutter{i}").geomadr[0]]))
            else:
                self.data.qpos[adr:adr + 3] = (PARK_X, -0.5 - 0.25 * i, 0.1)
        mujoco.mj_forward(self.model, self.data)
        return draw

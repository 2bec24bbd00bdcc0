"""MJCF snippets for products, the tote and the overhead camera (one place that knows MuJoCo's XML).

Stability settings found on this machine (FACTS): thick bin floor and walls, ``inertia="convex"``
meshes, ``condim=6`` with rolling friction, the ``implicitfast`` integrator, light damping and
stiffer product contacts than MuJoCo's default (``solref`` 4 ms instead of 20 ms: with the default,
piles of eight small shapes pushed some through the 3 cm floor). Only
the meshes a scene uses are declared: an unused convex-inertia mesh crashed MuJoCo 3.11 at compile.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from binpick.sim.mjcf_mesh import merged_obj
from xml.sax.saxutils import quoteattr

if TYPE_CHECKING:  # products.py compiles MJCF from here: the type only, no import cycle
    from binpick.sim.products import Product

# tote: inner half-sizes (x, y), wall height and thickness, floor thickness (metres)
BIN_HALF = (0.21, 0.16)
BIN_WALL_HEIGHT = 0.14
BIN_WALL = 0.02
BIN_FLOOR = 0.03
FLOOR_TOP = BIN_FLOOR  # the bin floor's top surface (table at z = 0)
GUARD_HEIGHT = 0.6
PRODUCT_SOLREF = "0.004 1"
PRODUCT_SOLIMP = "0.95 0.99 0.001"
# rolling friction (m): about 0.04 of a 2.5 cm ball's radius, a plastic or rubber ball on a plastic tote.
# With 0.0001 a ball knocked to 5 cm/s still rolled at 4.5 cm/s three seconds later, where a real one stops
# within a couple of seconds; with this it is under 0.5 cm/s after two
PRODUCT_ROLLING = 0.001


@dataclass(frozen=True)
class CameraSpec:
    """An overhead pinhole camera looking straight down at the bin centre."""

    height: float = 0.85
    fovy: float = 42.0  # degrees, vertical
    size: int = 416

    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels for a square image of ``size``."""
        import math

        f = 0.5 * self.size / math.tan(math.radians(self.fovy) / 2)
        return f, f, (self.size - 1) / 2, (self.size - 1) / 2


def _fmt(values) -> str:
    return " ".join(f"{float(v):.6g}" for v in values)


def product_assets(product: Product, prefix: str) -> str:
    """Mesh, texture and material of one product (declared once, used by all its copies)."""
    parts = []
    if product.pattern is not None:  # pixels filled after compiling (binpick.sim.domain.fill_product_textures)
        parts.append(f'<texture name="{prefix}_tex" type="cube" builtin="flat" rgb1="1 1 1" width="64" height="64"/>')
        parts.append(f'<material name="{prefix}_mat" texture="{prefix}_tex" rgba="1 1 1 1"/>')
    if product.mesh is not None:
        inline = merged_obj(product.mesh) if product.mesh.suffix.lower() == ".obj" else None
        source = f'vertex="{inline[0]}" face="{inline[1]}"' if inline else f"file={quoteattr(str(product.mesh))}"
        parts.append(f'<mesh name="{prefix}_mesh" {source} scale="{_fmt([product.scale] * 3)}" inertia="convex"/>')
    if product.pattern is not None:
        pass
    elif product.texture is not None:
        parts.append(f'<texture name="{prefix}_tex" type="2d" file={quoteattr(str(product.texture))}/>')
        uniform = "true" if product.texuniform else "false"
        parts.append(f'<material name="{prefix}_mat" texture="{prefix}_tex" texrepeat="{_fmt(product.texrepeat)}" '
                     f'texuniform="{uniform}" rgba="1 1 1 1"/>')
    elif product.shape is not None:  # procedural: a printed check pattern in the product's colour
        r, g, b, _ = product.rgba
        parts.append(f'<texture name="{prefix}_tex" type="cube" builtin="checker" rgb1="{_fmt((r, g, b))}" '
                     f'rgb2="{_fmt((min(1, r + .35), min(1, g + .35), min(1, b + .35)))}" width="64" height="64"/>')
        parts.append(f'<material name="{prefix}_mat" texture="{prefix}_tex" texrepeat="2 2" rgba="1 1 1 1"/>')
    return "".join(parts)


def product_geom(product: Product, prefix: str) -> str:
    textured = product.texture is not None or product.shape is not None or product.pattern is not None
    material = f'material="{prefix}_mat"' if textured else f'rgba="{_fmt(product.rgba)}"'
    common = (f'mass="{product.mass:.4g}" friction="{product.friction:.3g} 0.005 {PRODUCT_ROLLING}" condim="6" '
              f'solref="{PRODUCT_SOLREF}" solimp="{PRODUCT_SOLIMP}" {material}')
    if product.mesh is not None:
        return f'<geom type="mesh" mesh="{prefix}_mesh" {common}/>'
    return f'<geom type="{product.shape}" size="{_fmt(product.size)}" {common}/>'


def product_body(product: Product, name: str, pos, quat, prefix: str | None = None) -> str:
    return (f'<body name="{name}" pos="{_fmt(pos)}" quat="{_fmt(quat)}"><freejoint name="{name}_joint"/>'
            f'{product_geom(product, prefix or name)}</body>')


def tote(half: tuple[float, float] = BIN_HALF, wall_height: float = BIN_WALL_HEIGHT, tilt: tuple[float, float] = (0.0, 0.0)) -> str:
    """A tote on the table: a thick floor and four walls (static geoms); ``tilt`` (radians about the
    world's x and y axes) sets it down off level, as a tote on a sloping conveyor or table stands."""
    hx, hy = half
    h, t = wall_height, BIN_WALL
    z = FLOOR_TOP + h / 2
    walls = [((hx + t / 2, 0, z), (t / 2, hy + t, h / 2)), ((-hx - t / 2, 0, z), (t / 2, hy + t, h / 2)),
             ((0, hy + t / 2, z), (hx, t / 2, h / 2)), ((0, -hy - t / 2, z), (hx, t / 2, h / 2))]
    geoms = [f'<geom name="bin_floor" type="box" pos="0 0 {BIN_FLOOR / 2}" size="{hx + t} {hy + t} {BIN_FLOOR / 2}" material="bin"/>']
    geoms += [f'<geom name="bin_wall{i}" type="box" pos="{_fmt(p)}" size="{_fmt(s)}" material="bin"/>' for i, (p, s) in enumerate(walls)]
    # invisible guards above the walls (alpha 0: MuJoCo renders and segments nothing) keep products
    # dropped onto a pile from bouncing out onto the table, where they would be seen but not labelled
    guard_z = FLOOR_TOP + h + GUARD_HEIGHT / 2
    geoms += [f'<geom name="bin_guard{i}" type="box" pos="{_fmt((p[0], p[1], guard_z))}" '
              f'size="{_fmt((s[0], s[1], GUARD_HEIGHT / 2))}" rgba="0 0 0 0"/>' for i, (p, s) in enumerate(walls)]
    if any(tilt):
        return f'<body name="tote" euler="{_fmt((tilt[0], tilt[1], 0.0))}">{"".join(geoms)}</body>'
    return "".join(geoms)


def _preamble(size: int, headlight_diffuse: float) -> str:
    """Compiler, integrator, off-screen buffer, headlight and joint damping of every bin world."""
    return f"""<compiler angle="radian" autolimits="true"/>
  <option timestep="0.002" integrator="implicitfast"/>
  <visual><global offwidth="{size}" offheight="{size}"/><quality shadowsize="1024"/>
    <headlight ambient="0.35 0.35 0.35" diffuse="{_fmt([headlight_diffuse] * 3)}"/></visual>
  <default><joint damping="0.002"/></default>"""


def scene_xml(assets: str, bodies: str, camera: CameraSpec, extra_worldbody: str = "", extra: str = "",
              light_dir=(0.0, 0.0, -1.0), light_diffuse=(0.7, 0.7, 0.7), table_rgba=(0.55, 0.45, 0.35, 1.0),
              bin_rgba=(0.2, 0.35, 0.6, 1.0), tote_tilt: tuple[float, float] = (0.0, 0.0)) -> str:
    return f"""<mujoco model="bin_scene">
  {_preamble(camera.size, 0.3)}
  <asset>
    <texture name="table_tex" type="2d" builtin="flat" rgb1="{_fmt(table_rgba[:3])}" width="16" height="16"/>
    <material name="table" texture="table_tex" rgba="1 1 1 1"/>
    <material name="bin" rgba="{_fmt(bin_rgba)}"/>
    {assets}
  </asset>
  <worldbody>
    <light name="key" pos="0.3 -0.2 1.6" dir="{_fmt(light_dir)}" diffuse="{_fmt(light_diffuse)}" castshadow="true"/>
    <geom name="table" type="plane" size="0 0 0.05" material="table"/>
    {tote(tilt=tote_tilt)}
    <camera name="overhead" pos="0 0 {camera.height}" xyaxes="1 0 0 0 1 0" fovy="{camera.fovy}"/>
    {extra_worldbody}
    {bodies}
  </worldbody>
  {extra}
</mujoco>"""


def random_world_xml(assets: str, bodies: str, size: int, half: tuple[float, float], wall_height: float,
                     lights: int, extra_worldbody: str = "", extra: str = "", tote_tilt: tuple[float, float] = (0.0, 0.0)) -> str:
    """A randomised bin world (:mod:`binpick.sim.domain`): a tote of the given size, textured table
    and tote (``table_tex``/``tote_tex``, filled after compiling), ``lights`` lights and a camera
    whose pose and intrinsics are set per scene (declared with ``sensorsize`` so that
    ``cam_intrinsic`` holds focal length and principal point)."""
    light_xml = "".join(f'<light name="light{i}" pos="0 0 1.6" dir="0 0 -1" castshadow="true"/>' for i in range(lights))
    return f"""<mujoco model="bin_scene_random">
  {_preamble(size, 0.1)}
  <asset>
    <texture name="table_tex" type="2d" builtin="flat" rgb1="1 1 1" width="64" height="64"/>
    <material name="table" texture="table_tex" texrepeat="{_fmt((6, 6))}" rgba="1 1 1 1"/>
    <texture name="tote_tex" type="cube" builtin="flat" rgb1="1 1 1" width="64" height="64"/>
    <material name="bin" texture="tote_tex" rgba="1 1 1 1"/>
    {assets}
  </asset>
  <worldbody>
    {light_xml}
    <geom name="table" type="plane" size="0 0 0.05" material="table"/>
    {tote(half, wall_height, tote_tilt)}
    <camera name="overhead" pos="0 0 1" xyaxes="1 0 0 0 1 0" sensorsize="0.01 0.01" focal="0.012 0.012"
            principal="0 0" resolution="{size} {size}"/>
    {extra_worldbody}
    {bodies}
  </worldbody>
  {extra}
</mujoco>"""

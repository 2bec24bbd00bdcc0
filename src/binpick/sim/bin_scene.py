"""Bin scenes: K copies of one product plus distractors dropped into a tote and settled, seen by an
overhead RGB-D camera, with every instance's 2D box and visible fraction (thesis §5.4.4, Fig 5.13).

A :class:`BinWorld` compiles one MuJoCo model for a target product (up to ``max_copies`` slots) and
a few distractor products, then makes many scenes from it: unused slots are parked on the table far
outside the camera's view. Reusing the model and renderers is what makes generation fast (compiling
and creating a renderer cost more than a whole scene). Everything is deterministic under a seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from binpick.sim.domain import DomainConfig
from binpick.sim.mjcf import BIN_HALF, FLOOR_TOP, CameraSpec, product_assets, product_body, scene_xml
from binpick.sim.products import Product
from binpick.sim.randomised_world import PARK_X, RandomisedWorld
from binpick.sim.rendering import renderer
from binpick.sim.sensor import SensorConfig, sense, tote_tilt

SETTLE_SECONDS = 1.2
STILL_SECONDS = 3.0  # the longest a picking look waits for the bin to come to rest
STILL_SPEED, STILL_TURN = 0.005, 0.3  # m/s and rad/s: a product slower than both is at rest
AMODAL_SIZE = 80  # resolution of the per-instance masks that give the visible fraction


@dataclass
class Instance:
    """One object in a scene: which product, where it is, what the camera sees of it."""

    slot: int
    product_id: str
    category: str
    is_target: bool
    bbox: tuple[float, float, float, float]  # x, y, w, h in pixels (COCO)
    area: float  # visible pixels
    visible_fraction: float
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]


@dataclass
class Scene:
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 metres from the camera
    segmentation: np.ndarray  # (H, W) int16: slot index, -1 for background
    instances: list[Instance]
    target_id: str
    seed: int
    state: np.ndarray = field(repr=False, default=None)  # qpos after settling (for grasp trials)
    camera: dict = field(default_factory=dict)  # intrinsics K (3x3, pixels) and camera-to-world extrinsics (4x4, OpenCV axes)
    sensor: dict = field(default_factory=dict)  # what the depth sensor drew for this scene (empty: perfect depth)


class BinWorld(RandomisedWorld):
    """One compiled model: ``target`` × ``max_copies`` slots + one slot per distractor product."""

    def __init__(self, target: Product, distractors: list[Product], max_copies: int = 8,
                 camera: CameraSpec = CameraSpec(), extra_worldbody: str = "", extra: str = "",
                 randomise_lighting: bool = False, gripper: bool | str = False, seed: int = 0,
                 domain: DomainConfig | None = None, sensor: SensorConfig | None = None, robot=None, jaws=None, cup=None) -> None:
        """``robot``: an arm to put in the scene (e.g. :class:`binpick.sim.robot_arm.RobotArm`), with
        ``attach(spec)`` before compiling and ``bind(model)`` after; it waits at its home posture.
        ``gripper``: the floating hand's tools (jaws, suction or both; True: jaws), when there is no arm
        (an arm carries its own hand); ``jaws`` and ``cup``: their geometry (:class:`binpick.grippers.Jaws`,
        :class:`binpick.grippers.SuctionCup`; default binpick's own)."""
        self.target, self.distractors, self.camera = target, list(distractors), camera
        self.sensor = sensor if sensor is not None and sensor.realistic else None
        # the tote's tilt is the world's (one compiled model); drawn apart from the scenes' draws
        self.tote_tilt = tote_tilt(self.sensor, np.random.default_rng([seed, 0x7075])) if self.sensor else (0.0, 0.0)
        self.max_copies = max_copies
        self.domain = domain if domain is not None and domain.randomise else None
        self.half = BIN_HALF
        self.slots: list[Product] = [target] * max_copies + self.distractors
        self._seed, self.clutter = seed, []
        products = {target.id: target, **{d.id: d for d in self.distractors}}
        prefixes = {pid: f"p{i}" for i, pid in enumerate(products)}
        gripper = "jaws" if gripper is True else gripper or None
        self.xml = self._world_xml(products, prefixes, extra_worldbody, extra, randomise_lighting, gripper, robot, jaws, cup,
                                   np.random.default_rng(seed))
        if robot is None:
            self.model = mujoco.MjModel.from_xml_string(self.xml)
        else:
            spec = mujoco.MjSpec.from_string(self.xml)
            robot.attach(spec)
            self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.arm = robot.bind(self.model) if robot is not None else None
        self._index_slots()
        self.camera_id = self.model.camera("overhead").id
        self.guards = [g for g in range(self.model.ngeom) if (self.model.geom(g).name or "").startswith("bin_guard")]
        self.gripper = None
        if gripper:
            from binpick.sim.gripper import Gripper

            from binpick.grippers import SuctionCup

            self.gripper = Gripper(self.model, gripper, self.body_ids, cup or SuctionCup())
        if self.arm is not None:
            self.arm.bind_hand(self.model, self.body_ids)
        if self.domain is not None:  # generated textures go in before a renderer uploads them
            self._fill_textures(products, prefixes)
        self.renderer = renderer(self.model, camera.size, camera.size)  # (on this thread's shared OpenGL context)
        self.small = renderer(self.model, min(AMODAL_SIZE, camera.size), min(AMODAL_SIZE, camera.size))
        from binpick.sim.camera import close_at_exit

        close_at_exit(self)
        self._alpha = self.model.geom_rgba[:, 3].copy()
        self._matid = self.model.geom_matid.copy()

    def _world_xml(self, products: dict[str, Product], prefixes: dict[str, str], extra_worldbody: str, extra: str,
                   randomise_lighting: bool, gripper: str | None, robot, jaws, cup, rng: np.random.Generator) -> str:
        """The world's MJCF: the products' assets, a body per slot (parked), the floating hand or an arm's
        suction welds, binpick's look or a randomised world."""
        assets = "".join(product_assets(p, prefixes[p.id]) for p in products.values())
        bodies = "".join(product_body(p, f"slot{i}", self._parked(i), (1, 0, 0, 0), prefixes[p.id])
                         for i, p in enumerate(self.slots))
        lighting = {}
        if randomise_lighting:
            direction = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), -1.0])
            lighting = dict(light_dir=direction, light_diffuse=[rng.uniform(0.4, 0.9)] * 3,
                            table_rgba=(*rng.uniform(0.3, 0.8, 3), 1.0), bin_rgba=(*rng.uniform(0.1, 0.7, 3), 1.0))
        if gripper:
            from binpick.sim.gripper import floating_hand

            from binpick.grippers import Jaws, SuctionCup

            hand_body, hand_extra = floating_hand(gripper, len(self.slots), jaws or Jaws(), cup or SuctionCup())
            extra_worldbody, extra = extra_worldbody + hand_body, extra + hand_extra
        elif robot is not None and getattr(robot, "gripper", "jaws") != "jaws":
            from binpick.sim.hand import suction_welds

            extra += suction_welds(len(self.slots))
        if self.domain is not None:
            return self._random_world(assets, bodies, extra_worldbody, extra, rng)
        return scene_xml(assets, bodies, self.camera, extra_worldbody, extra, tote_tilt=self.tote_tilt, **lighting)

    def _index_slots(self) -> None:
        """Each slot's body, joint addresses, bounding sphere and geoms (segmentation gives geom ids)."""
        self.body_ids = [self.model.body(f"slot{i}").id for i in range(len(self.slots))]
        self.qpos_adr = [self.model.jnt_qposadr[self.model.body_jntadr[b]] for b in self.body_ids]
        self.dof_adr = [self.model.jnt_dofadr[self.model.body_jntadr[b]] for b in self.body_ids]
        # each product's bounding sphere: its geom's centre (a mesh may sit far off the body origin,
        # like pybullet's teddy) and radius; drops are placed by it
        geoms = [int(np.flatnonzero(self.model.geom_bodyid == b)[0]) for b in self.body_ids]
        self.offset = [self.model.geom_pos[g].copy() for g in geoms]
        self.radius = [float(self.model.geom_rbound[g]) for g in geoms]
        # geom id -> slot (or -1): segmentation gives geom ids
        self.geom_slot = np.full(self.model.ngeom + 1, -1, dtype=np.int16)
        for slot, body in enumerate(self.body_ids):
            self.geom_slot[np.flatnonzero(self.model.geom_bodyid == body)] = slot

    def camera_record(self, draw=None) -> dict:
        """Intrinsics and extrinsics of the scene's camera, recorded beside its annotations."""
        if draw is not None:
            fx, fy, cx, cy = draw.intrinsics()
            extrinsics = draw.extrinsics()
            fovy = draw.fovy
        else:
            fx, fy, cx, cy = self.camera.intrinsics()
            extrinsics = [[1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, self.camera.height], [0.0, 0.0, 0.0, 1.0]]
            fovy = self.camera.fovy
        return {"K": [[round(fx, 4), 0.0, round(cx, 4)], [0.0, round(fy, 4), round(cy, 4)], [0.0, 0.0, 1.0]],
                "width": self.camera.size, "height": self.camera.size, "fovy": round(fovy, 4),
                "camera_to_world": extrinsics}

    def set_guards(self, enabled: bool) -> None:
        """Switch the invisible drop guards above the tote walls on or off. They keep products that
        bounce off a pile in the tote while a scene settles, but would block a gripper carrying a
        product out of the tote."""
        self.model.geom_contype[self.guards] = int(enabled)
        self.model.geom_conaffinity[self.guards] = int(enabled)

    def close(self) -> None:
        for name in ("renderer", "small"):
            renderer = getattr(self, name, None)
            if renderer is not None:
                renderer.close()
                setattr(self, name, None)

    def _parked(self, slot: int) -> tuple[float, float, float]:
        return (PARK_X + 0.25 * (slot % 6), 0.25 * (slot // 6), 0.1)

    # ------------------------------------------------------------------ scenes
    def scene(self, copies: int, distractors: int, seed: int, still: bool = False) -> Scene:
        """Drop ``copies`` target instances and ``distractors`` distractor products, settle, render.
        ``still``: then wait until the bin is at rest (:meth:`come_to_rest`), as a picking cell's camera does."""
        if not 1 <= copies <= self.max_copies:
            raise ValueError(f"copies must be in 1..{self.max_copies}, got {copies}")
        rng = np.random.default_rng(seed)
        used = list(range(copies)) + [self.max_copies + int(i) for i in
                                      rng.choice(len(self.distractors), size=min(distractors, len(self.distractors)), replace=False)]
        for attempt in range(3):
            if self._drop_and_settle(used, rng):
                break
        self._used = used
        if still:
            self.come_to_rest()
        draw = self._randomise_scene(rng) if self.domain is not None else None
        sensing = np.random.default_rng([seed, 0x5E45])  # apart from the drops: a scene's perfect and realistic twins settle alike
        if draw is None and self.sensor is not None and self.sensor.tilts_camera:
            draw = self._tilt_camera(sensing)
        return self._observe(self.camera_record(draw), int(seed), rng, sensing)

    def come_to_rest(self, max_seconds: float = STILL_SECONDS) -> float:
        """Step the physics until every product in the tote is at rest (below STILL_SPEED and
        STILL_TURN), at most ``max_seconds``; the seconds waited. A ball still rolling when the frame
        is taken is elsewhere when the fingers arrive: a cell's camera looks at a still bin."""
        dofs = [self.dof_adr[slot] for slot in self._used]
        chunk = max(1, int(0.05 / self.model.opt.timestep))
        waited = 0.0
        while waited < max_seconds:
            moving = self.data.qvel[np.array(dofs)[:, None] + np.arange(6)] if dofs else np.zeros((0, 6))
            if not len(moving) or not np.all(np.isfinite(moving)) or (np.abs(moving[:, :3]).max() < STILL_SPEED
                                                                       and np.abs(moving[:, 3:]).max() < STILL_TURN):
                break
            for _ in range(chunk):
                mujoco.mj_step(self.model, self.data)
            waited += chunk * self.model.opt.timestep
        return waited

    def look_again(self, scene: Scene, seed: int) -> Scene:
        """The bin once at rest again (after a grasp moved things: :meth:`come_to_rest`), through the
        scene's camera: a new frame, the sensor's faults drawn anew from ``seed``."""
        self.come_to_rest()
        return self._observe(scene.camera, scene.seed, np.random.default_rng([seed, 1]), np.random.default_rng([seed, 0x5E45]))

    def _observe(self, record: dict, seed: int, rng: np.random.Generator, sensing: np.random.Generator) -> Scene:
        rgb, depth, segmentation = self.render()
        instances = self._annotate(self._used, segmentation)
        if self.domain is not None and self.domain.post_processing:
            from binpick.sim.domain import post_process

            rgb = post_process(rgb, self.domain, rng)
        drawn = {}
        if self.sensor is not None:
            depth, drawn = sense(rgb, depth, np.array(record["K"]), self.sensor, sensing, segmentation)
            drawn = {"name": self.sensor.name, "tote_tilt_degrees": [round(float(np.degrees(t)), 3) for t in self.tote_tilt], **drawn}
        return Scene(rgb, depth, segmentation, instances, self.target.id, seed, self.data.qpos.copy(), record, drawn)

    def _tilt_camera(self, rng: np.random.Generator):
        """Tilt the fixed overhead camera away from straight down by the sensor's range, aimed at the
        tote's centre from the same height (its intrinsics stay the camera spec's)."""
        from binpick.sim.domain import DomainConfig, draw_camera

        spec = self.camera
        mounting = DomainConfig(camera_height=(spec.height, spec.height), camera_tilt=self.sensor.camera_tilt,
                                camera_fovy=(spec.fovy, spec.fovy))
        draw = draw_camera(mounting, rng, spec.size, FLOOR_TOP)
        self.model.cam_pos[self.camera_id] = draw.position
        self.model.cam_quat[self.camera_id] = draw.quaternion
        mujoco.mj_forward(self.model, self.data)  # the camera's world pose follows the model's
        return draw

    def _drop_and_settle(self, used: list[int], rng: np.random.Generator) -> bool:
        self.set_guards(True)
        mujoco.mj_resetData(self.model, self.data)
        if self.arm is not None:
            self.arm.hold(self.model, self.data)
        for slot in range(len(self.slots)):
            self._place(slot, self._parked(slot), (1, 0, 0, 0))
        hx, hy = self.half
        placed: list[tuple[np.ndarray, float]] = []  # (centre, radius) of the bounding spheres so far
        for slot in rng.permutation(used):
            radius = self.radius[slot]
            room = np.maximum([hx - radius - 0.005, hy - radius - 0.005], 0.0)  # clear of the walls
            xy = rng.uniform(-room, room)
            # lowest start that overlaps nothing dropped before: overlaps start products flying
            z = FLOOR_TOP + radius + 0.01
            for centre, other in placed:
                reach = radius + other + 0.005
                gap = float(np.linalg.norm(xy - centre[:2]))
                if gap < reach:
                    z = max(z, centre[2] + float(np.sqrt(reach ** 2 - gap ** 2)))
            quaternion = rng.normal(size=4)
            quaternion /= np.linalg.norm(quaternion)
            rotation = np.zeros(9)
            mujoco.mju_quat2Mat(rotation, quaternion)
            centre = np.array([*xy, z])
            self._place(slot, centre - rotation.reshape(3, 3) @ self.offset[slot], quaternion)
            placed.append((centre, radius))
        mujoco.mj_forward(self.model, self.data)
        steps = int(SETTLE_SECONDS / self.model.opt.timestep)
        for step in range(steps):
            mujoco.mj_step(self.model, self.data)
            if step % 100 == 99:
                if not np.all(np.isfinite(self.data.qvel)):
                    return False
                if step * self.model.opt.timestep > 0.4 and np.abs(self.data.qvel).max() < 0.05:
                    break
        return bool(np.all(np.isfinite(self.data.qpos)))

    def _place(self, slot: int, position, quaternion) -> None:
        adr = self.qpos_adr[slot]
        self.data.qpos[adr:adr + 3] = position
        self.data.qpos[adr + 3:adr + 7] = quaternion
        self.data.qvel[self.dof_adr[slot]:self.dof_adr[slot] + 6] = 0.0

    def restore(self, qpos: np.ndarray) -> None:
        """Back to a settled scene (grasp trials start every attempt from the same state)."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = qpos
        if self.arm is not None:  # the arm holds the posture it was in
            self.arm.hold(self.model, self.data, qpos[self.arm.qpos])
        if self.hand is not None:  # open, no seal (the reset took every suction weld off)
            self.hand.reset(self.data)
        mujoco.mj_forward(self.model, self.data)

    @property
    def hand(self):
        """The hand that picks: the floating gripper's, or the arm's (None: no hand)."""
        return self.gripper if self.gripper is not None else (self.arm.hand if self.arm is not None else None)

    def instance_centre_and_top(self, slot: int) -> tuple[np.ndarray, float]:
        """The instance's centre and the height of its top (world axis-aligned box of its geoms)."""
        geoms = np.flatnonzero(self.model.geom_bodyid == self.body_ids[slot])
        tops, centres = [], []
        for g in geoms:
            rotation = self.data.geom_xmat[g].reshape(3, 3)
            centre = self.data.geom_xpos[g] + rotation @ self.model.geom_aabb[g, :3]
            half = np.abs(rotation) @ self.model.geom_aabb[g, 3:]
            centres.append(centre)
            tops.append(centre[2] + half[2])
        return np.mean(centres, axis=0), float(max(tops))

    # ------------------------------------------------------------------ rendering
    def render(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        renderer = self.renderer
        renderer.update_scene(self.data, camera=self.camera_id)
        rgb = renderer.render().copy()
        renderer.enable_depth_rendering()
        renderer.update_scene(self.data, camera=self.camera_id)
        depth = renderer.render().astype(np.float32)
        renderer.disable_depth_rendering()
        segmentation = self._segment(renderer)
        return rgb, depth, segmentation

    def _segment(self, renderer: mujoco.Renderer) -> np.ndarray:
        renderer.enable_segmentation_rendering()
        renderer.update_scene(self.data, camera=self.camera_id)
        ids = renderer.render()
        renderer.disable_segmentation_rendering()
        geom = np.where(ids[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), ids[..., 0], -1)
        return self.geom_slot[geom]  # index -1 maps to the extra trailing -1 entry

    def _annotate(self, used: list[int], segmentation: np.ndarray) -> list[Instance]:
        small_visible = self._segment(self.small)
        instances = []
        for slot in sorted(used):
            mask = segmentation == slot
            if not mask.any():
                continue  # fully hidden, or bounced out of view
            position = self.data.qpos[self.qpos_adr[slot]:self.qpos_adr[slot] + 3]
            centre, _ = self.instance_centre_and_top(slot)  # not the body origin: meshes may sit off it
            if centre[2] < FLOOR_TOP - 0.01 - 0.3 * np.hypot(*self.tote_tilt) or abs(centre[0]) > self.half[0] + 0.03 or abs(centre[1]) > self.half[1] + 0.03:
                continue  # fell out of the tote
            ys, xs = np.nonzero(mask)
            full = self._amodal_pixels(slot)
            visible = float(np.count_nonzero(small_visible == slot))
            product = self.slots[slot]
            instances.append(Instance(slot, product.id, product.category, slot < self.max_copies,
                                      (float(xs.min()), float(ys.min()), float(xs.max() - xs.min() + 1), float(ys.max() - ys.min() + 1)),
                                      float(mask.sum()), float(min(1.0, visible / full)) if full else 0.0,
                                      tuple(np.round(position, 5).tolist()),
                                      tuple(np.round(self.data.qpos[self.qpos_adr[slot] + 3:self.qpos_adr[slot] + 7], 5).tolist())))
        return instances

    def _amodal_pixels(self, slot: int) -> int:
        """Pixels the instance would cover alone (others hidden): the visible fraction's denominator."""
        hidden = self.model.geom_bodyid != self.body_ids[slot]
        hidden &= self.geom_slot[:-1] >= 0
        self.model.geom_rgba[hidden, 3] = 0.0
        self.model.geom_matid[hidden] = -1
        try:
            return int(np.count_nonzero(self._segment(self.small) == slot))
        finally:
            self.model.geom_rgba[:, 3] = self._alpha
            self.model.geom_matid[:] = self._matid

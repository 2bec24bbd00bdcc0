"""The warehouse pick pipeline (thesis ch. 6, Fig 1.1): an order's shop photo -> ROD with external
conditioning -> ranked detections of pickable instances -> a product check against the photos -> the
best one's 3D grasp point from depth -> a top-down grasp -> carried to the order tote -> verified.
Each detection gets a grasp from the grasp planner (:mod:`binpick.grasping`, depth only); detections
without a feasible one are skipped. After a failed attempt the robot looks at the bin again and plans
anew (a grasp of the same tool where one just failed counts for less), up to ``max_attempts``
grasps. The planning is :class:`binpick.picking.Picker`'s, the same code a real
camera's frames go through (`binpick plan`, the ROS nodes); this module renders and executes.

Each order is a new bin: K copies of the ordered product and some other products, settled from a
seed. What happened is reported per order, with a reason when it failed.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from binpick.detection.model import DetectorNetwork
from binpick.core.errors import ConfigError
from binpick.sim.bin_scene import BinWorld, Scene
from binpick.sim.mjcf import CameraSpec
from binpick.sim.products import ProductLibrary, product_dimensions
from binpick.grasping import GraspPlanner, GraspPolicyName, PinholeCamera
from binpick.core.depth import as_camera_depth
from binpick.picking import GraspPlan, Picker, Plans
from binpick.detection.photos import photo_mask
from binpick.sim.order_tote import order_tote_xml
from binpick.sim.gripper import TRIAL_TIMESTEP
from binpick.warehouse.order_pictures import write_order_pictures
from binpick.warehouse.orders import Attempt, OrderResult
from binpick.warehouse.grasping import (Reason, execute_arm_pick, execute_arm_push, execute_pick, execute_push,
                                        fixed_policy_tips, legacy_view)

GIF_SIZE = 240
MAX_PUSHES = 1  # pushes per pointed pick, to free an instance no grasp fits well (binpick.grasping.push)
ROBOTS = ("floating", "panda", "ur5e")  # what executes the picks: the floating gripper, or an arm (binpick.arm)


class PickPipeline:
    """``PickPipeline(detector, library).run_order(product_id, order, seed)``, or many with :func:`fulfil`:
    the simulator's client of :class:`binpick.picking.Picker` (render -> plan -> execute in MuJoCo),
    so the simulated orders and a real camera's frames run the same planning code.

    ``verifier`` is the product check against the shop photos (:class:`binpick.picking.Picker`:
    ``learnt``, the shipped verifier, whose ``check`` threshold is a probability, by default the one calibrated with its weights;
    ``colour``, the older hue-saturation check, 0.15; None: none). It drops confident detections of
    other products before a grasp puts them in the customer's tote. ``photos`` says which of the
    product's shop photos condition the detector: ``catalogue`` (each built-in product's views,
    :data:`binpick.sim.photos.CATALOGUE_VIEWS`, or a user's ``photos:`` list), or ``canonical`` (one).
    ``copies_from_match`` seeds the box-query detector with the surest photo detection (see ``Picker``).

    ``rank_from`` (None: off) ranks the detections scoring at least this (below the weights' own
    threshold) by detector score times the check's score: the photo-query detector often scores the
    ordered product's copies lowest in a cluttered bin, and the check tells them apart (why 0.01:
    docs/notes.md, "Tuning notes"); the picker then weighs the best ones by how much the likely copies
    agree with each other (:mod:`binpick.picking.agreement`).

    ``oracle=True`` takes the ordered product's boxes from the simulator (most visible first) instead of
    the detector: what the grasp alone achieves, to tell detection failures from grasp failures.
    ``domain`` (a :class:`binpick.sim.domain.DomainConfig`) renders the bins in another domain, e.g.
    the shifted-domain test set's camera, tote and light; ``sensor`` (a
    :class:`binpick.sim.sensor.SensorConfig`) gives its depth as a real sensor would, holes and noise,
    from a tilted camera over a tote that may not be level. ``size_check`` gives the picker the ordered
    product's catalogue dimensions, so instances clearly bigger than it are not grasped. ``gripper``:
    the hand's tools (jaws, suction or both: the planner chooses per detection, and the hand picks with
    the tool the plan names); None: the given planner's, or both."""

    def __init__(self, detector: DetectorNetwork, library: ProductLibrary, grasp: GraspPlanner | str = "learnt",
                 copies: tuple[int, int] = (3, 6), distractors: tuple[int, int] = (2, 3), max_attempts: int = 3,
                 score_threshold: float | None = None, camera: CameraSpec = CameraSpec(size=416),
                 verifier="learnt", check: float | None = None, oracle: bool = False, rank_from: float | None = 0.01,
                 domain=None, size_check: bool = True, sensor=None, photos: str = "catalogue",
                 copies_from_match: float | None = None, robot: str = "floating", gripper: str | None = None,
                 look_again: bool = True, tcp: float | None = None, mount: tuple[float, float, float] | None = None) -> None:
        if detector.spec.query != "photo":
            raise ConfigError("the pick pipeline conditions on shop photos: give a detector trained with query: photo")
        from binpick.grippers import tools_of

        if gripper is None:
            gripper = grasp.hand if isinstance(grasp, GraspPlanner) else "both"
        tools_of(gripper)  # a bad name is one line, now
        planner = grasp if isinstance(grasp, GraspPlanner) else GraspPlanner.load(grasp, hand=gripper)
        if planner.hand != gripper:
            raise ConfigError(f"the grasp planner plans for a hand with {planner.hand}, the cell's carries {gripper}")
        self.gripper = gripper
        self.look_again = look_again  # after a failed grasp: a new frame and new plans (False: the first frame's plans go on)
        if photos not in ("catalogue", "canonical"):
            raise ConfigError(f"photos must be catalogue or canonical, got {photos!r}")
        if robot not in ROBOTS:
            from binpick.core.config import did_you_mean

            raise ConfigError(f"unknown robot {robot!r}{did_you_mean(robot, ROBOTS)}; choose from {', '.join(ROBOTS)}")
        if robot != "floating" and ((domain is not None and domain.randomise) or (sensor is not None and sensor.tilts_tote)):
            raise ConfigError(f"the {robot} arm works in binpick's own cell (the default domain, a level tote): its collision "
                              "model does not follow a randomised domain or a tilted tote")
        self.robot = robot
        self.tcp = tcp  # the arm's flange to the tool point (a cell file's; None: binpick's own hand)
        self.mount = mount  # where the arm's base stands (a cell file's; None: binpick's cell's place)
        self.motion = None  # the arm's motion planner (binpick.arm.MotionPlanner); None: the floating gripper
        if robot != "floating":
            from binpick.arm import ArmKinematics, MotionPlanner

            self.motion = MotionPlanner(ArmKinematics(self.robot_arm(planner)), period=TRIAL_TIMESTEP, gripper=gripper)
        self.picker = Picker(detector, planner, score_threshold=score_threshold, verifier=None if oracle else verifier,
                             check=check, rank_from=rank_from, max_grasps=max_attempts, copies_from_match=copies_from_match,
                             reach=self.motion.reach_check if self.motion is not None else None)
        self.photo_set = photos
        self.detector, self.library, self.grasp = detector, library, planner
        self.copies, self.distractors, self.max_attempts = copies, distractors, max_attempts
        self.camera, self.oracle, self.domain, self.size_check, self.sensor = camera, oracle, domain, size_check, sensor
        self._photos: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        self.recording = None  # a binpick.viz.recording.OrderRecording: each order goes to it (binpick pick --rerun)

    def robot_arm(self, planner: GraspPlanner):
        """The arm carrying the hand ``planner`` plans for (its tools, jaws and cup) at the tool point ``tcp``."""
        from binpick.sim.robot_arm import RobotArm, arm_model

        return RobotArm.carrying(arm_model(self.robot), self.gripper, planner.gripper, planner.cup, self.tcp, self.mount)

    @property
    def score_threshold(self) -> float:
        return self.picker.score_threshold

    @property
    def check(self) -> float | None:
        return self.picker.check

    @property
    def rank_from(self) -> float | None:
        return self.picker.rank_from

    def photo(self, product_id: str) -> np.ndarray:
        """The shop's (first) photo of a product: the user's own, or rendered like the training data's."""
        return self.photos_and_masks(product_id)[0][0]

    def photos_and_masks(self, product_id: str) -> list[tuple[np.ndarray, np.ndarray]]:
        """The product's photos an order gives (``photos``: every catalogue view, or the first) and
        their product pixels (the renderer's masks; a user's photo: its alpha, or found from it)."""
        if product_id not in self._photos:
            from binpick.detection.data import read_image
            from binpick.sim.photos import catalogue_photos

            product = self.library[product_id]
            if product.photos:
                views = []
                for path in product.photos:
                    image = read_image(path, keep_alpha=True)
                    views.append((np.ascontiguousarray(image[..., :3]), photo_mask(image)))
            else:
                views = catalogue_photos(product)
            self._photos[product_id] = views if self.photo_set == "catalogue" else views[:1]
        return self._photos[product_id]

    def build_world(self, product_id: str, seed: int) -> tuple[BinWorld, np.random.Generator]:
        """The order's bin world (not yet settled) and the generator that settles it: K copies of the
        product and some others, all chosen from ``seed``."""
        rng = np.random.default_rng(seed)
        target = self.library[product_id]
        others = [p for p in sorted(self.library.products) if p != product_id]
        chosen = [self.library[others[i]] for i in rng.choice(len(others), size=self.distractors[1], replace=False)]
        robot = self.robot_arm(self.grasp) if self.robot != "floating" else None
        world = BinWorld(target, chosen, max_copies=self.copies[1], camera=self.camera, extra_worldbody=order_tote_xml(),
                         gripper=self.gripper if robot is None else False, seed=seed, domain=self.domain, sensor=self.sensor,
                         robot=robot, jaws=self.grasp.gripper, cup=self.grasp.cup)  # the hand the planner plans for
        return world, rng

    def settle(self, world: BinWorld, rng: np.random.Generator, seed: int) -> Scene:
        scene = world.scene(int(rng.integers(self.copies[0], self.copies[1] + 1)),
                            int(rng.integers(self.distractors[0], self.distractors[1] + 1)), seed, still=True)
        world.set_guards(False)  # the invisible drop guards would block the carry to the order tote
        return scene

    def run_order(self, product_id: str, order: int, seed: int, out: Path | None = None) -> OrderResult:
        started = time.perf_counter()
        world, rng = self.build_world(product_id, seed)
        frames: list[np.ndarray] = []
        overview = None
        try:
            from binpick.sim.rendering import renderer

            side = min(GIF_SIZE, self.camera.size)  # the model's framebuffer is the camera's size
            overview = renderer(world.model, side, side)
            camera_id = world.model.camera("overview").id

            caption = ["the bin"]

            def frame() -> None:
                overview.update_scene(world.data, camera=camera_id)
                frames.append((overview.render().copy(), caption[0]))

            scene = self.settle(world, rng, seed)
            frame()
            plans = self.plan(scene, product_id)
            trained = self.detector.trained_products
            result = OrderResult(order, product_id, seed, False, Reason.NO_DETECTION,
                                 seen=None if trained is None else product_id in trained, detections=plans.detections,
                                 robot=self.robot, gripper=self.gripper)
            if plans.detections and not plans:
                result.reason = Reason.NOT_THE_PRODUCT
            tick = time.perf_counter()

            def look_again(attempt: int) -> tuple[Scene, Plans]:  # after a failed grasp the bin has changed: a new frame
                seen = world.look_again(scene, seed * 31 + attempt)
                failed = [(a.grasp_point, a.tool) for a in result.attempts if a.tool is not None and a.outcome is not Reason.PLACED]
                return seen, self.plan(seen, product_id, failed)

            self.execute(world, scene, plans, result, on_frame=frame, on_caption=lambda text: caption.__setitem__(0, text),
                         look_again=look_again if self.look_again else None)
            result.timing_ms = {**plans.timing_ms, "simulated picks": round(1000 * (time.perf_counter() - tick), 1)}
            caption[0] = f"order {order}: {result.reason}"
            frame()
            if self.recording is not None:
                self.recording.frame(order, product_id, scene.rgb, as_camera_depth(scene.depth), PinholeCamera.from_record(scene.camera),
                                     plans, str(result.reason), result.attempts)
            if out is not None:
                result.gif, result.overlay, result.depth = write_order_pictures(
                    out, f"order_{order:03d}_{product_id.replace('/', '_')}", scene, plans.boxes, plans.scores, frames, result.attempts,
                    self.photo(product_id), self.picker.candidate_threshold, self.grasp.gripper.opening)
        finally:
            if overview is not None:
                overview.close()
            world.close()
        result.seconds = round(time.perf_counter() - started, 2)
        return result

    def plan(self, scene: Scene, product_id: str, failed=()) -> Plans:
        """The picker's plans for the scene's frame as a real camera would give it: depth in whole
        millimetres (a 16-bit frame), so the plan is the one `binpick plan` makes from its files."""
        views = self.photos_and_masks(product_id)
        camera, depth = PinholeCamera.from_record(scene.camera), as_camera_depth(scene.depth)
        if self.oracle:
            return self.picker.plan(scene.rgb, depth, camera, boxes=self.oracle_boxes(scene, product_id), failed=failed)
        size = product_dimensions(self.library[product_id]) if self.size_check else None
        return self.picker.plan(scene.rgb, depth, camera, photo=[image for image, _ in views],
                                photo_product_mask=[mask for _, mask in views], size=size, failed=failed)

    def execute(self, world: BinWorld, scene: Scene, plans: list[GraspPlan], result: OrderResult, on_frame=None,
                on_caption=None, look_again=None) -> None:
        """Try the plans in turn in the simulator until the ordered product lands in the order tote
        (plans without a feasible grasp are recorded and cost no attempt); ``on_caption`` hears what the
        frames show ("attempt 1 (jaws)", then "attempt 1 (jaws): slipped"). ``look_again(attempt)`` (if
        given) -> (a new frame, its plans): after a failed grasp the robot looks at the bin again and
        goes on with the new plans, as a real cell does (a slipped product has moved; the old frame's
        plans would aim where it was)."""
        queue = self.good_first(plans)
        while queue and result.grasps < self.max_attempts:
            plan = queue.pop(0)
            if self.pushes_first(plan, queue, result) and look_again is not None:
                moved, why = self.push(world, plan.push, on_frame)
                result.pushes.append({**plan.push, "moved": round(moved, 4), **({"not_taken": why} if why else {})})
                if on_caption is not None:
                    on_caption(f"push ({100 * moved:.0f} cm moved)")
                scene, replanned = look_again(result.looked_again + 1)  # the sensor's faults drawn anew for each look
                result.looked_again += 1
                queue = self.good_first(replanned)
                continue
            if not plan.feasible:
                result.attempts.append(Attempt(plan.box, plan.score, plan.same_product, [], Reason.NO_GRASP, None,
                                               rejected=plan.rejected))
                result.reason = Reason.NO_GRASP
                continue
            tips = self.tips(plan, scene)
            tool = plan.tool or "jaws"
            attempt = result.grasps + 1
            if on_caption is not None:
                on_caption(f"attempt {attempt} ({tool})")
            if self.motion is not None:
                outcome = execute_arm_pick(world, self.motion, tips, plan.yaw, on_frame=on_frame, tool=tool)
                if outcome.unreachable:  # the picker checked the reach; the lift, carry or way home may still fail
                    rejected = {**plan.rejected, outcome.unreachable: plan.rejected.get(outcome.unreachable, 0) + 1}
                    result.attempts.append(Attempt(plan.box, plan.score, plan.same_product, [], Reason.NO_GRASP, None,
                                                   rejected=rejected))
                    result.reason = Reason.NO_GRASP
                    continue
            else:
                outcome = execute_pick(world, tips, plan.yaw, on_frame=on_frame, tool=tool)
            lifted = world.slots[outcome.lifted_slot].id if outcome.lifted_slot is not None else None
            if on_caption is not None:
                wrong = f" ({lifted.split('/')[-1]}, not the ordered product)" if lifted not in (None, result.product) and outcome.placed else ""
                on_caption(f"attempt {attempt} ({tool}): {outcome.reason}{wrong}")
                if on_frame is not None:
                    on_frame()
            wrong = lifted not in (None, result.product)
            result.attempts.append(Attempt(plan.box, plan.score, plan.same_product, np.round(tips, 4).tolist(),
                                           Reason.WRONG_PRODUCT if wrong and outcome.placed else outcome.reason, lifted, plan.yaw, plan.width, plan.quality, plan.rejected,
                                           outcome.motion_s, outcome.planning_ms, outcome.collisions, outcome.grasp_error_mm,
                                           tool, outcome.why))
            if outcome.placed and lifted == result.product:
                result.success, result.reason = True, Reason.PLACED
                return
            result.reason = Reason.WRONG_PRODUCT if wrong else outcome.reason
            if wrong and outcome.placed:  # another product is in the customer's tote: the order is wrong whatever
                return  # follows (a cell stops and calls a person), and it is never counted as placed
            if look_again is not None and result.grasps < self.max_attempts:
                scene, replanned = look_again(result.looked_again + 1)
                result.looked_again += 1
                queue = self.good_first(replanned)

    def good_first(self, plans) -> list[GraspPlan]:
        """The plans in their order, but those whose grasp is predicted to fail most of the time
        (:meth:`Picker.hopeless`) after those worth trying: a copy with a 0.99 grasp before one whose
        only grasp is a cup on a ball."""
        return sorted(plans, key=lambda p: p.feasible and self.picker.hopeless(p))

    def push(self, world: BinWorld, push: dict, on_frame=None) -> tuple[float, str | None]:
        """Execute a plan's push with the floating gripper or the arm; (moved m, why the arm could not: None if it did)."""
        start, end = np.array(push["start"]), np.array(push["end"])
        if self.motion is not None:
            return execute_arm_push(world, self.motion, start, end, push["yaw"], on_frame=on_frame)
        return execute_push(world, start, end, push["yaw"], on_frame=on_frame), None

    def pushes_first(self, plan: GraspPlan, queue: list[GraspPlan], result: OrderResult) -> bool:
        """Whether to push ``plan``'s instance free before anything else: it offers a push (no grasp, or
        one predicted to fail most of the time), no plan after it has a grasp worth trying, and the
        order has pushes left."""
        if plan.push is None or len(result.pushes) >= MAX_PUSHES or "jaws" not in self.grasp.tools:
            return False
        return not any(p.feasible and not self.picker.hopeless(p) for p in queue)

    def pick_pointed(self, world: BinWorld, scene: Scene, query_box, result: OrderResult) -> None:
        """Pick the instance a person pointed at (``query_box``, pixels of ``scene``'s frame) as a robot
        would: plan on it (then on the copies of it the detector finds), execute the best feasible grasp,
        and after a failed one look at the bin again, find the instance again near where it was (the
        box-conditioned detector on the new frame, :meth:`Picker.find_again`) and plan anew, up to
        ``max_attempts`` grasps. When no grasp fits it well (against a wall, in a corner) and the plan
        offers a push, the closed jaws push it free first (MAX_PUSHES, no grasp counted) and it is
        found again the same way. When it is not found again (it left), stop: nothing else is grasped
        in its place."""
        from binpick.core.errors import InputFileError

        for look in range(1, self.max_attempts + MAX_PUSHES + 1):  # each look: a push or a grasp (or the end)
            if result.grasps >= self.max_attempts:
                break
            camera = PinholeCamera.from_record(scene.camera)
            try:
                failed = [(a.grasp_point, a.tool) for a in result.attempts if a.tool is not None and a.outcome is not Reason.PLACED]
                plans = self.picker.plan(scene.rgb, as_camera_depth(scene.depth), camera, query_box=query_box, max_grasps=1,
                                         failed=failed)
            except InputFileError:  # nothing stands in the box any more
                break
            result.detections = max(result.detections, plans.detections)
            chosen = next(iter(plans.grasps), None)
            pointed = plans[0] if len(plans) else None
            others = [p for p in plans if p is not pointed]  # its copies: one with a grasp worth trying goes first
            push = pointed.push if pointed is not None and self.pushes_first(pointed, others, result) else None
            pushed = None
            if push is not None:
                moved, why = self.push(world, push)
                result.pushes.append({**push, "moved": round(moved, 4), **({"not_taken": why} if why else {})})
                pushed = None if why else push  # found again along it only where it was made
            elif chosen is None:
                result.attempts.append(Attempt(pointed.box if pointed is not None else list(query_box), 1.0, None, [], Reason.NO_GRASP,
                                               None, rejected=pointed.rejected if pointed is not None else {}))
                result.reason = Reason.NO_GRASP
                break
            else:
                self.execute(world, scene, [chosen], result)
                if result.success:
                    return
            seen = world.look_again(scene, result.seed * 31 + look)
            again = self.picker.find_again(scene.rgb, as_camera_depth(scene.depth), query_box, seen.rgb,
                                           as_camera_depth(seen.depth), camera, pushed=pushed)
            result.found_again.append(None if again is None else [float(v) for v in again])
            if again is None:
                break
            scene, query_box = seen, again

    def tips(self, plan: GraspPlan, scene: Scene) -> np.ndarray:
        """Where the fingertips go. The fixed policy keeps the grasp point and depth it had before the
        planner existed (from the overhead camera), so its rows stay comparable."""
        if self.grasp.policy is GraspPolicyName.FIXED and legacy_view(scene):
            return fixed_policy_tips(plan.box, scene.depth, self.camera)
        return np.asarray(plan.position, dtype=float)

    @staticmethod
    def oracle_boxes(scene: Scene, product_id: str) -> tuple[np.ndarray, np.ndarray]:
        """The ordered product's boxes from the simulator, most visible first, scored by visibility."""
        mine = sorted((i for i in scene.instances if i.product_id == product_id and i.visible_fraction >= 0.5),
                      key=lambda i: -i.visible_fraction)
        return np.array([i.bbox for i in mine], dtype=float).reshape(-1, 4), np.array([i.visible_fraction for i in mine])

"""Pick planning from one RGB-D frame, with no simulator in it: the step between a robot's camera and
its controller (thesis ch. 6: ROS as the interface between the learning system and a real robot).

    picker = Picker.load()                                   # shipped detector and grasp model
    plans = picker.plan(rgb, depth, camera, photo=photo)     # or query_box=(x, y, w, h)
    best = plans[0]            # position (m) + quaternion (x, y, z, w) in the robot's base frame

ROD (conditioned on the shop photo or several photos of the product, or on a box around one
instance) finds the ordered product's instances; a product check against the photos (a learnt
verifier whose output is a probability, :mod:`binpick.detection.verifier`; against a query box, a
colour check in the frame's own light) drops confident detections of other products and ranks the
rest; each in turn gets a grasp from depth (:mod:`binpick.grasping`) until ``max_grasps`` have a
feasible one (default one: after a failed grasp a cell looks again and plans anew, so a frame's second and
third plans are rarely used, and each costs about as much as the first; ask for more where they are). The simulator's pick loop, ``binpick plan`` and the ROS nodes all call this.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from binpick.core.errors import ConfigError, InputFileError
from binpick.grasping import DepthFrame, GraspChoice, GraspPlanner, PinholeCamera
from binpick.grasping.planner import GraspPolicyName
from binpick.grasping.push import PUSH_WHEN_BELOW, plan_push
from binpick.picking.agreement import POWER as AGREEMENT_POWER, rank_by_support
from binpick.picking.camera_info import CameraInfo
from binpick.picking.find_again import find_again
from binpick.picking.inputs import (WORKING_PIXELS, as_camera_info, as_photos, as_query_box, check_frame, one_blas_thread,
                                    working_frame)
from binpick.picking.plans import LARGER, GraspPlan, Plans, grasp_orientation, larger_than
from binpick.picking.pose_check import check_camera_pose
from binpick.picking.product_check import QUERY_CHECK, THRESHOLDS, VERIFIERS, frame_windows, product_scores
from binpick.picking.workspace import OUTSIDE, Workspace

REACH_TRIES = 4  # candidates of one detection checked for the robot's reach before it is given up
DEFAULT_GRIPPER = "both"  # the hand binpick plans for unless told: jaws and a suction cup


class Picker:
    """``Picker.load(...).plan(rgb, depth, camera, photo=...)``: grasps for the ordered product.

    ``verifier``: the product check against shop photos: ``learnt`` (the shipped
    :class:`~binpick.detection.verifier.ProductVerifier`, or one given), ``colour`` (hue-saturation
    histogram intersection, the older tuned check) or None (no check). ``check`` drops detections it
    scores below this (default: the threshold calibrated with the learnt one's weights, a probability; 0.15 for colour). Against a
    query box the check is the colour one in the frame's own light. ``rank_from`` (None: off)
    considers detections down to this detector score and ranks them by detector score times the
    check's score, and by how much the best-ranked ones agree with each other (``agreement``, a power;
    None: off; :mod:`binpick.picking.agreement`). ``copies_from_match`` (None: off): where the product check gives a photo detection
    at least this probability, the box-query detector is seeded with that instance's box to find its
    copies too (they join the photo's detections, checked the same way). Their values and why are in
    :class:`binpick.warehouse.pipeline.PickPipeline`. ``reach`` (None: any grasp goes) is the robot's
    reachability check, ``reach(position, yaw)`` (``reach(position, yaw, "suction")`` for a suction
    grasp, ``"push"`` for a push's start with the jaws shut) -> ``(None, yaw it takes)`` or ``(reason, yaw)`` when
    the arm cannot take that grasp (no IK solution, a collision on the way down, a wrist flip): a
    detection's grasp the arm cannot take gives way to its next best candidate the arm can (up to
    ``REACH_TRIES``); the reasons are counted with the plan's other rejections, and the plan's yaw is
    the one the arm takes (the same jaws, perhaps a half turn round)."""

    def __init__(self, detector, grasp: GraspPlanner, crop_detector=None, score_threshold: float | None = None,
                 verifier="learnt", check: float | None = None, rank_from: float | None = 0.01, max_grasps: int = 1,
                 workspace: Workspace | None = None, copies_from_match: float | None = None, reach=None,
                 working_pixels: int | None = WORKING_PIXELS, agreement: float | None = AGREEMENT_POWER) -> None:
        # a Detector (binpick.Detector.load(...)) or the network inside one
        detector, crop_detector = (getattr(d, "inference_network", d) for d in (detector, crop_detector))
        self.detector, self.crop_detector, self.grasp = detector, crop_detector, grasp
        self.workspace = workspace  # None: the camera's own (camera.yaml), else around its view
        if score_threshold is None:  # the weights' own threshold where they carry one (scores are calibrated per model)
            own = getattr(detector, "score_threshold", None) if detector is not None else None
            score_threshold = own if own is not None else 0.2
        if isinstance(verifier, str) and verifier not in VERIFIERS:
            raise ConfigError(f"verifier must be one of {', '.join(VERIFIERS)} (or none), got {verifier!r}")
        self.verifier = verifier  # "learnt" is loaded when first needed
        kind = verifier if isinstance(verifier, str) or verifier is None else "learnt"
        # the learnt check's threshold is the one calibrated with its weights (read when it is first needed)
        self._check = check if check is not None or verifier is None or kind == "learnt" else THRESHOLDS[kind]
        self._check_given = check is not None  # a threshold given by the caller holds against a query box too
        self.score_threshold, self.rank_from = score_threshold, rank_from
        if max_grasps < 1:
            raise ConfigError(f"max_grasps must be at least 1, got {max_grasps}")
        self.max_grasps = max_grasps
        self.copies_from_match = copies_from_match
        if agreement is not None and not (np.isfinite(agreement) and agreement >= 0):
            raise ConfigError(f"agreement must be a power of at least 0 (or None: off), got {agreement!r}")
        self.agreement = agreement  # None: photo detections ranked without asking them of each other
        # reach(position, yaw) -> (None, the yaw the robot takes) or (why it cannot take that grasp, yaw)
        # (binpick.arm.MotionPlanner.reach_check)
        self.reach = reach
        self.working_pixels = working_pixels  # larger frames are planned at this many pixels (None: at their own size)

    @property
    def check(self) -> float | None:
        """The product check's threshold: the caller's, else the learnt verifier's calibrated one
        (chosen on held-out products, carried in its weights' metadata), else the colour check's."""
        if self._check is None and self.verifier is not None:
            self._check = float(self.learnt_verifier().meta.get("threshold", THRESHOLDS["learnt"]))
        return self._check

    def learnt_verifier(self):
        """The learnt product check (the shipped one, loaded the first time it is needed)."""
        if self.verifier == "learnt":
            from binpick.detection.verifier import ProductVerifier

            self.verifier = ProductVerifier.load()
        return self.verifier

    @classmethod
    def load(cls, detector: str | Path | None = None, grasp: str = "learnt", grasp_weights: str | Path | None = None,
             crop_detector: str | Path | None = None, runtime: str = "torch", gripper: str = DEFAULT_GRIPPER,
             cell=None, **settings) -> Picker:
        """The photo-conditioned detector (default: shipped), the box-conditioned one for ``query_box``
        (default: shipped, loaded when first needed) and the grasp policy (default: learnt, shipped) for
        a hand carrying ``gripper`` (jaws, suction or both: grasps only for the tools it has), or the hand
        of ``cell`` (a :class:`binpick.cell.Cell`: its tools, its jaws' stroke and fingers, its cup).
        ``runtime="onnx"`` runs the photo-conditioned detector in ONNX Runtime."""
        from binpick.detection import Detector
        from binpick.detection.detector import PICKING

        if cell is not None:
            planner = GraspPlanner.load(grasp, grasp_weights, hand=cell.tools, gripper=cell.jaws, cup=cell.cup)
        else:
            planner = GraspPlanner.load(grasp, grasp_weights, hand=gripper)
        network = Detector.load(detector or PICKING, runtime=runtime).inference_network
        crop = Detector.load(crop_detector).inference_network if crop_detector is not None else None
        return cls(network, planner, crop, **settings)

    def warm_up(self, size: int = 320) -> None:
        """Run the detector once on a blank frame: a process's first inference costs seconds (kernel
        selection, allocation), which a node should pay at start, not on its first request."""
        from binpick.detection.predict import predict

        blank = np.zeros((size, size, 3), np.uint8)
        if self.detector is not None and self.detector.spec.query == "photo":
            predict(self.detector, blank, query_image=blank[:96, :96], score_threshold=1.0,
                    depth=np.full((size, size), 0.8, np.float32))

    @property
    def candidate_threshold(self) -> float:
        """The lowest detection score considered."""
        return self.score_threshold if self.rank_from is None else min(self.score_threshold, self.rank_from)

    def detector_for(self, query_box) -> Any:
        """The network that answers a query: the photo detector for shop photos (``query_box`` None),
        else the box-conditioned one (the shipped crop detector, loaded when first needed)."""
        if query_box is None:
            if self.detector is None or self.detector.spec.query != "photo":
                raise ConfigError("planning from a shop photo needs a detector trained with query: photo")
            return self.detector
        if self.detector is not None and self.detector.spec.query != "photo":
            return self.detector
        if self.crop_detector is None:
            from binpick.detection import Detector

            self.crop_detector = Detector.load("rod_tiny_320").inference_network
        return self.crop_detector

    def plan(self, rgb: np.ndarray, depth: np.ndarray, camera: CameraInfo | PinholeCamera, photo=None,
             query_box=None, *, photo_product_mask=None, boxes: tuple[np.ndarray, np.ndarray] | None = None,
             max_grasps: int | None = None, size=None, copies_only: bool = False, failed=()) -> Plans:
        """Grasps for the product in ``photo`` (or the one inside ``query_box``, x, y, w, h pixels) in
        one frame: ``rgb`` uint8 (H, W, 3), ``depth`` metres (H, W, 0 = no reading), registered to the
        colour camera (at its size, or one of the same aspect). ``boxes`` (boxes, scores) skips
        detection and the product check: grasps for detections from elsewhere. ``photo`` is one shop
        photo or a list of the product's photos (views, studios: the best match over them counts); each
        may be RGBA, its alpha marking the product's pixels (as ``photo_product_mask`` does, one mask or
        a list; default: found from the photo). ``size``: the product's catalogue dimensions (m, any
        order); detections whose instance is clearly bigger are not planned (rejected as larger than the
        ordered product).

        A ``query_box`` points at one instance: it is planned first, then the copies the detector
        finds of it. ``copies_only`` plans on the other copies alone (the thesis's evaluation of
        repeated-object detection). A query box with no object under it is one clear line. ``failed``:
        grasps that failed since (base-frame positions and their tools, ``[(position, tool), ...]``): a
        candidate of that tool where one failed counts for less (a regrasp tries the other tool or another
        place; :meth:`binpick.grasping.GraspPlanner.choose`)."""
        with one_blas_thread():
            self._failed = [(np.asarray(position, dtype=float), str(tool)) for position, tool in failed]
            return self._plan(rgb, depth, camera, photo, query_box, photo_product_mask, boxes, max_grasps, size, copies_only)

    def _plan(self, rgb, depth, camera, photo, query_box, photo_product_mask, boxes, max_grasps, size, copies_only) -> Plans:
        info = as_camera_info(camera)
        check_frame(rgb, depth, info.camera)
        full = (info.camera.width, info.camera.height)
        if query_box is not None:
            query_box = as_query_box(query_box, *full)
        photos = as_photos(photo, photo_product_mask)
        if boxes is None and (not photos) == (query_box is None):
            raise ConfigError("give exactly one of a shop photo (or several of one product) or a query box")
        timing: dict[str, float] = {}
        started = time.perf_counter()
        rgb, depth, info, scale = self.working_frame(rgb, depth, info)
        work = (info.camera.width, info.camera.height)
        if work != full:
            query_box = None if query_box is None else np.asarray(query_box, dtype=float) * scale
            boxes = None if boxes is None else (np.asarray(boxes[0], dtype=float).reshape(-1, 4) * scale, boxes[1])
        frame = self.grasp.frame(depth, info.camera)  # once per frame: holes filled, support plane found
        check_camera_pose(frame, self.workspace or info.workspace)  # a pose its own depth contradicts: one line, no plan
        workspace = self.workspace or info.workspace or Workspace.around_view(info.camera)
        timing["depth"] = 1000 * (time.perf_counter() - started)
        pointed, windows = None, None
        if query_box is not None and boxes is None:
            pointed = self.pointed_instance(frame, query_box)
        tick = time.perf_counter()
        if boxes is not None:
            found, scores = np.asarray(boxes[0], dtype=float).reshape(-1, 4), np.asarray(boxes[1], dtype=float)
            checked: list[float | None] = [None] * len(found)
        else:
            found, scores = self.detect(rgb, frame, photos, query_box)
            timing["detect"] = 1000 * (time.perf_counter() - tick)
            tick = time.perf_counter()
            windows = self.frame_windows(rgb, depth, photos)  # read once, for the photo check and the agreement
            checked = self.product_scores(rgb, depth, frame, found, photos, query_box, windows)
            if photos and self.copies_from_match is not None:
                found, scores, checked = self.copies_of_best_match(rgb, depth, frame, photos, found, scores, checked, windows)
            timing["check"] = 1000 * (time.perf_counter() - tick)
        ranked = list(zip(found, scores, checked))
        threshold = self.check if query_box is None or self._check_given else QUERY_CHECK
        if threshold is not None and self.verifier is not None:
            ranked = [c for c in ranked if c[2] is None or c[2] >= threshold]
        not_the_product = len(found) - len(ranked)
        if self.rank_from is not None:  # the product check's evidence joins the detector's in the ranking
            ranked.sort(key=lambda c: -c[1] * (c[2] if c[2] is not None else 1.0))
            if self.agreement is not None and photos and query_box is None and hasattr(self.learnt_verifier(), "pairwise"):
                tick_agree = time.perf_counter()  # copies agree with each other, a look-alike with few
                shared = {} if windows is None else {"windows": windows}  # a verifier of one's own may not take them
                ranked = rank_by_support(ranked, lambda boxes_: self.verifier.pairwise(rgb, depth, boxes_, **shared), self.agreement)
                timing["agree"] = 1000 * (time.perf_counter() - tick_agree)
        tick = time.perf_counter()
        plans: list[GraspPlan] = []
        wanted = max_grasps or self.max_grasps
        if pointed is not None and not copies_only:  # what the user pointed at first, then its copies
            plans.append(self.plan_detection(frame, query_box, 1.0, None, size, choice=pointed, workspace=workspace))
        for box, score, same in ranked:
            if sum(p.feasible for p in plans) >= wanted:
                break
            plans.append(self.plan_detection(frame, box, float(score), same, size, workspace=workspace))
        timing["grasp"] = 1000 * (time.perf_counter() - tick)
        timing["total"] = 1000 * (time.perf_counter() - started)
        if work != full:  # boxes back in the caller's pixels (grasp poses are in the base frame: unchanged)
            for plan in plans:
                plan.box = [round(float(v), 2) for v in np.asarray(plan.box, dtype=float) / scale]
            found = np.asarray(found, dtype=float).reshape(-1, 4) / scale
        return Plans(plans, info.base_frame, {k: round(v, 2) for k, v in timing.items()}, found, scores, not_the_product)

    def working_frame(self, rgb, depth, info: CameraInfo) -> tuple[np.ndarray, np.ndarray, CameraInfo, np.ndarray]:
        """:func:`binpick.picking.inputs.working_frame` at this picker's working resolution."""
        return working_frame(rgb, depth, info, self.working_pixels)

    def detect(self, rgb: np.ndarray, frame: DepthFrame, photos: list[tuple[np.ndarray, np.ndarray | None]],
               query_box) -> tuple[np.ndarray, np.ndarray]:
        """(boxes x, y, w, h; scores) of the ordered product: the copies of a query box (the pointed
        instance itself left out: it is planned as pointed), or the best match over the photos."""
        from binpick.detection.ops import box_iou, nms, xywh_to_xyxy
        from binpick.detection.predict import predict

        model = self.detector_for(query_box)
        if query_box is not None:
            prediction = predict(model, rgb, query_box=query_box, score_threshold=self.candidate_threshold, depth=frame.filled)
            found, scores = prediction.boxes, prediction.scores
            if len(found):
                overlap = box_iou(xywh_to_xyxy(torch.as_tensor(found, dtype=torch.float32)),
                                  xywh_to_xyxy(torch.as_tensor(query_box[None], dtype=torch.float32)))[:, 0].numpy()
                found, scores = found[overlap < 0.5].reshape(-1, 4), scores[overlap < 0.5]
            return found, scores
        every_box, every_score = [], []
        for image, mask in photos:  # the product mask travels as alpha, for framing
            query_image = image if mask is None else np.dstack([image, np.where(mask, 255, 0).astype(np.uint8)])
            prediction = predict(model, rgb, query_image=query_image, score_threshold=self.candidate_threshold,
                                 depth=frame.filled)  # holes filled, as the planner sees it
            every_box.append(prediction.boxes.reshape(-1, 4))
            every_score.append(prediction.scores.reshape(-1))
        found, scores = np.concatenate(every_box), np.concatenate(every_score)
        if len(photos) > 1 and len(found):  # one box per instance: its best score over the photos
            keep = nms(xywh_to_xyxy(torch.as_tensor(found, dtype=torch.float32)), torch.as_tensor(scores, dtype=torch.float32), 0.5)
            keep = keep.numpy()
            found, scores = found[keep], scores[keep]
        order = np.argsort(-scores, kind="stable")
        return found[order].reshape(-1, 4), scores[order]

    def copies_of_best_match(self, rgb: np.ndarray, depth: np.ndarray, frame: DepthFrame, photos, found: np.ndarray,
                             scores: np.ndarray, checked: list[float | None], windows=None):
        """The photo detections plus the copies the box-query detector finds of the surest of them (the
        product check at least ``copies_from_match``), those not already found, checked the same way."""
        from binpick.detection.ops import box_iou, xywh_to_xyxy
        from binpick.detection.predict import predict

        sure = [i for i, p in enumerate(checked) if p is not None and p >= self.copies_from_match
                and found[i][2] >= 2 and found[i][3] >= 2]
        if not sure:
            return found, scores, checked
        best = max(sure, key=lambda i: scores[i] * checked[i])
        prediction = predict(self.detector_for(found[best]), rgb, query_box=found[best],
                             score_threshold=self.candidate_threshold, depth=frame.filled)
        extra, extra_scores = prediction.boxes.reshape(-1, 4), prediction.scores.reshape(-1)
        if len(extra):
            overlap = box_iou(xywh_to_xyxy(torch.as_tensor(extra, dtype=torch.float32)),
                              xywh_to_xyxy(torch.as_tensor(found, dtype=torch.float32))).amax(1).numpy()
            extra, extra_scores = extra[overlap < 0.5], extra_scores[overlap < 0.5]
        if not len(extra):
            return found, scores, checked
        return (np.concatenate([found, extra]), np.concatenate([scores, extra_scores]),
                list(checked) + self.product_scores(rgb, depth, frame, extra, photos, None, windows))

    def frame_windows(self, rgb: np.ndarray, depth: np.ndarray, photos):
        """The learnt product check's windows of this frame (read once per plan; None without one)."""
        learnt = bool(photos) and self.verifier not in (None, "colour")  # a query box, or no learnt check: nothing to read
        return frame_windows(self.learnt_verifier(), rgb, depth, photos) if learnt else None

    def product_scores(self, rgb: np.ndarray, depth: np.ndarray, frame: DepthFrame, boxes: np.ndarray,
                       photos: list[tuple[np.ndarray, np.ndarray | None]], query_box, windows=None) -> list[float | None]:
        """:func:`binpick.picking.product_check.product_scores` with this picker's check."""
        verifier = self.learnt_verifier() if self.verifier == "learnt" and query_box is None and len(boxes) else self.verifier
        return product_scores(verifier, rgb, depth, frame, boxes, photos, query_box, windows)

    def find_again(self, previous_rgb: np.ndarray, previous_depth: np.ndarray, previous_box, rgb: np.ndarray, depth: np.ndarray,
                   camera: CameraInfo | PinholeCamera, pushed: dict | None = None) -> np.ndarray | None:
        """Where the instance a person pointed at (``previous_box`` in the previous frame) is in a new
        frame of the same camera, after a grasp moved things (:func:`binpick.picking.find_again.find_again`);
        None when nothing near matches (it left). ``pushed``: the push made since (a plan's ``push``)."""
        return find_again(self, previous_rgb, previous_depth, previous_box, rgb, depth, camera, pushed)

    def pointed_instance(self, frame: DepthFrame, query_box) -> GraspChoice:
        """The grasp for the instance a query box points at; a box over nothing standing out (only the
        floor beneath it in depth) is one clear line."""
        choice = self.grasp.choose(frame, query_box, failed=getattr(self, "_failed", ()))
        if choice.surface is None:
            x, y, w, h = (float(v) for v in query_box)
            raise InputFileError(f"the query box {x:g},{y:g},{w:g},{h:g} lies on no object: depth shows only the surface "
                                 "beneath it (draw the box around one instance of the product)")
        return choice

    def plan_detection(self, frame: DepthFrame, box, score: float, similarity: float | None, size=None,
                       choice: GraspChoice | None = None, workspace: Workspace | None = None) -> GraspPlan:
        """The plan for one detection: its best grasp, unless the instance is larger than the ordered
        product or the grasp lies outside ``workspace`` (then rejected, with the reason, and no pose)."""
        choice = choice if choice is not None else self.grasp.choose(frame, box, failed=getattr(self, "_failed", ()))
        widths = [c.width for c in choice.candidates if c.tool == "jaws" and np.isfinite(c.width) and c.width > 0]
        plan = GraspPlan([round(float(v), 2) for v in box], round(score, 4), None if similarity is None else round(similarity, 3),
                         rejected=choice.rejections(), narrowest=round(float(min(widths)), 4) if widths else None)
        if size is not None and choice.surface is not None and larger_than(choice.surface, size):
            plan.rejected = {LARGER: 1}
            return plan
        chosen = choice.chosen
        if chosen is not None and workspace is not None and not workspace.contains(chosen.position):
            plan.rejected = {**plan.rejected, OUTSIDE: 1}
            return plan
        yaw = None if chosen is None else float(chosen.yaw)
        if chosen is not None and chosen.tool not in self.grasp.tools:  # never a grasp for a tool the cell lacks
            raise AssertionError(f"the planner chose a {chosen.tool} grasp for a hand with {', '.join(self.grasp.tools)}")
        if chosen is not None and self.reach is not None:
            chosen, yaw, unreachable = self.reachable(choice, workspace)
            for reason, count in unreachable.items():
                plan.rejected[reason] = plan.rejected.get(reason, 0) + count
        if chosen is not None:
            plan.tool = chosen.tool
            plan.position = [round(float(v), 4) for v in chosen.position]
            plan.yaw = round(yaw, 4)
            plan.orientation = [round(v, 6) for v in grasp_orientation(plan.yaw)]
            if chosen.tool == "jaws":
                plan.width = round(float(chosen.width), 4)
                plan.opening = float(self.grasp.gripper.opening)
            plan.quality = None if chosen.quality is None else round(float(chosen.quality), 4)
        if (choice.surface is not None and "jaws" in self.grasp.tools and self.grasp.policy is not GraspPolicyName.FIXED
                and self.hopeless(plan)):  # the push is the closed jaws': a cup-only hand gets none
            push = plan_push(frame, choice.surface)
            rounded = None if push is None else push.as_dict()  # (judged as it is emitted, rounded)
            if push is not None and (workspace is None or (workspace.contains(rounded["start"]) and workspace.contains(rounded["end"]))):
                if self.reach is None or any(self.reach(push.start, yaw, "push")[0] is None for yaw in (push.yaw, push.yaw + np.pi / 2)):
                    plan.push = rounded  # (an arm's push: only where it can reach down onto it with the fingers shut)
        return plan

    def hopeless(self, plan: GraspPlan) -> bool:
        """No grasp, or one predicted to fail at least PUSH_WHEN_BELOW of the time (its quality is a
        success probability: suction's, or the learnt jaws policy's): a push to free it comes first."""
        if plan.position is None:
            return True
        probability = plan.tool == "suction" or self.grasp.policy is GraspPolicyName.LEARNT
        return bool(probability and plan.quality is not None and plan.quality < PUSH_WHEN_BELOW)

    def reachable(self, choice: GraspChoice, workspace: Workspace | None = None):
        """The best of the detection's candidates the robot can take (the chosen one first, then the
        other feasible ones inside the workspace, by quality), the jaw yaw the robot takes it with (the
        candidate's, or the same jaws a half turn round), and the reasons the ones before it could not
        be taken."""
        others = sorted((c for c in choice.candidates if c is not choice.chosen and c.rejected is None and c.quality is not None
                         and (workspace is None or workspace.contains(c.position))), key=lambda c: -c.quality)
        unreachable: dict[str, int] = {}
        for candidate in [choice.chosen, *others][:REACH_TRIES]:
            # a jaw grasp is asked as before (position, yaw); a suction grasp names its tool (its point lies lower on the hand)
            reason, yaw = (self.reach(candidate.position, float(candidate.yaw)) if candidate.tool == "jaws"
                           else self.reach(candidate.position, float(candidate.yaw), candidate.tool))
            if reason is None:
                return candidate, float(yaw), unreachable
            unreachable[reason] = unreachable.get(reason, 0) + 1
        return None, None, unreachable

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
feasible one. The simulator's pick loop, ``binpick plan`` and the ROS nodes all call this.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from binpick.errors import ConfigError, InputFileError
from binpick.grasping import DepthFrame, GraspChoice, GraspPlanner, PinholeCamera
from binpick.depth import depth_problem
from binpick.picking.camera_info import CameraInfo, matrix_to_quaternion
from binpick.detection.photos import photo_mask
from binpick.picking.colour import colour_histogram, colour_similarity, detection_mask
from binpick.picking.workspace import OUTSIDE, Workspace

APPROACH = (0.0, 0.0, -1.0)  # top-down: the gripper moves along the base frame's -z (z up)
LARGER = "larger than the ordered product"


def larger_than(surface, size, margin: float = 0.02, relative: float = 0.15) -> bool:
    """Whether what depth shows of an instance is too big to be a product of catalogue ``size`` (its
    bounding-box sides, any order): the visible top's long side against the product's longest,
    its short side against the middle one, its height against the longest. Occlusion only shrinks
    what is seen, so only too big counts. On tuning bins 95% of the products' own instances measured
    within their sides, 99% within 3.6 cm (two touching copies seen as one)."""
    first, second, _ = sorted((float(v) for v in size), reverse=True)
    major, minor = surface.extents()
    slack = lambda side: max(margin, relative * side)  # noqa: E731
    return major > first + slack(first) or minor > second + slack(second) or surface.height > first + slack(first)


def grasp_orientation(yaw: float) -> list[float]:
    """The gripper frame's quaternion (x, y, z, w) in the base frame: z along the approach (down),
    x along the jaws' closing direction (``yaw`` about the base's z), y = z x x."""
    x_axis = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    z_axis = np.array(APPROACH)
    return matrix_to_quaternion(np.stack([x_axis, np.cross(z_axis, x_axis), z_axis], axis=1))


@dataclass
class GraspPlan:
    """One detection of the ordered product and the grasp chosen for it (``position`` None: no
    candidate was feasible; ``rejected`` says why, reason -> candidates)."""

    box: list[float]  # x, y, w, h pixels in the (rectified) colour image
    score: float  # the detector's
    same_product: float | None  # the product check's: P(the ordered product) from photos, colour similarity to a query box; None: not checked
    position: list[float] | None = None  # fingertips' midpoint, base frame (m)
    orientation: list[float] | None = None  # gripper frame, quaternion x, y, z, w in the base frame
    approach: list[float] = field(default_factory=lambda: list(APPROACH))
    yaw: float | None = None  # the jaws' closing direction about the base's z (rad)
    width: float | None = None  # the instance's width across the jaws (m)
    opening: float | None = None  # how far to open the jaws before descending (m)
    quality: float | None = None  # the grasp policy's score of the chosen candidate
    rejected: dict[str, int] = field(default_factory=dict)

    @property
    def feasible(self) -> bool:
        return self.position is not None


class Plans(list):
    """``list[GraspPlan]`` in the order to try them, with what the frame gave: ``grasps`` (the
    feasible ones), ``boxes``/``scores`` of every detection above the score threshold, ``frame``
    (the base frame's name) and ``timing_ms``."""

    def __init__(self, plans: list[GraspPlan], frame: str, timing_ms: dict[str, float], boxes: np.ndarray | None = None,
                 scores: np.ndarray | None = None, not_the_product: int = 0) -> None:
        super().__init__(plans)
        self.frame, self.timing_ms = frame, timing_ms
        self.not_the_product = not_the_product  # detections the product check dropped
        self.boxes = np.zeros((0, 4)) if boxes is None else np.asarray(boxes, dtype=float).reshape(-1, 4)  # every detection
        self.scores = np.zeros(0) if scores is None else np.asarray(scores, dtype=float)

    @property
    def detections(self) -> int:
        return len(self.boxes)

    @property
    def grasps(self) -> list[GraspPlan]:
        return [p for p in self if p.feasible]

    def to_json(self) -> dict[str, Any]:
        return {"frame": self.frame, "detections": self.detections, "not_the_product": self.not_the_product, "timing_ms": self.timing_ms,
                "grasps": len(self.grasps), "plans": [asdict(p) for p in self]}

    def plot(self, rgb: np.ndarray, camera: PinholeCamera, opening: float, photo=None,
             query_box=None) -> np.ndarray:
        """The frame with each detection's box and score, and each grasp's open jaws numbered in the
        order to try them (green)."""
        from binpick.viz.detection import draw_jaws, overlay

        boxes = np.array([p.box for p in self], dtype=float).reshape(-1, 4)
        if isinstance(photo, (list, tuple)):  # several photos of the product: the first is shown
            photo = photo[0] if photo else None
        photo = None if photo is None else split_photo(photo)[0]
        picture = overlay(rgb, boxes, np.array([p.score for p in self]), query_box, photo, min_score=0.0)
        jaws = [(*jaw_pixels(camera, plan.position, plan.yaw, opening), True, str(number))
                for number, plan in enumerate(self.grasps, start=1)]
        return draw_jaws(picture, jaws)


def jaw_pixels(camera: PinholeCamera, position, yaw: float, opening: float) -> tuple[np.ndarray, np.ndarray]:
    """The open fingers' pixels (u, v) of a grasp at ``position`` closing along ``yaw``: its jaw line."""
    centre = np.asarray(position, dtype=float)
    reach = np.array([np.cos(yaw), np.sin(yaw), 0.0]) * opening / 2
    (a, b), _ = camera.project(np.stack([centre - reach, centre + reach]))
    return a, b


def split_photo(photo: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """A shop photo's RGB and its product mask: the alpha channel of an RGBA photo (a cut-out PNG),
    None for an RGB one (the colour check then takes what is not bright grey)."""
    photo = np.asarray(photo)
    if photo.ndim == 3 and photo.shape[2] == 4:
        alpha = photo[..., 3] > 127
        return np.ascontiguousarray(photo[..., :3]), None if alpha.all() or not alpha.any() else alpha
    return photo, None


def as_photos(photo, masks) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """One shop photo or a list of them as (RGB, mask) pairs. ``masks``: None (an RGBA photo's alpha,
    else found from the photo), one mask for one photo, or a list with one (or None) per photo; each
    the photo's height and width."""
    if photo is None:
        return []
    several = isinstance(photo, (list, tuple))
    photos = list(photo) if several else [photo]
    if not photos:
        return []
    if masks is None:
        masks = [None] * len(photos)
    elif isinstance(masks, np.ndarray) and not several:
        masks = [masks]
    elif not isinstance(masks, (list, tuple)) or len(masks) != len(photos):
        raise ConfigError(f"{len(photos)} photos: give one product mask per photo (a list), or none")
    pairs = []
    for image, mask in zip(photos, masks):
        rgb, alpha = split_photo(image)
        if mask is not None:
            mask = np.asarray(mask, bool)
            if mask.shape != rgb.shape[:2]:
                raise ConfigError(f"a product mask is {mask.shape[1]}x{mask.shape[0]} but its photo is {rgb.shape[1]}x{rgb.shape[0]}")
        pairs.append((rgb, alpha if mask is None else mask))
    return pairs


def as_camera_info(camera: CameraInfo | PinholeCamera) -> CameraInfo:
    return camera if isinstance(camera, CameraInfo) else CameraInfo(camera)


_BLAS = None


def one_blas_thread():
    """A context in which numpy's BLAS runs on one thread. Planning does many small matrix products
    (3-column point clouds); after each, OpenBLAS's worker threads spin on the cores and the
    detector's PyTorch threads wait for them: on 2 cores the detection stage took 2-3x as long."""
    global _BLAS
    if _BLAS is None:
        from threadpoolctl import ThreadpoolController

        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")


def same_aspect(a: tuple[int, ...], b: tuple[int, ...]) -> bool:
    """Whether two (height, width) images have the same aspect ratio (within a pixel)."""
    return abs(a[0] * b[1] - a[1] * b[0]) <= max(a[0], b[0])


def register_depth(depth: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Depth registered to the colour camera but at another resolution (a RealSense's 640x360 depth
    aligned to its 1280x720 colour), resampled to the colour's ``shape`` (height, width): nearest
    reading, so no depth is invented between an edge's two sides and holes stay holes."""
    if depth.shape == tuple(shape):
        return depth
    import cv2

    return cv2.resize(np.asarray(depth, dtype=np.float32), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)


def as_query_box(box, width: int, height: int) -> np.ndarray:
    """A query box as 4 finite numbers x, y, w, h inside a ``width`` x ``height`` image; one line if not."""
    from binpick.detection.predict import check_query_box

    try:
        array = np.asarray(box, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError(f"a query box is 4 numbers x, y, w, h, got {box!r}") from None
    if array.shape != (4,) or not np.all(np.isfinite(array)):
        raise ConfigError(f"a query box is 4 finite numbers x, y, w, h, got {array.tolist()}")
    check_query_box(array, width, height)
    return array


def check_frame(rgb: np.ndarray, depth: np.ndarray, camera: PinholeCamera) -> None:
    """Colour and depth that the calibration describes (depth registered to the colour camera, at its
    size or one of the same aspect); depth in metres."""
    rgb, depth = np.asarray(rgb), np.asarray(depth)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise InputFileError(f"colour image must be 8-bit RGB (height x width x 3), got {rgb.dtype} with shape {rgb.shape}")
    if depth.ndim != 2:
        raise InputFileError(f"depth image must be 2-D (height x width), got shape {depth.shape}")
    if depth.shape != rgb.shape[:2] and not same_aspect(depth.shape, rgb.shape[:2]):
        raise InputFileError(f"depth is {depth.shape[1]}x{depth.shape[0]} but colour is {rgb.shape[1]}x{rgb.shape[0]}: "
                             "register depth to the colour camera (its viewpoint and intrinsics; at the colour's size or "
                             "one of the same aspect, which binpick resamples)")
    if (camera.width, camera.height) != (rgb.shape[1], rgb.shape[0]):
        raise InputFileError(f"the camera calibration is for {camera.width}x{camera.height} images, the frame is "
                             f"{rgb.shape[1]}x{rgb.shape[0]}")
    problem = depth_problem(depth)
    if problem is not None:
        hint = "" if "no valid reading" in problem else ": give depth in metres (16-bit PNGs in millimetres are converted when read)"
        raise InputFileError(f"depth image {problem}{hint}")


VERIFIERS = ("learnt", "colour")
# the learnt check's is a probability (calibrated on randomised bins): detections it gives under 20% are
# dropped and the rest ranked by detector score times it. On tuning bins (40 orders each, seeds apart from
# the benchmarks') 0.2 put a right instance first in 31 of 40 shifted-light orders against 25 at 0.5, the
# wrong-first orders staying 2 of 40, and changed nothing in binpick's own light (36 right first at every
# threshold from 0.1 to 0.5). The colour check's is a histogram intersection, tuned in binpick's own light.
THRESHOLDS = {"learnt": 0.2, "colour": 0.15}


class Picker:
    """``Picker.load(...).plan(rgb, depth, camera, photo=...)``: grasps for the ordered product.

    ``verifier``: the product check against shop photos: ``learnt`` (the shipped
    :class:`~binpick.detection.verifier.ProductVerifier`, or one given), ``colour`` (hue-saturation
    histogram intersection, the older tuned check) or None (no check). ``check`` drops detections it
    scores below this (default: 0.2 for the learnt one, a probability; 0.15 for colour). Against a
    query box the check is the colour one in the frame's own light. ``rank_from`` (None: off)
    considers detections down to this detector score and ranks them by detector score times the
    check's score. ``copies_from_match`` (None: off): where the product check gives a photo detection
    at least this probability, the box-query detector is seeded with that instance's box to find its
    copies too (they join the photo's detections, checked the same way). Their values and why are in
    :class:`binpick.warehouse.pipeline.PickPipeline`."""

    def __init__(self, detector, grasp: GraspPlanner, crop_detector=None, score_threshold: float | None = None,
                 verifier="learnt", check: float | None = None, rank_from: float | None = 0.01, max_grasps: int = 3,
                 workspace: Workspace | None = None, copies_from_match: float | None = None) -> None:
        self.detector, self.crop_detector, self.grasp = detector, crop_detector, grasp
        self.workspace = workspace  # None: the camera's own (camera.yaml), else around its view
        if score_threshold is None:  # the weights' own threshold where they carry one (scores are calibrated per model)
            own = getattr(detector, "score_threshold", None) if detector is not None else None
            score_threshold = own if own is not None else 0.2
        if isinstance(verifier, str) and verifier not in VERIFIERS:
            raise ConfigError(f"verifier must be one of {', '.join(VERIFIERS)} (or none), got {verifier!r}")
        self.verifier = verifier  # "learnt" is loaded when first needed
        kind = verifier if isinstance(verifier, str) or verifier is None else "learnt"
        self.check = check if check is not None or verifier is None else THRESHOLDS[kind]
        self.score_threshold, self.rank_from = score_threshold, rank_from
        if max_grasps < 1:
            raise ConfigError(f"max_grasps must be at least 1, got {max_grasps}")
        self.max_grasps = max_grasps
        self.copies_from_match = copies_from_match

    @classmethod
    def load(cls, detector: str | Path | None = None, grasp: str = "learnt", grasp_weights: str | Path | None = None,
             crop_detector: str | Path | None = None, **settings) -> Picker:
        """The photo-conditioned detector (default: shipped), the box-conditioned one for ``query_box``
        (default: shipped, loaded when first needed) and the grasp policy (default: learnt, shipped)."""
        from binpick.detection import Detector
        from binpick.detection.detector import PICKING

        planner = GraspPlanner.load(grasp, grasp_weights)
        network = Detector.load(detector or PICKING).inference_network
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

    def _detector_for(self, query_box) -> Any:
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
             max_grasps: int | None = None, size=None, copies_only: bool = False) -> Plans:
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
        repeated-object detection). A query box with no object under it is one clear line."""
        with one_blas_thread():
            return self._plan(rgb, depth, camera, photo, query_box, photo_product_mask, boxes, max_grasps, size, copies_only)

    def _plan(self, rgb, depth, camera, photo, query_box, photo_product_mask, boxes, max_grasps, size, copies_only) -> Plans:
        info = as_camera_info(camera)
        check_frame(rgb, depth, info.camera)
        depth = register_depth(np.asarray(depth), np.asarray(rgb).shape[:2])
        if query_box is not None:
            query_box = as_query_box(query_box, info.camera.width, info.camera.height)
        photos = as_photos(photo, photo_product_mask)
        if boxes is None and (not photos) == (query_box is None):
            raise ConfigError("give exactly one of a shop photo (or several of one product) or a query box")
        timing: dict[str, float] = {}
        started = time.perf_counter()
        rgb, depth = info.rectify(np.asarray(rgb), np.asarray(depth, dtype=np.float32))
        frame = self.grasp.frame(depth, info.camera)  # once per frame: holes filled, support plane found
        workspace = self.workspace or info.workspace or Workspace.around_view(info.camera)
        timing["depth"] = 1000 * (time.perf_counter() - started)
        pointed = None
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
            checked = self.product_scores(rgb, depth, frame, found, photos, query_box)
            if photos and self.copies_from_match is not None:
                found, scores, checked = self.copies_of_best_match(rgb, depth, frame, photos, found, scores, checked)
            timing["check"] = 1000 * (time.perf_counter() - tick)
        ranked = list(zip(found, scores, checked))
        threshold = self.check if query_box is None or self.verifier == "colour" else THRESHOLDS["colour"]
        if threshold is not None and self.verifier is not None:
            ranked = [c for c in ranked if c[2] is None or c[2] >= threshold]
        not_the_product = len(found) - len(ranked)
        if self.rank_from is not None:  # the product check's evidence joins the detector's in the ranking
            ranked.sort(key=lambda c: -c[1] * (c[2] if c[2] is not None else 1.0))
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
        return Plans(plans, info.base_frame, {k: round(v, 2) for k, v in timing.items()}, found, scores, not_the_product)

    def detect(self, rgb: np.ndarray, frame: DepthFrame, photos: list[tuple[np.ndarray, np.ndarray | None]],
               query_box) -> tuple[np.ndarray, np.ndarray]:
        """(boxes x, y, w, h; scores) of the ordered product: the copies of a query box (the pointed
        instance itself left out: it is planned as pointed), or the best match over the photos."""
        from binpick.detection.ops import box_iou, nms, xywh_to_xyxy
        from binpick.detection.predict import predict

        model = self._detector_for(query_box)
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
                             scores: np.ndarray, checked: list[float | None]):
        """The photo detections plus the copies the box-query detector finds of the surest of them (the
        product check at least ``copies_from_match``), those not already found, checked the same way."""
        from binpick.detection.ops import box_iou, xywh_to_xyxy
        from binpick.detection.predict import predict

        sure = [i for i, p in enumerate(checked) if p is not None and p >= self.copies_from_match
                and found[i][2] >= 2 and found[i][3] >= 2]
        if not sure:
            return found, scores, checked
        best = max(sure, key=lambda i: scores[i] * checked[i])
        prediction = predict(self._detector_for(found[best]), rgb, query_box=found[best],
                             score_threshold=self.candidate_threshold, depth=frame.filled)
        extra, extra_scores = prediction.boxes.reshape(-1, 4), prediction.scores.reshape(-1)
        if len(extra):
            overlap = box_iou(xywh_to_xyxy(torch.as_tensor(extra, dtype=torch.float32)),
                              xywh_to_xyxy(torch.as_tensor(found, dtype=torch.float32))).amax(1).numpy()
            extra, extra_scores = extra[overlap < 0.5], extra_scores[overlap < 0.5]
        if not len(extra):
            return found, scores, checked
        return (np.concatenate([found, extra]), np.concatenate([scores, extra_scores]),
                list(checked) + self.product_scores(rgb, depth, frame, extra, photos, None))

    def product_scores(self, rgb: np.ndarray, depth: np.ndarray, frame: DepthFrame, boxes: np.ndarray,
                       photos: list[tuple[np.ndarray, np.ndarray | None]], query_box) -> list[float | None]:
        """The product check's score of each box: against a query box, colour similarity to the pointed
        instance's pixels (same frame, same light); against photos, the verifier's (best over the photos;
        on depth as read, holes as holes, as it was trained)."""
        if self.verifier is None or not len(boxes):
            return [None] * len(boxes)
        if query_box is not None:
            mask = detection_mask(frame.heights, query_box)
            histogram = colour_histogram(rgb, mask if mask.any() else None)
            return [colour_similarity(histogram, rgb, frame.heights, box) for box in boxes]
        if self.verifier == "colour":
            histograms = [colour_histogram(image, photo_mask(image) if mask is None else mask) for image, mask in photos]
            return [max(colour_similarity(h, rgb, frame.heights, box) for h in histograms) for box in boxes]
        if self.verifier == "learnt":
            from binpick.detection.verifier import ProductVerifier

            self.verifier = ProductVerifier.load()
        probabilities = self.verifier.probabilities([image for image, _ in photos], [mask for _, mask in photos], rgb, depth, boxes)
        return [float(p) for p in probabilities]

    def pointed_instance(self, frame: DepthFrame, query_box) -> GraspChoice:
        """The grasp for the instance a query box points at; a box over nothing standing out (only the
        floor beneath it in depth) is one clear line."""
        choice = self.grasp.choose(frame, query_box)
        if choice.surface is None:
            x, y, w, h = (float(v) for v in query_box)
            raise InputFileError(f"the query box {x:g},{y:g},{w:g},{h:g} lies on no object: depth shows only the surface "
                                 "beneath it (draw the box around one instance of the product)")
        return choice

    def plan_detection(self, frame: DepthFrame, box, score: float, similarity: float | None, size=None,
                       choice: GraspChoice | None = None, workspace: Workspace | None = None) -> GraspPlan:
        """The plan for one detection: its best grasp, unless the instance is larger than the ordered
        product or the grasp lies outside ``workspace`` (then rejected, with the reason, and no pose)."""
        choice = choice if choice is not None else self.grasp.choose(frame, box)
        plan = GraspPlan([round(float(v), 2) for v in box], round(score, 4), None if similarity is None else round(similarity, 3),
                         rejected=choice.rejections())
        if size is not None and choice.surface is not None and larger_than(choice.surface, size):
            plan.rejected = {LARGER: 1}
            return plan
        chosen = choice.chosen
        if chosen is not None and workspace is not None and not workspace.contains(chosen.position):
            plan.rejected = {**plan.rejected, OUTSIDE: 1}
            return plan
        if chosen is not None:
            plan.position = [round(float(v), 4) for v in chosen.position]
            plan.yaw = round(float(chosen.yaw), 4)
            plan.orientation = [round(v, 6) for v in grasp_orientation(plan.yaw)]
            plan.width = round(float(chosen.width), 4)
            plan.opening = float(self.grasp.gripper.opening)
            plan.quality = None if chosen.quality is None else round(float(chosen.quality), 4)
        return plan

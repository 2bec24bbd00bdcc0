"""Finding a pointed instance again after a grasp moved things: the box-conditioned detector on the
new frame queried with the instance as it looked, and where the detector does not fire, the
instance's own picture in place or its colours nearby (the same camera, the same light)."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
import torch

from binpick.grasping import DepthFrame, GraspPlanner, PinholeCamera
from binpick.picking.camera_info import CameraInfo
from binpick.picking.colour import colour_histogram, detection_mask
from binpick.picking.inputs import as_camera_info, as_query_box, check_frame, one_blas_thread


class Planner(Protocol):
    """What finding again needs of a :class:`binpick.picking.Picker`."""

    grasp: GraspPlanner
    candidate_threshold: float

    def working_frame(self, rgb, depth, info: CameraInfo) -> tuple[np.ndarray, np.ndarray, CameraInfo, np.ndarray]: ...

    def detector_for(self, query_box) -> Any: ...

FIND_AGAIN_RADIUS = 1.0  # a pointed instance found again lies within this many of its old box's diagonals
PUSH_REACH = 5.0  # after a push: ... or on the ray along it, up to this many push lengths (or box diagonals) on
# ... and its colours match its own in the previous frame this well (histogram intersection, same light): the
# instance moved 3.6 cm matched itself at 0.90, a neighbour where it had been 0.29 (tests/test_real_depth.py)
FIND_AGAIN_COLOUR = 0.5
FIND_AGAIN_MATCH = 0.6  # normalised cross-correlation at which the instance's own picture is found in place
FIND_AGAIN_FAR = 3.0  # a pointed instance found by its colours lies within this many of its old box's diagonals


def instance_pixels(frame: DepthFrame, box, surface=None) -> np.ndarray:
    """The instance's own pixels in ``box`` (H, W bool): its region of the planner's height watershed
    (``surface``, found here when not given), so that its colours are not mixed with the floor or a
    wall beside it (near a tote's wall the floor stands above the table the support is read from); the
    box's pixels above the support where depth shows no instance."""
    from binpick.grasping.instance import instance_surface

    surface = instance_surface(frame, box) if surface is None else surface
    if surface is None or surface.mask is None or not surface.mask.any():
        return detection_mask(frame.heights, box)
    mask = np.zeros(frame.heights.shape, bool)
    row, column = surface.origin
    crop = surface.mask[:max(0, mask.shape[0] - row), :max(0, mask.shape[1] - column)]
    mask[row:row + crop.shape[0], column:column + crop.shape[1]] = crop
    return mask


def instance_similarity(histogram: np.ndarray, rgb: np.ndarray, frame: DepthFrame, box) -> float:
    """Histogram intersection in [0, 1] between ``histogram`` and the colours of the instance in
    ``box`` (:func:`instance_pixels`); 0 where depth shows nothing standing there."""
    from binpick.grasping.instance import instance_surface

    surface = instance_surface(frame, box)  # once: it is both the presence test and the pixels
    if surface is None:
        return 0.0
    mask = instance_pixels(frame, box, surface)
    if not mask.any():
        return 0.0
    return float(np.minimum(histogram, colour_histogram(rgb, mask)).sum())


def textured(picture: np.ndarray) -> bool:
    """Whether a picture has texture to match: on a flat one normalised cross-correlation scores the
    same everywhere and its best place is arbitrary."""
    return float(np.asarray(picture, dtype=np.float32).reshape(-1, picture.shape[-1]).std(axis=0).max()) >= 4.0


def middle_of(rgb: np.ndarray, box) -> np.ndarray | None:
    """The middle three fifths of ``box`` in ``rgb`` (mostly the instance, little background); None
    when that is under 6 pixels a side."""
    height, width = rgb.shape[:2]
    x, y, w, h = (float(v) for v in box)
    x0, y0 = int(round(max(0.0, x))), int(round(max(0.0, y)))
    x1, y1 = int(round(min(width, x + w))), int(round(min(height, y + h)))
    inset_x, inset_y = (x1 - x0) // 5, (y1 - y0) // 5
    middle = rgb[y0 + inset_y:y1 - inset_y, x0 + inset_x:x1 - inset_x]
    return middle if middle.shape[0] >= 6 and middle.shape[1] >= 6 else None


def matched_in_place(previous_rgb: np.ndarray, box: np.ndarray, rgb: np.ndarray, frame: DepthFrame,
                     histogram: np.ndarray) -> np.ndarray | None:
    """The instance in ``box`` of the previous frame found in the new one by its own picture: its
    crop's middle (mostly the instance, little background) matched by normalised cross-correlation
    within a box diagonal of where it was (a missed grasp nudges, turns a little or leaves it). Found
    when the match is close (:data:`FIND_AGAIN_MATCH`), the colours agree and depth shows something
    standing there; None otherwise. It needs no detector: a crop query that does not fire on the new
    frame (a small or low-contrast instance) does not lose a pointed instance that is still there."""
    import cv2

    height, width = rgb.shape[:2]
    x, y, w, h = (float(v) for v in box)
    x0, y0 = int(round(max(0.0, x))), int(round(max(0.0, y)))
    x1, y1 = int(round(min(width, x + w))), int(round(min(height, y + h)))
    inset_x, inset_y = (x1 - x0) // 5, (y1 - y0) // 5
    template = middle_of(previous_rgb, box)
    if template is None or not textured(template):
        return None
    reach = int(np.ceil(FIND_AGAIN_RADIUS * np.hypot(w, h)))
    sx0, sy0 = max(0, x0 + inset_x - reach), max(0, y0 + inset_y - reach)
    sx1 = min(width, x1 - inset_x + reach)
    sy1 = min(height, y1 - inset_y + reach)
    window = rgb[sy0:sy1, sx0:sx1]
    if window.shape[0] < template.shape[0] or window.shape[1] < template.shape[1]:
        return None
    scores = cv2.matchTemplate(window.astype(np.float32), template.astype(np.float32), cv2.TM_CCOEFF_NORMED)
    scores = np.nan_to_num(scores, nan=-1.0)
    if float(scores.max()) < FIND_AGAIN_MATCH:
        return None
    row, column = np.unravel_index(int(np.argmax(scores)), scores.shape)
    found = np.array([sx0 + column - inset_x, sy0 + row - inset_y, x1 - x0, y1 - y0], dtype=float)
    found[:2] = np.clip(found[:2], 0, [width - found[2], height - found[3]])
    if instance_similarity(histogram, rgb, frame, found) < FIND_AGAIN_COLOUR:
        return None
    return found


def found_by_colour(histogram: np.ndarray, rgb: np.ndarray, frame: DepthFrame, box: np.ndarray, area: int,
                    template: np.ndarray | None = None) -> np.ndarray | None:
    """The instance found again by its colours where a missed grasp pushed or rolled it, or turned it
    so that its picture no longer matches in place: the pixels standing out of the floor around them
    whose hue and saturation are common in the instance (its histogram back-projected), in blobs of
    half to twice its pixels within :data:`FIND_AGAIN_FAR` box diagonals of where it was, whose
    colours match (:data:`FIND_AGAIN_COLOUR` at least) and whose picture matches its own
    (``template``, the middle of its crop, turned by quarter turns: :data:`FIND_AGAIN_MATCH` at
    least). Colour alone cannot tell two products of one colour apart, and lifting the wrong one is
    worse than lifting none: of several such blobs the one clearly nearest its size in pixels (a
    third nearer, in ratio) or, sizes alike, clearly best in picture (by 0.15) is it, else none is."""
    import cv2

    from binpick.picking.colour import BINS

    if area < 16 or template is None or not textured(template):
        return None
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    hue = np.minimum(hsv[..., 0].astype(int) * BINS[0] // 180, BINS[0] - 1)
    saturation = np.minimum(hsv[..., 1].astype(int) * BINS[1] // 256, BINS[1] - 1)
    likely = histogram.reshape(BINS)[hue, saturation] >= 0.25 * max(float(histogram.max()), 1e-9)
    heights = np.nan_to_num(frame.heights, nan=0.0).astype(np.float32)
    size = int(2 * np.hypot(*box[2:])) | 1  # standing out of the floor round it (a top-hat wider than the instance:
    standing = cv2.morphologyEx(heights, cv2.MORPH_TOPHAT, np.ones((size, size), np.uint8)) > 0.008  # a bin's floor, a table)
    blobs = cv2.morphologyEx((likely & standing).astype(np.uint8), cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
    count, _, stats, centroids = cv2.connectedComponentsWithStats(blobs, connectivity=8)
    centre, diagonal = box[:2] + box[2:] / 2, max(float(np.hypot(*box[2:])), 1.0)
    qualified = []  # (how far from its size, as a log ratio; picture match; box)
    for label in range(1, count):
        x, y, w, h, pixels = (int(v) for v in stats[label])
        if not 0.5 * area <= pixels <= 2.0 * area or w < 3 or h < 3 \
                or np.linalg.norm(centroids[label] - centre) > FIND_AGAIN_FAR * diagonal:
            continue
        candidate = np.array([x, y, w, h], dtype=float)
        if instance_similarity(histogram, rgb, frame, candidate) >= FIND_AGAIN_COLOUR:
            qualified.append((abs(float(np.log(pixels / area))), picture_match(template, rgb, candidate), candidate))
    # every blob of its colours and size competes, its picture required of the one taken: a look-alike whose
    # picture happens to match better than the instance's turned one is not taken for it unless clearly so
    if not qualified:
        return None
    chosen = None
    by_size = sorted(qualified, key=lambda item: item[0])
    by_picture = sorted(qualified, key=lambda item: -item[1])
    if len(qualified) == 1:
        chosen = qualified[0]
    elif by_size[1][0] - by_size[0][0] >= np.log(4 / 3):
        chosen = by_size[0]
    elif by_picture[0][1] - by_picture[1][1] >= 0.15:  # sizes alike: its picture decides
        chosen = by_picture[0]
    return chosen[2] if chosen is not None and chosen[1] >= FIND_AGAIN_MATCH else None


def picture_match(template: np.ndarray, rgb: np.ndarray, box: np.ndarray) -> float:
    """The best normalised cross-correlation of ``template`` over ``box`` (padded by the template's
    size) in ``rgb``, over the template turned by multiples of 90 degrees; -1 where it does not fit."""
    import cv2

    height, width = rgb.shape[:2]
    x, y, w, h = (float(v) for v in box)
    pad = max(template.shape[:2])
    x0, y0 = int(max(0, x - pad)), int(max(0, y - pad))
    x1, y1 = int(min(width, x + w + pad)), int(min(height, y + h + pad))
    window = rgb[y0:y1, x0:x1].astype(np.float32)
    best = -1.0
    if not textured(template):
        return best
    for turns in range(4):
        turned = np.ascontiguousarray(np.rot90(template, turns)).astype(np.float32)
        if window.shape[0] >= turned.shape[0] and window.shape[1] >= turned.shape[1]:
            scores = np.nan_to_num(cv2.matchTemplate(window, turned, cv2.TM_CCOEFF_NORMED), nan=-1.0)
            best = max(best, float(scores.max()))
    return best


def found_without_detector(previous_rgb: np.ndarray, box: np.ndarray, rgb: np.ndarray, frame: DepthFrame,
                           histogram: np.ndarray, area: int) -> np.ndarray | None:
    """Where a pointed instance is when the detector does not fire on the new frame: its own picture
    in place (:func:`matched_in_place`), else its colours anywhere (:func:`found_by_colour`)."""
    found = matched_in_place(previous_rgb, box, rgb, frame, histogram)
    return found if found is not None else found_by_colour(histogram, rgb, frame, box, area, middle_of(previous_rgb, box))


def find_again(picker: Planner, previous_rgb: np.ndarray, previous_depth: np.ndarray, previous_box, rgb: np.ndarray,
               depth: np.ndarray,
               camera: CameraInfo | PinholeCamera, pushed: dict | None = None) -> np.ndarray | None:
    """Where the instance a person pointed at (``previous_box`` in the previous frame) is in a new
    frame of the same camera, after a grasp moved things: the box-conditioned detector on the new
    frame, queried with the instance as it looked (its crop from the previous frame, shown to the
    detector in the new frame's corner farthest from it: the crop query reads the frame's own
    features); of the detections, the one nearest the old box whose colours match the instance's in
    the previous frame (the same light) is it. None when nothing near matches (it left). ``pushed``:
    the push made since (a plan's ``push``, base frame): a ball pushed rolls on along it, so whatever
    lies near the ray from the old box along the push counts as near too."""
    from binpick.detection.ops import box_iou, xywh_to_xyxy
    from binpick.detection.predict import predict

    info = as_camera_info(camera)
    check_frame(previous_rgb, previous_depth, info.camera)
    check_frame(rgb, depth, info.camera)
    box = np.asarray(as_query_box(previous_box, info.camera.width, info.camera.height), dtype=float)
    previous_rgb, previous_depth, _, _ = picker.working_frame(previous_rgb, previous_depth, info)
    rgb, depth, info, scale = picker.working_frame(rgb, depth, info)  # as the plans saw them: boxes in the same pixels
    box = box * scale
    width, height = info.camera.width, info.camera.height
    x, y, w, h = (int(round(v)) for v in box)
    w, h = max(2, min(w, width // 2 - 4)), max(2, min(h, height // 2 - 4))
    crop = previous_rgb[y:y + h, x:x + w]
    corners = [(2, 2), (width - w - 2, 2), (2, height - h - 2), (width - w - 2, height - h - 2)]
    centre = box[:2] + box[2:] / 2
    cx, cy = max(corners, key=lambda c: np.hypot(c[0] + w / 2 - centre[0], c[1] + h / 2 - centre[1]))
    shown = rgb.copy()
    shown[cy:cy + crop.shape[0], cx:cx + crop.shape[1]] = crop
    query = np.array([cx, cy, crop.shape[1], crop.shape[0]], dtype=float)
    with one_blas_thread():
        before = picker.grasp.frame(previous_depth, info.camera)
        mask = instance_pixels(before, box)
        histogram = colour_histogram(previous_rgb, mask if mask.any() else None)
        frame = picker.grasp.frame(depth, info.camera)
        prediction = predict(picker.detector_for(query), shown, query_box=query, score_threshold=picker.candidate_threshold,
                             depth=frame.filled)
        found, scores = prediction.boxes.reshape(-1, 4), prediction.scores.reshape(-1)
        if not len(found):  # the detector sees nothing: only the instance's own picture and colours can find it
            best = found_without_detector(previous_rgb, box, rgb, frame, histogram, int(mask.sum()))
            return None if best is None else np.round(best / scale, 2)
        shown_at = box_iou(xywh_to_xyxy(torch.as_tensor(found, dtype=torch.float32)),
                           xywh_to_xyxy(torch.as_tensor(query[None], dtype=torch.float32)))[:, 0].numpy()
        overlap = box_iou(xywh_to_xyxy(torch.as_tensor(found, dtype=torch.float32)),
                          xywh_to_xyxy(torch.as_tensor(box[None], dtype=torch.float32)))[:, 0].numpy()
        diagonal = max(float(np.hypot(*box[2:])), 1.0)
        distance = np.linalg.norm(found[:, :2] + found[:, 2:] / 2 - centre, axis=1) / diagonal
        if pushed is not None:
            ends, _ = info.camera.project(np.array([pushed["start"], pushed["end"]], dtype=float))
            along = ends[1] - ends[0]
            ends = np.asarray(ends, dtype=float)
            if np.all(np.isfinite(along)) and np.linalg.norm(along) > 1e-6:
                along = along / np.linalg.norm(along)
                relative = found[:, :2] + found[:, 2:] / 2 - centre
                ahead = relative @ along
                off_ray = np.linalg.norm(relative - ahead[:, None] * along, axis=1) / diagonal
                length = float(np.linalg.norm(ends[1] - ends[0]))  # the push in the working frame's pixels, as the boxes
                on_ray = (ahead > 0) & (ahead < PUSH_REACH * max(length, diagonal))  # a ball rolls on, but not across the bin
                distance = np.where(on_ray, np.minimum(distance, off_ray), distance)
        best, best_score = None, 0.0
        for candidate, score, shown_iou, iou, reach in zip(found, scores, shown_at, overlap, distance):
            if shown_iou > 0.1 or not (iou > 0.05 or reach < FIND_AGAIN_RADIUS) or candidate[2] < 2 or candidate[3] < 2:
                continue
            same = instance_similarity(histogram, rgb, frame, candidate)
            if same < FIND_AGAIN_COLOUR:
                continue
            value = same * (1.0 - 0.5 * min(reach / FIND_AGAIN_RADIUS, 1.0)) * (0.5 + 0.5 * float(score))
            if value > best_score:
                best, best_score = candidate, value
        if best is None:  # the detector does not see it in the new frame: its own picture and colours may
            best = found_without_detector(previous_rgb, box, rgb, frame, histogram, int(mask.sum()))
    return None if best is None else np.round(best / scale, 2)

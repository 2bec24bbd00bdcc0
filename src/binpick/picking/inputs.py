"""The planner's inputs checked and brought into one form: frames, registered depth, query boxes
and shop photos."""

from __future__ import annotations

import numpy as np

from binpick.core.depth import depth_problem
from binpick.core.errors import ConfigError, InputFileError
from binpick.grasping import PinholeCamera
from binpick.picking.camera_info import CameraInfo


def split_photo(photo: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """A shop photo's RGB and its product mask: the alpha channel of an RGBA photo (a cut-out PNG),
    None for an RGB one (the colour check then takes what is not bright grey)."""
    photo = np.asarray(photo)
    if photo.ndim == 3 and photo.shape[2] == 4:
        alpha = photo[..., 3] > 127
        if not alpha.any():
            raise InputFileError("the shop photo is transparent all over: its alpha marks no product pixel (give the "
                                 "product's cut-out, or the photo without alpha)")
        return np.ascontiguousarray(photo[..., :3]), None if alpha.all() else alpha
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
            if not mask.any():
                raise InputFileError("a product mask marks no pixel of its photo: give the product's pixels, or no mask")
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


WORKING_PIXELS = 640 * 480  # frames with more pixels are planned at this many (same aspect): the cost stays flat


def working_size(width: int, height: int, pixels: int | None = WORKING_PIXELS) -> tuple[int, int]:
    """(width, height) a frame is planned at: its own up to ``pixels`` pixels (None: always its own),
    else scaled down to that many at the same aspect. A grasp needs millimetres, and at 640 x 480 a
    pixel of a camera 1 m above a tote is about 2 mm: more pixels add time, not grasps."""
    if pixels is None or width * height <= pixels:
        return int(width), int(height)
    scale = (pixels / (width * height)) ** 0.5
    return max(1, int(round(width * scale))), max(1, int(round(height * scale)))


def to_working_size(rgb: np.ndarray, depth: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Colour averaged down (area) and depth resampled to ``size`` (width, height): nearest reading,
    so no depth is invented between an edge's two sides and holes stay holes."""
    import cv2

    if (rgb.shape[1], rgb.shape[0]) != tuple(size):
        rgb = cv2.resize(np.ascontiguousarray(rgb), size, interpolation=cv2.INTER_AREA)
    if (depth.shape[1], depth.shape[0]) != tuple(size):
        depth = cv2.resize(np.asarray(depth, dtype=np.float32), size, interpolation=cv2.INTER_NEAREST)
    return rgb, depth


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
    step = max(1, int((depth.size / WORKING_PIXELS) ** 0.5))  # a huge frame's median from a sample of its pixels
    problem = depth_problem(depth[::step, ::step])
    if problem is not None:
        hint = "" if "no valid reading" in problem else ": give depth in metres (16-bit PNGs in millimetres are converted when read)"
        raise InputFileError(f"depth image {problem}{hint}")


def working_frame(rgb, depth, info: CameraInfo, pixels: int | None = WORKING_PIXELS) -> tuple[np.ndarray, np.ndarray, CameraInfo, np.ndarray]:
    """A frame as the planner works on it: at the working resolution of ``pixels`` (more pixels add
    time, not grasps), depth registered to the colour's size, both rectified; with the camera at that
    size and the scale from the caller's pixels (x, y, w, h) to the working ones."""
    full = (info.camera.width, info.camera.height)
    work = working_size(*full, pixels)
    scale = np.array([work[0] / full[0], work[1] / full[1]] * 2)
    if work != full:
        rgb, depth = to_working_size(np.asarray(rgb), np.asarray(depth), work)
        info = info.scaled(*work)
    else:
        depth = register_depth(np.asarray(depth), np.asarray(rgb).shape[:2])
    rgb, depth = info.rectify(np.asarray(rgb), np.asarray(depth, dtype=np.float32))
    return rgb, depth, info, scale

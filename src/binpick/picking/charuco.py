"""The ChArUco calibration board: its layout, a printable picture of it, and its pose in a camera
image (OpenCV's ChArUco detection and PnP). Hand-eye calibration (:mod:`binpick.picking.hand_eye`)
solves from these poses; the same detections give a camera's intrinsics where it has no factory ones.

The board's frame is OpenCV's: origin at the outer corner of the first square, x along its columns,
y along its rows, z into the board (away from a camera that reads it).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from binpick.core.errors import ConfigError, InputFileError

DICTIONARIES = {"4x4_50": cv2.aruco.DICT_4X4_50, "5x5_100": cv2.aruco.DICT_5X5_100, "6x6_250": cv2.aruco.DICT_6X6_250}
MIN_CORNERS = 6  # chessboard corners seen: fewer, and the board's pose is not trusted


@dataclass(frozen=True)
class Board:
    """A ChArUco board: ``squares`` (columns, rows), the square's and marker's sides in metres as
    printed (measure them: the scale of every pose comes from here), and the marker dictionary."""

    squares: tuple[int, int] = (7, 5)
    square: float = 0.04
    marker: float = 0.03
    dictionary: str = "5x5_100"

    def __post_init__(self) -> None:
        columns, rows = self.squares
        if columns < 3 or rows < 3:
            raise ConfigError(f"board.squares must be at least 3 x 3, got {columns} x {rows}")
        if not 0 < self.marker < self.square:
            raise ConfigError(f"board.marker ({self.marker} m) must be positive and smaller than board.square ({self.square} m)")
        if self.dictionary not in DICTIONARIES:
            raise ConfigError(f"board.dictionary {self.dictionary!r}: choose from {', '.join(DICTIONARIES)}")

    @property
    def size(self) -> tuple[float, float]:
        """The board's printed area (m), x along its columns, y along its rows."""
        return self.squares[0] * self.square, self.squares[1] * self.square

    def opencv(self) -> cv2.aruco.CharucoBoard:
        return cv2.aruco.CharucoBoard(tuple(self.squares), self.square, self.marker,
                                      cv2.aruco.getPredefinedDictionary(DICTIONARIES[self.dictionary]))

    def picture(self, pixels_per_square: int = 100) -> np.ndarray:
        """The board as a grey image to print (or to texture a simulated board with), no margin."""
        columns, rows = self.squares
        return self.opencv().generateImage((columns * pixels_per_square, rows * pixels_per_square), marginSize=0)


@dataclass(frozen=True)
class BoardView:
    """The board seen in one image: its pose in the camera (4x4, board -> camera), the corners used
    and their reprojection error (pixels, RMS)."""

    board_to_camera: np.ndarray
    corners: int
    reprojection_px: float
    object_points: np.ndarray  # (N, 3) the corners on the board (m)
    image_points: np.ndarray  # (N, 2) where they were seen (pixels)


def board_corners(image: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray] | None:
    """The chessboard corners of ``board`` found in ``image`` (grey or RGB uint8): (object points
    (N, 3) m, image points (N, 2) px), or None when fewer than MIN_CORNERS are seen."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    detector = cv2.aruco.CharucoDetector(board.opencv())
    corners, ids, _, _ = detector.detectBoard(np.ascontiguousarray(grey))
    if corners is None or ids is None or len(ids) < MIN_CORNERS:
        return None
    objects, pixels = board.opencv().matchImagePoints(corners, ids)
    return objects.reshape(-1, 3).astype(np.float64), pixels.reshape(-1, 2).astype(np.float64)


def board_pose(object_points: np.ndarray, image_points: np.ndarray, K: np.ndarray,
               distortion: np.ndarray | None = None) -> BoardView:
    """The board's pose from its corners (PnP, refined by Levenberg-Marquardt), with the RMS
    reprojection error of its corners."""
    distortion = np.zeros(5) if distortion is None else np.asarray(distortion, dtype=float)
    ok, rvec, tvec = cv2.solvePnP(object_points, image_points, np.asarray(K, dtype=float), distortion, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        ok, rvec, tvec = cv2.solvePnP(object_points, image_points, np.asarray(K, dtype=float), distortion)
    if not ok:
        raise InputFileError("the board's pose could not be solved from its corners")
    rvec, tvec = cv2.solvePnPRefineLM(object_points, image_points, np.asarray(K, dtype=float), distortion, rvec, tvec)
    projected, _ = cv2.projectPoints(object_points, rvec, tvec, np.asarray(K, dtype=float), distortion)
    error = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - image_points) ** 2, axis=1))))
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rvec)[0]
    pose[:3, 3] = tvec.ravel()
    return BoardView(pose, len(object_points), error, object_points, image_points)


def intrinsics_from_board(views: list[tuple[np.ndarray, np.ndarray]], size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, float]:
    """A camera's K and distortion (plumb bob) from the board seen in several images (``views``:
    (object points, image points) per image, :func:`board_corners`), and the RMS reprojection error (px)."""
    if len(views) < 4:
        raise InputFileError(f"intrinsics need the board in at least 4 images at different angles; it was found in {len(views)}")
    objects = [v[0].astype(np.float32) for v in views]
    pixels = [v[1].astype(np.float32) for v in views]
    error, K, distortion, _, _ = cv2.calibrateCamera(objects, pixels, tuple(size), None, None)
    return K, distortion.ravel()[:5], float(error)

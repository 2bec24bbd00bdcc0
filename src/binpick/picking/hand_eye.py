"""Hand-eye calibration: the camera's pose from the flange poses a robot reports and the board's pose
in the camera at each of them (:mod:`binpick.picking.charuco`).

Two mountings:

- ``eye-to-hand``: the camera stands still, the board rides on the flange. Unknown: the camera in the
  base (what ``camera.yaml``'s ``camera_to_base`` is). For poses i, j:
  ``(F_j F_i^-1) X = X (C_j C_i^-1)`` with F the flange in the base, C the board in the camera.
- ``eye-in-hand``: the camera rides on the flange, the board stands still. Unknown: the camera in the
  flange. ``(F_j^-1 F_i) X = X (C_j C_i^-1)``.

Both are ``AX = XB``, solved in closed form as Park & Martin (1994) do: the rotation from the
rotation vectors of every pair (orthogonal Procrustes), then the translation by least squares. The
OpenCV wheel binpick pins (5.0) does not expose ``calibrateHandEye``, hence this solver (about 40
lines, checked against the simulator). Poses whose implied board pose disagrees with the others (a
misdetected board, a robot that had not stopped) are dropped and the rest solved again. The
residual is that disagreement: how far each pose's board (on the flange, or in the base) lies from
their mean, in mm and degrees.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from binpick.core.errors import InputFileError

MOUNTS = ("eye-to-hand", "eye-in-hand")
MIN_POSES = 3
MIN_SPREAD_DEGREES = 5.0  # the flange's rotations must turn about at least two axes by this much
OUTLIER_FACTOR, OUTLIER_FLOOR_MM, OUTLIER_FLOOR_DEGREES = 3.0, 30.0, 3.0  # the closed form's, gross errors only: it is the start
OUTLIER_FLOOR_PX = 5.0  # a view whose corners reproject worse than this (and 3 times the median) is dropped
FLANGE_SIGMA = (1.0, 0.1)  # mm, degrees: how far a reported flange pose may be off (an arm's repeatability and calibration)
PIXEL_SIGMA = 1.0  # px: how far a detected board corner may be off


@dataclass
class HandEye:
    """The solved transform (``camera_to_base`` for eye-to-hand, ``camera_to_flange`` for
    eye-in-hand), the board's fixed pose it implies, and how well the poses agree."""

    mount: str
    transform: np.ndarray  # 4x4
    board: np.ndarray  # 4x4: board -> flange (eye-to-hand) or board -> base (eye-in-hand)
    residual_mm: float  # RMS over the poses kept
    residual_degrees: float
    used: list[int] = field(default_factory=list)  # indices of the poses kept
    dropped: list[int] = field(default_factory=list)  # ... and of those dropped as outliers
    reprojection_px: float | None = None  # the board corners' RMS reprojection error after refining (None: not refined)

    def summary(self) -> dict:
        name = "camera_to_base" if self.mount == "eye-to-hand" else "camera_to_flange"
        return {"mount": self.mount, name: self.transform.round(6).tolist(), "residual_mm": round(self.residual_mm, 3),
                "residual_degrees": round(self.residual_degrees, 4), "poses_used": len(self.used), "dropped": self.dropped,
                "reprojection_px": None if self.reprojection_px is None else round(self.reprojection_px, 3)}


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """The axis-angle vector of a rotation matrix (angle in radians, 0 to pi)."""
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    angle = float(np.arccos(cos))
    if angle < 1e-9:
        return np.zeros(3)
    if angle > np.pi - 1e-6:  # a half turn: the axis from the symmetric part
        axis = np.sqrt(np.maximum((np.diag(R) + 1.0) / 2.0, 0.0))
        k = int(np.argmax(axis))
        axis[np.arange(3) != k] = (R[k, np.arange(3) != k] + R[np.arange(3) != k, k]) / (4 * axis[k])
        return angle * axis / np.linalg.norm(axis)
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2 * np.sin(angle))
    return angle * axis


def inverse(T: np.ndarray) -> np.ndarray:
    result = np.eye(4)
    result[:3, :3] = T[:3, :3].T
    result[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return result


def solve_ax_xb(A: list[np.ndarray], B: list[np.ndarray]) -> np.ndarray:
    """X with A_k X = X B_k for every pair (4x4 each): Park & Martin's closed form."""
    alpha = np.array([rotation_vector(a[:3, :3]) for a in A])
    beta = np.array([rotation_vector(b[:3, :3]) for b in B])
    U, _, Vt = np.linalg.svd(beta.T @ alpha)  # R minimises sum |alpha_k - R beta_k|^2
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    lhs = np.concatenate([a[:3, :3] - np.eye(3) for a in A])
    rhs = np.concatenate([R @ b[:3, 3] - a[:3, 3] for a, b in zip(A, B)])
    t = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, t
    return X


def _pairs(flange: list[np.ndarray], board: list[np.ndarray], mount: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    A, B = [], []
    for i in range(len(flange)):
        for j in range(i + 1, len(flange)):
            A.append(flange[j] @ inverse(flange[i]) if mount == "eye-to-hand" else inverse(flange[j]) @ flange[i])
            B.append(board[j] @ inverse(board[i]))
    return A, B


def _implied_boards(X: np.ndarray, flange: list[np.ndarray], board: list[np.ndarray], mount: str) -> list[np.ndarray]:
    """Each pose's view of the board's fixed pose: on the flange (eye-to-hand) or in the base."""
    if mount == "eye-to-hand":
        return [inverse(f) @ X @ c for f, c in zip(flange, board)]
    return [f @ X @ c for f, c in zip(flange, board)]


def _spread(poses: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mean of rigid poses (chordal, rotation by SVD) and each one's distance from it (mm, degrees)."""
    U, _, Vt = np.linalg.svd(sum(p[:3, :3] for p in poses))
    mean = np.eye(4)
    mean[:3, :3] = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    mean[:3, 3] = np.mean([p[:3, 3] for p in poses], axis=0)
    mm = np.array([1000 * np.linalg.norm(p[:3, 3] - mean[:3, 3]) for p in poses])
    degrees = np.array([np.degrees(np.linalg.norm(rotation_vector(mean[:3, :3].T @ p[:3, :3]))) for p in poses])
    return mean, mm, degrees


def check_motion(flange: list[np.ndarray]) -> None:
    """One line when the flange poses cannot determine the camera: too few, or turning about one axis only."""
    if len(flange) < MIN_POSES:
        raise InputFileError(f"hand-eye calibration needs at least {MIN_POSES} poses with the board seen; got {len(flange)} "
                             "(15 or more, turned about different axes, give a good result)")
    turns = np.array([rotation_vector(f[:3, :3] @ flange[0][:3, :3].T) for f in flange[1:]])
    spread = np.linalg.svd(turns, compute_uv=False) / np.sqrt(max(len(turns), 1)) if len(turns) else np.zeros(1)  # RMS turn
    if len(spread) < 2 or np.degrees(spread[1]) < MIN_SPREAD_DEGREES:
        raise InputFileError("the flange poses all turn about one axis (or hardly at all): hand-eye calibration cannot tell "
                             f"the camera's pose from them; tilt the flange about at least two axes by more than {MIN_SPREAD_DEGREES:.0f} degrees")


def calibrate(flange_to_base: list[np.ndarray], board_to_camera: list[np.ndarray], mount: str = "eye-to-hand",
              observations: list[tuple[np.ndarray, np.ndarray]] | None = None, K: np.ndarray | None = None,
              distortion: np.ndarray | None = None, flange_sigma: tuple[float, float] | None = FLANGE_SIGMA) -> HandEye:
    """Solve the hand-eye transform from matching lists of 4x4 poses (flange in the base, as the robot
    reports it; board in the camera, :func:`binpick.picking.charuco.board_pose`), dropping poses that
    disagree with the rest (more than OUTLIER_FACTOR times the median and the floor, in mm or degrees).
    With ``observations`` (each pose's board corners: object points, image points) and the camera's
    ``K``, the closed form is then refined on the corners themselves (:func:`refine`): a board's PnP
    pose alone is a few tenths of a degree off under a pixel of noise, and the closed form carries that
    error times the board's distance into the translation."""
    if mount not in MOUNTS:
        raise InputFileError(f"mount {mount!r}: choose from {', '.join(MOUNTS)}")
    if len(flange_to_base) != len(board_to_camera):
        raise InputFileError(f"{len(flange_to_base)} flange poses but {len(board_to_camera)} board poses: they must match")
    flange = [np.asarray(f, dtype=float) for f in flange_to_base]
    board = [np.asarray(c, dtype=float) for c in board_to_camera]
    if not all(np.all(np.isfinite(p)) for p in flange + board):
        raise InputFileError("a flange or board pose is not finite")
    kept = list(range(len(flange)))
    dropped: list[int] = []
    while True:
        check_motion([flange[k] for k in kept])
        A, B = _pairs([flange[k] for k in kept], [board[k] for k in kept], mount)
        X = solve_ax_xb(A, B)
        mean, mm, degrees = _spread(_implied_boards(X, [flange[k] for k in kept], [board[k] for k in kept], mount))
        limit_mm = max(OUTLIER_FACTOR * float(np.median(mm)), OUTLIER_FLOOR_MM)
        limit_degrees = max(OUTLIER_FACTOR * float(np.median(degrees)), OUTLIER_FLOOR_DEGREES)
        badness = np.maximum(mm / limit_mm, degrees / limit_degrees)
        worst = int(np.argmax(badness))
        if badness[worst] <= 1.0 or len(kept) <= MIN_POSES:
            break
        dropped.append(kept.pop(worst))  # one at a time: the worst may have pulled the solution towards itself
    solved = HandEye(mount, X, mean, float(np.sqrt(np.mean(mm ** 2))), float(np.sqrt(np.mean(degrees ** 2))), kept, sorted(dropped))
    if observations is not None:
        if K is None:
            raise InputFileError("refining on the board's corners needs the camera's K")
        while True:  # refined on the corners; a view its corners do not fit (a misread board) is dropped, and again
            X, fixed, per_view = refine(solved, [flange[k] for k in kept], [observations[k] for k in kept], K, distortion,
                                        flange_sigma)
            worst = int(np.argmax(per_view))
            if per_view[worst] <= max(OUTLIER_FACTOR * float(np.median(per_view)), OUTLIER_FLOOR_PX) or len(kept) <= MIN_POSES:
                break
            dropped.append(kept.pop(worst))
            check_motion([flange[k] for k in kept])
        _, mm, degrees = _spread(_implied_boards(X, [flange[k] for k in kept], [board[k] for k in kept], mount))
        solved = HandEye(mount, X, fixed, float(np.sqrt(np.mean(mm ** 2))), float(np.sqrt(np.mean(degrees ** 2))), kept,
                         sorted(dropped), float(np.sqrt(np.mean(per_view ** 2))))
    return solved


def _pose(parameters: np.ndarray) -> np.ndarray:
    import cv2

    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(parameters[:3])[0]
    pose[:3, 3] = parameters[3:6]
    return pose


def _board_in_camera(X: np.ndarray, fixed: np.ndarray, flange: np.ndarray, mount: str) -> np.ndarray:
    """Where the board should be in the camera at one flange pose, given the transform and the board's fixed pose."""
    return inverse(X) @ (flange if mount == "eye-to-hand" else inverse(flange)) @ fixed


def refine(solved: HandEye, flange: list[np.ndarray], observations: list[tuple[np.ndarray, np.ndarray]], K: np.ndarray,
           distortion: np.ndarray | None = None, flange_sigma: tuple[float, float] | None = FLANGE_SIGMA,
           pixel_sigma: float = PIXEL_SIGMA) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The transform and the board's fixed pose that best explain every board corner seen, as a
    bundle adjustment: each flange pose may be off by what the robot's repeatability allows
    (``flange_sigma``: mm, degrees; None: taken as exact), each corner by ``pixel_sigma``, and the
    most likely transform is found (Levenberg-Marquardt from the closed form; a Huber loss against
    stray corners). Returns (transform, board pose, each view's RMS reprojection error in px)."""
    import cv2
    from scipy.optimize import least_squares

    distortion = np.zeros(5) if distortion is None else np.asarray(distortion, dtype=float)
    K = np.asarray(K, dtype=float)
    views = len(flange)
    per_view = 6 if flange_sigma is not None else 0

    def corrected(parameters: np.ndarray, index: int) -> np.ndarray:
        if not per_view:
            return flange[index]
        delta = parameters[12 + 6 * index:18 + 6 * index]
        pose = flange[index].copy()
        pose[:3, :3] = cv2.Rodrigues(delta[:3])[0] @ pose[:3, :3]
        pose[:3, 3] += delta[3:]
        return pose

    def residuals(parameters: np.ndarray) -> np.ndarray:
        X, fixed = _pose(parameters[:6]), _pose(parameters[6:12])
        errors = []
        for index, (objects, pixels) in enumerate(observations):
            C = _board_in_camera(X, fixed, corrected(parameters, index), solved.mount)
            projected, _ = cv2.projectPoints(objects, cv2.Rodrigues(C[:3, :3])[0], C[:3, 3], K, distortion)
            errors.append((projected.reshape(-1, 2) - pixels).ravel() / pixel_sigma)
        if per_view:
            deltas = parameters[12:].reshape(views, 6)
            errors.append((deltas[:, :3] / np.radians(flange_sigma[1])).ravel())
            errors.append((deltas[:, 3:] / (flange_sigma[0] / 1000)).ravel())
        return np.concatenate(errors)

    start = np.concatenate([rotation_vector(solved.transform[:3, :3]), solved.transform[:3, 3],
                            rotation_vector(solved.board[:3, :3]), solved.board[:3, 3], np.zeros(per_view * views)])
    fit = least_squares(residuals, start, loss="huber", f_scale=3.0, x_scale="jac")
    X, fixed = _pose(fit.x[:6]), _pose(fit.x[6:12])
    errors = residuals(fit.x)[:sum(2 * len(o[0]) for o in observations)].reshape(-1, 2) * pixel_sigma
    squared = np.sum(errors ** 2, axis=1)
    ends = np.cumsum([len(o[0]) for o in observations])
    per_view = np.sqrt(np.array([chunk.mean() for chunk in np.split(squared, ends[:-1])]))
    return X, fixed, per_view


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """How far a pose is from the true one: (mm, degrees)."""
    mm = 1000 * float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))
    degrees = float(np.degrees(np.linalg.norm(rotation_vector(truth[:3, :3].T @ estimate[:3, :3]))))
    return mm, degrees

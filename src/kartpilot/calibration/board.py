"""Camera calibration from views of a chessboard or a ChArUco board (OpenCV).

* :func:`find_board`: the board's corners in one image, refined to sub-pixel, or None
  when the whole board is not seen (a cropped chessboard, too few ChArUco corners).
* :func:`calibrate_mono`: intrinsics and distortion from many views, with the RMS
  reprojection error and each view's own error.
* :func:`calibrate_stereo`: both cameras' intrinsics, then the pose of the right camera
  relative to the left with the intrinsics fixed; the rectification is computed and its
  quality measured as the row difference of the board's corners once rectified.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from kartpilot.calibration.rectify import StereoRectification, rectify_stereo
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import CalibrationError, ConfigError, DataError
from kartpilot.core.geometry import Array, pose_from_rt
from kartpilot.core.types import Image

__all__ = [
    "BoardConfig",
    "BoardView",
    "MonoCalibration",
    "StereoCalibration",
    "calibrate_mono",
    "calibrate_stereo",
    "find_board",
    "pair_names",
    "read_views",
    "rectified_row_error_px",
]


@dataclass(frozen=True)
class BoardConfig:
    """Attributes:
        kind: ``chessboard`` or ``charuco``.
        columns, rows: inner corners across and down (chessboard), or squares (ChArUco).
        square_m: the side of one square.
        marker_m: the side of a ChArUco marker (0: 0.75 of a square).
        dictionary: the ArUco dictionary of a ChArUco board.
        min_charuco_corners: fewest ChArUco corners for a view to count.
    """

    kind: Literal["chessboard", "charuco"] = "chessboard"
    columns: int = 9
    rows: int = 6
    square_m: float = 0.025
    marker_m: float = 0.0
    dictionary: str = "DICT_4X4_50"
    min_charuco_corners: int = 12

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "charuco"):
            raise ConfigError(f"board.kind: unknown board {self.kind!r} (chessboard or charuco)")
        if self.columns < 3 or self.rows < 3 or not self.square_m > 0:
            raise ConfigError("board: at least 3x3 corners and a positive square size")
        if self.kind == "charuco" and not hasattr(cv2.aruco, self.dictionary):
            raise ConfigError(f"board.dictionary: OpenCV has no ArUco dictionary {self.dictionary!r}")

    def object_points(self) -> Array:
        """The chessboard's inner corners on the board plane (z = 0), row by row, in metres."""
        grid = np.mgrid[0:self.columns, 0:self.rows].T.reshape(-1, 2)
        return np.column_stack([grid * self.square_m, np.zeros(len(grid))]).astype(np.float32)

    def charuco_board(self) -> cv2.aruco.CharucoBoard:
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        marker = self.marker_m or 0.75 * self.square_m
        return cv2.aruco.CharucoBoard((self.columns, self.rows), self.square_m, marker, dictionary)


@dataclass(frozen=True)
class BoardView:
    """The board found in one image: (N, 2) pixels, their (N, 3) board points, and the corner ids
    (ChArUco; the running index for a chessboard)."""

    name: str
    pixels: Array
    points_m: Array
    ids: np.ndarray


def find_board(image: Image, board: BoardConfig, name: str = "") -> BoardView | None:
    """The board in ``image`` with sub-pixel corners, or None when it is not wholly (chessboard) or
    sufficiently (ChArUco) visible."""
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    if board.kind == "chessboard":
        size = (board.columns, board.rows)
        found, corners = cv2.findChessboardCorners(
            gray, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK)
        if not found:
            found, corners = cv2.findChessboardCorners(gray, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                                       | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:
            return None
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
        corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), criteria)
        count = board.columns * board.rows
        return BoardView(name, corners.reshape(-1, 2).astype(np.float64), board.object_points().astype(np.float64),
                         np.arange(count))
    detector = cv2.aruco.CharucoDetector(board.charuco_board())
    corners, ids, _, _ = detector.detectBoard(gray)
    if ids is None or len(ids) < board.min_charuco_corners:
        return None
    ids = ids.ravel()
    points = board.charuco_board().getChessboardCorners()[ids]
    return BoardView(name, corners.reshape(-1, 2).astype(np.float64), np.asarray(points, np.float64), ids)


def read_views(paths: Sequence[str | Path], board: BoardConfig) -> tuple[list[BoardView], list[str], tuple[int, int]]:
    """(views found, names skipped with the reason, image size) for image files. Images of another size
    than the first are skipped: one calibration is for one resolution."""
    views: list[BoardView] = []
    skipped: list[str] = []
    size: tuple[int, int] | None = None
    for path in paths:
        path = Path(path)
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            skipped.append(f"{path.name}: unreadable")
            continue
        if size is None:
            size = (image.shape[1], image.shape[0])
        elif (image.shape[1], image.shape[0]) != size:
            skipped.append(f"{path.name}: {image.shape[1]}x{image.shape[0]}, not {size[0]}x{size[1]} like the first")
            continue
        view = find_board(image, board, path.name)
        if view is None:
            skipped.append(f"{path.name}: the whole board is not visible")
        else:
            views.append(view)
    if size is None:
        raise DataError("none of the calibration images could be read")
    return views, skipped, size


@dataclass(frozen=True)
class MonoCalibration:
    camera: PinholeCamera
    rms_px: float
    per_view_rms_px: dict[str, float]


def _per_view_rms(views: Sequence[BoardView], camera_matrix: Array, distortion: Array, rvecs: Sequence[Array],
                  tvecs: Sequence[Array]) -> dict[str, float]:
    errors = {}
    for view, rvec, tvec in zip(views, rvecs, tvecs, strict=True):
        projected, _ = cv2.projectPoints(view.points_m, rvec, tvec, camera_matrix, distortion)
        errors[view.name] = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - view.pixels) ** 2, axis=1))))
    return errors


MIN_TILT_SPREAD_DEG = 5.0
"""Board views whose planes all lie within this angle of each other do not fix the focal length (Zhang, "A
flexible new technique for camera calibration", PAMI 2000: planes parallel to each other add no constraint on
the intrinsics beyond the first)."""


def _copies(views: Sequence[BoardView]) -> list[tuple[str, str]]:
    """(copy, original) for each view whose corners lie within half a pixel of an earlier view's."""
    out = []
    for k, view in enumerate(views):
        for earlier in views[:k]:
            if len(view.ids) == len(earlier.ids) and np.array_equal(view.ids, earlier.ids) and float(
                    np.median(np.linalg.norm(view.pixels - earlier.pixels, axis=1))) < 0.5:
                out.append((view.name, earlier.name))
                break
    return out


def _tilt_spread_deg(rvecs: Sequence[Array]) -> float:
    """The largest angle between two views' board normals."""
    normals = np.array([cv2.Rodrigues(np.asarray(r, np.float64))[0][:, 2] for r in rvecs])
    cosines = np.clip(np.abs(normals @ normals.T), -1.0, 1.0)
    return float(np.degrees(np.arccos(cosines.min())))


def calibrate_mono(views: Sequence[BoardView], size_wh: tuple[int, int], min_views: int = 3) -> MonoCalibration:
    """Intrinsics and distortion (k1, k2, p1, p2, k3) from board views."""
    if len(views) < min_views:
        raise CalibrationError(f"only {len(views)} images show the whole board; calibration needs {min_views}")
    copies = _copies(views)
    if len(views) - len(copies) < min_views:
        named = ", ".join(f"{a} of {b}" for a, b in copies[:4]) + (", ..." if len(copies) > 4 else "")
        raise CalibrationError(f"{len(copies)} of the {len(views)} board views are copies of another ({named}): "
                               f"the same view twice measures nothing new; calibration needs {min_views} "
                               "different ones")
    rms, K, distortion, rvecs, tvecs = cv2.calibrateCamera(
        [v.points_m.astype(np.float32) for v in views], [v.pixels.astype(np.float32) for v in views], size_wh,
        None, None)
    if not math.isfinite(rms):
        raise CalibrationError("the calibration did not converge")
    tilt = _tilt_spread_deg(rvecs)
    if tilt < MIN_TILT_SPREAD_DEG:
        raise CalibrationError(f"the board is held at one angle in every view (its tilt varies by {tilt:.1f} deg): "
                               "the focal length cannot be told from the distance then, however small the "
                               "reprojection error; tilt it by 20 to 45 degrees in some views")
    camera = PinholeCamera.from_matrix(K, size_wh, tuple(float(d) for d in distortion.ravel()[:5]))
    return MonoCalibration(camera, float(rms), _per_view_rms(views, K, distortion, rvecs, tvecs))


@dataclass(frozen=True)
class StereoCalibration:
    """Attributes:
        left, right: each camera's calibration (alone).
        pose_right_left: 4x4 transform of points from the left camera frame to the right one.
        rms_px: the stereo RMS reprojection error over both cameras (intrinsics fixed).
        pairs: the names of the pairs used.
        rectification: the rectified rig and remap tables.
        row_error_px: per used pair, the median row difference of its board corners after rectification.
    """

    left: MonoCalibration
    right: MonoCalibration
    pose_right_left: Array
    rms_px: float
    pairs: tuple[str, ...]
    rectification: StereoRectification
    row_error_px: dict[str, float]

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(self.pose_right_left[:3, 3]))


def calibrate_stereo(left_views: Sequence[BoardView], right_views: Sequence[BoardView], size_wh: tuple[int, int],
                     min_pairs: int = 3, pairs: Sequence[tuple[str, str]] | None = None) -> StereoCalibration:
    """Both cameras alone, then their relative pose from the views where both see the board. ``pairs`` names
    which left image goes with which right one (:func:`pair_names` of the images given); by default the
    views' own names are paired."""
    left_cal = calibrate_mono(left_views, size_wh)
    right_cal = calibrate_mono(right_views, size_wh)
    if pairs is None:
        pairs = pair_names([v.name for v in left_views], [v.name for v in right_views])
    left_by_name, right_by_name = {v.name: v for v in left_views}, {v.name: v for v in right_views}
    both = [(left_by_name[a], right_by_name[b]) for a, b in pairs if a in left_by_name and b in right_by_name]
    pairs_seen = [(lv, rv) for lv, rv in both if len(lv.ids) == len(rv.ids) and np.array_equal(lv.ids, rv.ids)]
    if len(pairs_seen) < min_pairs:
        raise CalibrationError(f"only {len(pairs_seen)} of the {len(pairs)} pairs show the whole board in both "
                               f"images; need {min_pairs}")
    K1, d1 = left_cal.camera.matrix, left_cal.camera.distortion_array
    K2, d2 = right_cal.camera.matrix, right_cal.camera.distortion_array
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-6)
    rms, *_, R, T, _, _ = cv2.stereoCalibrate(
        [lv.points_m.astype(np.float32) for lv, _ in pairs_seen],
        [lv.pixels.astype(np.float32) for lv, _ in pairs_seen], [rv.pixels.astype(np.float32) for _, rv in pairs_seen],
        K1, d1, K2, d2, size_wh, criteria=criteria, flags=cv2.CALIB_FIX_INTRINSIC)
    pose = pose_from_rt(R, T.ravel())
    rectification = rectify_stereo(left_cal.camera, right_cal.camera, pose)
    rows = {lv.name: float(np.median(np.abs(rectified_row_error_px(rectification, left_cal.camera, right_cal.camera,
                                                                    lv.pixels, rv.pixels)))) for lv, rv in pairs_seen}
    return StereoCalibration(left_cal, right_cal, pose, float(rms), tuple(lv.name for lv, _ in pairs_seen),
                             rectification, rows)


_SIDE = re.compile(r"(?i)left|right|cam0|cam1|(?<![a-z])[lr](?![a-z])|[LR](?=[_\-.]?\d)")


def _pair_key(name: str) -> str:
    """``left03.jpg`` and ``right03.jpg``, ``imageL0.png`` and ``imageR0.png``, ``cam0/03.png`` and
    ``cam1/03.png`` share a key: the name without the word that says which side."""
    return _SIDE.sub("", Path(name).stem)


def pair_names(left: Sequence[str], right: Sequence[str]) -> list[tuple[str, str]]:
    """Which left image goes with which right one: by a name pattern both lists follow (``left03``/``right03``,
    ``imageL0``/``imageR0``), else by the order given when both lists are as long. Lists that cannot be
    paired one to one raise CalibrationError saying so."""
    left_keys, right_keys = [_pair_key(n) for n in left], [_pair_key(n) for n in right]
    unique = len(set(left_keys)) == len(left_keys) and len(set(right_keys)) == len(right_keys)
    if unique and set(left_keys) == set(right_keys):
        by_key = dict(zip(right_keys, right, strict=True))
        return [(name, by_key[key]) for name, key in zip(left, left_keys, strict=True)]
    if len(left) == len(right):
        return list(zip(left, right, strict=True))
    common = len(set(left_keys) & set(right_keys))
    raise CalibrationError(f"the {len(left)} left and {len(right)} right images cannot be paired one to one: "
                           f"their names pair {common} of them, and by order the counts differ")


def rectified_row_error_px(rectification: StereoRectification, left: PinholeCamera, right: PinholeCamera,
                           left_px: Array, right_px: Array) -> Array:
    """Row differences (px) of corresponding raw points once both are undistorted and rectified: 0 for
    a perfect calibration, whatever the points' depth."""
    P1, P2 = rectification.rig.P0, rectification.rig.P1
    rows = []
    for camera, pixels, R, P in ((left, left_px, rectification.rotation_rect_left, P1),
                                 (right, right_px, rectification.rotation_rect_right, P2)):
        rectified = cv2.undistortPoints(np.asarray(pixels, np.float64).reshape(-1, 1, 2), camera.matrix,
                                        camera.distortion_array, R=R, P=P)
        rows.append(rectified.reshape(-1, 2)[:, 1])
    return np.asarray(rows[0] - rows[1])

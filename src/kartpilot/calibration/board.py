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
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from kartpilot.calibration.rectify import StereoRectification, rectify_stereo
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import CalibrationError, ConfigError, DataError
from kartpilot.core.geometry import Array, pose_from_rt
from kartpilot.core.images import read_gray
from kartpilot.core.types import Image

__all__ = [
    "ARUCO_FAMILIES",
    "BoardConfig",
    "BoardSearch",
    "BoardView",
    "MonoCalibration",
    "StereoCalibration",
    "board_points",
    "calibrate_mono",
    "calibrate_stereo",
    "detect_board",
    "find_board",
    "measure_marker",
    "pair_names",
    "read_views",
    "rectified_row_error_px",
    "views_from_frames",
]


@dataclass(frozen=True)
class BoardConfig:
    """Attributes:
        kind: ``chessboard`` or ``charuco``.
        columns, rows: inner corners across and down (chessboard), or squares (ChArUco).
        square_m: the side of one square.
        marker_m: the side of a ChArUco marker (0: 0.75 of a square).
        dictionary: the ArUco dictionary of a ChArUco board.
        min_points: fewest points (corners) for a view to count.
        legacy: the ChArUco layout of OpenCV before 4.6 (boards printed with it).
        marker_corners: :func:`find_board` gives each marker's own four corners too (a ground calibration, whose
            side cameras see part of the board, needs them; photos of the whole board for a lens have corners
            enough, and the markers' corners, placed less precisely, would only add their bias: a rendered lens
            came out 0.9 % further off with them).
    """

    kind: Literal["chessboard", "charuco"] = "chessboard"
    columns: int = 9
    rows: int = 6
    square_m: float = 0.025
    marker_m: float = 0.0
    dictionary: str = "DICT_4X4_50"
    min_points: int = 12
    legacy: bool = False
    marker_corners: bool = False

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "charuco"):
            raise ConfigError(f"board.kind: unknown board {self.kind!r} (chessboard or charuco)")
        if self.columns < 3 or self.rows < 3 or not (math.isfinite(self.square_m) and self.square_m > 0):
            raise ConfigError("board: at least 3x3 corners and a positive square size")
        if not (math.isfinite(self.marker_m) and 0.0 <= self.marker_m < self.square_m):
            raise ConfigError(f"board.marker_m: {self.marker_m} m; a marker lies inside its square "
                              f"({self.square_m} m), or 0 for 0.75 of it")
        if self.min_points < 4:
            raise ConfigError(f"board.min_points: {self.min_points}; a board's pose needs four points or more")
        if self.kind == "charuco" and not hasattr(cv2.aruco, self.dictionary):
            raise ConfigError(f"board.dictionary: OpenCV has no ArUco dictionary {self.dictionary!r}")

    @property
    def chessboard_corners(self) -> int:
        """How many inner corners the board has; a ChArUco board's markers' own corners have the ids after them
        (``chessboard_corners + 4 * marker_id + k``, k = 0 to 3 clockwise from the marker's top left)."""
        if self.kind == "chessboard":
            return self.columns * self.rows
        return (self.columns - 1) * (self.rows - 1)

    def describe(self) -> str:
        """The board as a person would name it."""
        if self.kind == "chessboard":
            return f"a chessboard of {self.columns}x{self.rows} inner corners, {self.square_m * 1000:g} mm squares"
        marker = self.marker_m or 0.75 * self.square_m
        return (f"a ChArUco board of {self.columns}x{self.rows} squares of {self.square_m * 1000:g} mm, markers of "
                f"{marker * 1000:.1f} mm, {self.dictionary}" + (" (the pre-4.6 OpenCV layout)" if self.legacy else ""))

    def object_points(self) -> Array:
        """The chessboard's inner corners on the board plane (z = 0), row by row, in metres."""
        grid = np.mgrid[0:self.columns, 0:self.rows].T.reshape(-1, 2)
        return np.column_stack([grid * self.square_m, np.zeros(len(grid))]).astype(np.float32)

    def charuco_board(self) -> cv2.aruco.CharucoBoard:
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        marker = self.marker_m or 0.75 * self.square_m
        board = cv2.aruco.CharucoBoard((self.columns, self.rows), self.square_m, marker, dictionary)
        board.setLegacyPattern(self.legacy)
        return board


@dataclass(frozen=True)
class BoardView:
    """The board found in one image: (N, 2) pixels, their (N, 3) board points, and the ids (ChArUco: its inner
    corners' ids, then ``markers`` of its markers' own corners, see :attr:`BoardConfig.chessboard_corners`; the
    running index for a chessboard)."""

    name: str
    pixels: Array
    points_m: Array
    ids: np.ndarray
    markers: int = 0

    @property
    def corners(self) -> int:
        """How many of the points are the chessboard's inner corners (the rest are markers' corners)."""
        return len(self.ids) - 4 * self.markers

    def chessboard(self) -> BoardView:
        """The view with the chessboard's inner corners only."""
        keep = slice(0, self.corners)
        return BoardView(self.name, self.pixels[keep], self.points_m[keep], self.ids[keep])

    def counted(self) -> str:
        """What was found, as a person reads it."""
        if not self.markers:
            return f"{len(self.ids)} corners"
        return f"{len(self.ids)} points ({self.corners} chessboard corners, {self.markers} markers' 4 corners each)"


def find_board(image: Image, board: BoardConfig, name: str = "") -> BoardView | None:
    """The board in ``image`` with sub-pixel corners, or None when it is not wholly (chessboard) or
    sufficiently (ChArUco: fewer than ``board.min_points`` points) visible."""
    if board.kind == "chessboard":
        return _find_chessboard(image, board, name)
    view = board_points(image, board, name, markers=board.marker_corners)
    return view if len(view.ids) >= board.min_points else None


def board_points(image: Image, board: BoardConfig, name: str = "", markers: bool = True) -> BoardView:
    """Every point of a ChArUco board that ``image`` shows, however few: the inner corners OpenCV interpolates
    from the markers around them and refines, and (``markers``) each marker's own four corners,
    refined to sub-pixel, so that a camera that sees only a corner of the board (a kart's side camera, looking
    outward while the board lies ahead) still has points enough: six markers give 24 and their corners between.
    Markers whose ids the board does not hold are ignored."""
    if board.kind != "charuco":
        raise ConfigError("board_points is for a ChArUco board; a chessboard is found whole (find_board)")
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    charuco = board.charuco_board()
    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.CharucoDetector(charuco, cv2.aruco.CharucoParameters(), parameters)
    corners, ids, marker_corners, marker_ids = detector.detectBoard(gray)
    base = board.chessboard_corners
    pixels: list[Array] = []
    points: list[Array] = []
    point_ids: list[np.ndarray] = []
    if ids is not None and len(ids):
        ids = ids.ravel()
        pixels.append(corners.reshape(-1, 2))
        points.append(np.asarray(charuco.getChessboardCorners(), np.float64)[ids])
        point_ids.append(ids)
    described = 0
    if markers and marker_ids is not None and len(marker_ids):
        index = {int(i): k for k, i in enumerate(np.asarray(charuco.getIds()).ravel())}
        objects = charuco.getObjPoints()
        for quad, marker_id in zip(marker_corners, np.asarray(marker_ids).ravel(), strict=True):
            k = index.get(int(marker_id))
            if k is None:
                continue
            pixels.append(np.asarray(quad, np.float64).reshape(4, 2))
            points.append(np.asarray(objects[k], np.float64).reshape(4, 3))
            point_ids.append(base + 4 * int(marker_id) + np.arange(4))
            described += 1
    if not pixels:
        return BoardView(name, np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0, np.int64))
    return BoardView(name, np.concatenate(pixels).astype(np.float64), np.concatenate(points).astype(np.float64),
                     np.concatenate(point_ids).astype(np.int64), described)


def _find_chessboard(image: Image, board: BoardConfig, name: str) -> BoardView | None:
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
    return None


ARUCO_FAMILIES: dict[str, tuple[str, ...]] = {
    "4X4": ("DICT_4X4_50", "DICT_4X4_100", "DICT_4X4_250", "DICT_4X4_1000"),
    "5X5": ("DICT_5X5_50", "DICT_5X5_100", "DICT_5X5_250", "DICT_5X5_1000"),
    "6X6": ("DICT_6X6_50", "DICT_6X6_100", "DICT_6X6_250", "DICT_6X6_1000"),
    "7X7": ("DICT_7X7_50", "DICT_7X7_100", "DICT_7X7_250", "DICT_7X7_1000"),
    "ARUCO_ORIGINAL": ("DICT_ARUCO_ORIGINAL",),
    "APRILTAG_16h5": ("DICT_APRILTAG_16h5",),
    "APRILTAG_25h9": ("DICT_APRILTAG_25h9",),
    "APRILTAG_36h10": ("DICT_APRILTAG_36h10",),
    "APRILTAG_36h11": ("DICT_APRILTAG_36h11",),
}
"""The ArUco dictionaries a ChArUco board is searched in, by family, smallest first: each family's smaller
dictionaries are the first markers of its largest, so the largest finds them all and the smallest that holds the
highest id seen names the board."""

MAX_SQUARES = 24
"""The most squares across or down a board the layout search tries (an A0 sheet of 30 mm squares has 39x28; the
boards teams lay on the floor have 5 to 12)."""

LAYOUT_FIT = 0.12
"""The layout search's fit: the markers' centres on the board mapped into the image by one homography, at most this
share of a marker's side in pixels off where they were seen (RMS). The right layout fits to a fraction of this (the
lens's distortion over a board); a wrong one puts markers whole squares off."""


@dataclass(frozen=True)
class BoardSearch:
    """What :func:`detect_board` found: the board, the markers it was found from, how well the layout fits (RMS,
    in markers' sides), and whether the marker's side was measured (it was not given)."""

    board: BoardConfig
    markers: int
    fit: float
    marker_measured: bool


def _markers(gray: Image, dictionary: str) -> tuple[list[Array], np.ndarray]:
    aruco = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    corners, ids, _ = cv2.aruco.ArucoDetector(aruco).detectMarkers(gray)
    if ids is None:
        return [], np.zeros(0, np.int64)
    return [np.asarray(c, np.float64).reshape(4, 2) for c in corners], np.asarray(ids, np.int64).ravel()


def _layout_fit(board: cv2.aruco.CharucoBoard, seen: Sequence[tuple[list[Array], np.ndarray]]) -> float:
    """RMS of the markers' centres through each image's homography, in markers' sides; infinite where a marker id
    is not on the board."""
    index = {int(i): k for k, i in enumerate(np.asarray(board.getIds()).ravel())}
    objects = board.getObjPoints()
    errors: list[float] = []
    for quads, ids in seen:
        if len(ids) < 4:
            continue
        if any(int(i) not in index for i in ids):
            return math.inf
        on_board = np.array([np.asarray(objects[index[int(i)]])[:, :2].mean(axis=0) for i in ids])
        in_image = np.array([q.mean(axis=0) for q in quads])
        homography, _ = cv2.findHomography(on_board, in_image, 0)
        if homography is None:
            return math.inf
        mapped = cv2.perspectiveTransform(on_board.reshape(-1, 1, 2), homography).reshape(-1, 2)
        side_px = np.array([np.mean(np.linalg.norm(q - np.roll(q, 1, axis=0), axis=1)) for q in quads])
        errors.extend((np.linalg.norm(mapped - in_image, axis=1) / side_px).tolist())
    return float(np.sqrt(np.mean(np.square(errors)))) if errors else math.inf


def detect_board(images: Sequence[Image], square_m: float, marker_m: float = 0.0) -> BoardSearch:
    """The ChArUco board that ``images`` show (the same board in each, seen whole or in part): its dictionary,
    from the family whose markers are found most often, the smallest of it that holds the highest id seen; its
    squares across and down and the OpenCV layout (the one since 4.6, or the one before), from the markers'
    centres: the layout whose centres one homography per image maps onto the seen ones (``LAYOUT_FIT``); the
    marker's side, unless given, measured against the inner corners (:func:`measure_marker`). The square's side
    cannot be told from images
    (a board twice the size twice as far looks the same): it is given.

    Layouts that differ only in squares beyond the highest marker seen place every seen point alike; the smallest
    is named, and no point of the images depends on it."""
    if not (math.isfinite(square_m) and square_m > 0):
        raise ConfigError(f"the board's square side must be a positive number of metres, got {square_m}")
    grays = [cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) if im.ndim == 3 else im for im in images]
    best_family, best_seen, best_count = "", [], 0
    for family, dictionaries in ARUCO_FAMILIES.items():
        seen = [_markers(gray, dictionaries[-1]) for gray in grays]
        count = sum(len(ids) for _, ids in seen)
        if count > best_count:
            best_family, best_seen, best_count = family, seen, count
    if best_count < 4:
        raise CalibrationError(f"no ChArUco board in the images: {best_count} ArUco markers of any common dictionary "
                               f"({', '.join(ARUCO_FAMILIES)}) found; is the board in view, lit and sharp?")
    highest = max(int(ids.max()) for _, ids in best_seen if len(ids))
    dictionaries = ARUCO_FAMILIES[best_family]
    sizes = [cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, d)).bytesList.shape[0] for d in dictionaries]
    dictionary = next(d for d, n in zip(dictionaries, sizes, strict=True) if n > highest)
    capacity = max(sizes)
    trial_marker = marker_m or 0.75 * square_m
    found: tuple[float, int, int, int, bool] | None = None
    for columns in range(3, MAX_SQUARES + 1):
        for rows in range(3, MAX_SQUARES + 1):
            if not highest < columns * rows // 2 <= capacity:
                continue
            for legacy in (False, True):
                config = BoardConfig("charuco", columns, rows, square_m, trial_marker, dictionary, legacy=legacy)
                fit = _layout_fit(config.charuco_board(), best_seen)
                key = (fit, columns * rows, columns, rows, legacy)
                # within 1 % of the best fit, the fewer squares: they differ only beyond the markers seen
                if found is None or fit < 0.99 * found[0] or (fit <= 1.01 * found[0] and columns * rows < found[1]):
                    found = key
    if found is None or not found[0] <= LAYOUT_FIT:
        fit_text = f"the best fits to {found[0]:.2f} of a marker's side" if found and math.isfinite(found[0]) else ""
        raise CalibrationError(f"{best_count} {dictionary} markers found, but no ChArUco layout of up to "
                               f"{MAX_SQUARES}x{MAX_SQUARES} squares places them ({fit_text or 'none fits'}); give "
                               "--board COLUMNSxROWS and --dictionary")
    fit, _, columns, rows, legacy = found
    board = BoardConfig("charuco", columns, rows, square_m, trial_marker, dictionary, legacy=legacy,
                        marker_corners=True)
    measured = measure_marker(grays, board) if not marker_m else None
    if measured is not None:
        board = replace(board, marker_m=measured)
    return BoardSearch(board, best_count, fit, measured is not None)


MIN_MEASURING_CORNERS = 8
"""Fewest inner corners in an image for it to measure the markers' side (:func:`measure_marker`)."""


def measure_marker(images: Sequence[Image], board: BoardConfig) -> float | None:
    """The side of the board's markers as the detector places their corners, in metres: each marker's corners mapped
    onto the board through the homography of the inner corners around them (which the detector places to a tenth of
    a pixel), the median side over the images. None where no image shows ``MIN_MEASURING_CORNERS`` inner corners.

    On the Hanze kart's images the markers measure 83 to 84 mm where the team's board says 86: the corners the
    detector finds lie a millimetre inside the printed ones, or the print is smaller. Either way the markers'
    corners are consistent with the inner corners only at the measured side."""
    sides: list[float] = []
    for image in images:
        view = board_points(image, board)
        chess = view.chessboard()
        if view.markers == 0 or chess.corners < MIN_MEASURING_CORNERS:
            continue
        homography, _ = cv2.findHomography(chess.pixels, chess.points_m[:, :2], 0)
        if homography is None:
            continue
        quads = view.pixels[view.corners:].reshape(-1, 1, 2)
        back = cv2.perspectiveTransform(quads.astype(np.float64), homography).reshape(-1, 4, 2)
        sides.extend(np.linalg.norm(back - np.roll(back, 1, axis=1), axis=2).ravel().tolist())
    if not sides:
        return None
    side = float(np.median(sides))
    return side if 0.3 * board.square_m < side < board.square_m else None


def read_views(paths: Sequence[str | Path], board: BoardConfig) -> tuple[list[BoardView], list[str], tuple[int, int]]:
    """(views found, names skipped with the reason, image size) for image files. Images of another size
    than the first are skipped: one calibration is for one resolution."""
    views: list[BoardView] = []
    skipped: list[str] = []
    size: tuple[int, int] | None = None
    for path in paths:
        path = Path(path)
        try:
            image = read_gray(path)
        except DataError as exc:
            skipped.append(f"{path.name}: {exc}")
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


MIN_VIEW_MOTION = 0.05
"""A video's frame is a new view of the board when its points moved by this share of the image's width since the
last view kept (the median point): a board held still for a second is one view, not thirty copies of it."""


def views_from_frames(frames: Iterable[tuple[str, Image]], board: BoardConfig, max_views: int = 40
                      ) -> tuple[list[BoardView], int, tuple[int, int]]:
    """(views, frames read, image size) from a video's frames: the frames where the board is found and has moved
    since the last view kept (``MIN_VIEW_MOTION``), thinned evenly to ``max_views``."""
    views: list[BoardView] = []
    size: tuple[int, int] | None = None
    read = 0
    for name, image in frames:
        read += 1
        if size is None:
            size = (image.shape[1], image.shape[0])
        elif (image.shape[1], image.shape[0]) != size:
            raise DataError(f"{name}: {image.shape[1]}x{image.shape[0]}, not {size[0]}x{size[1]} like the first frame")
        view = find_board(image, board, name)
        if view is None:
            continue
        if views:
            last = views[-1]
            shared, here, there = np.intersect1d(view.ids, last.ids, return_indices=True)
            moved = (float(np.median(np.linalg.norm(view.pixels[here] - last.pixels[there], axis=1)))
                     if len(shared) else math.inf)
            if moved < MIN_VIEW_MOTION * size[0]:
                continue
        views.append(view)
    if size is None:
        raise DataError("the video has no frames")
    if len(views) > max_views:
        views = [views[k] for k in np.linspace(0, len(views) - 1, max_views).round().astype(int)]
    return views, read, size


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

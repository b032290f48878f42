"""Paint across the lane, on the ground: stop lines and zebra crossings, through the camera's mount.

The centre image is warped to the ground from above (the camera's pose over the ground, from ``kartpilot calibrate
ground``), where a stop line is a bar across the lane of a fixed depth and a zebra a row of stripes along the road,
whatever their distance. Paint is what is brighter than the asphalt around it by more than the ground's own texture
(a grey top-hat a metre wide, thresholded at the median plus ``noise_sigmas`` robust standard deviations of the
ground within a few metres of each row). A lane boundary, which runs along the road, covers little of any row across
the lane; a stop line covers most of it (``stop_cover``) over a depth of ``stop_depth_m``; a zebra's rows hold at
least ``zebra_min_stripes`` separate stripes of a stripe's width over ``zebra_min_length_m`` along the road.

Without a camera mount there is no ground and nothing is reported: these marks are told apart by their size on the
ground, not by how they look in the image.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.ndimage import median_filter

from kartpilot.calibration.ground import BirdseyeView, birdseye_homography
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import Image
from kartpilot.perception.objects import Detection

__all__ = ["RoadMarkConfig", "camera_for_image", "detect_road_marks"]


@dataclass(frozen=True)
class RoadMarkConfig:
    """Attributes:
        near_m, far_m: the stretch of ground ahead that is searched.
        lane_half_width_m: half the lane's width: the stop line is sought across it.
        zebra_half_width_m: half the width searched for a zebra's stripes.
        pixels_per_m: the ground view's resolution.
        noise_sigmas, min_contrast: the paint threshold (robust sigmas above the median top-hat; a floor).
        stop_cover: the least share of the lane's width that a stop line's rows cover.
        stop_depth_m: a stop line's depth along the road (least, most).
        stripe_width_m: a zebra stripe's width across the road (least, most).
        zebra_min_stripes, zebra_min_length_m: the fewest stripes side by side, over at least this length.
        stats_half_window_m: each row's paint threshold comes from the rows this far either side of it (a
            running median of the rows' own statistics; wider than half a zebra's length, so a zebra's rows,
            a third paint, do not raise their own threshold).
    """

    near_m: float = 1.2
    far_m: float = 16.0
    lane_half_width_m: float = 1.4
    zebra_half_width_m: float = 2.5
    pixels_per_m: float = 25.0
    noise_sigmas: float = 5.0
    min_contrast: float = 20.0
    stop_cover: float = 0.6
    stop_depth_m: tuple[float, float] = (0.08, 0.8)
    stripe_width_m: tuple[float, float] = (0.2, 1.0)
    zebra_min_stripes: int = 3
    zebra_min_length_m: float = 1.0
    stats_half_window_m: float = 4.0

    def __post_init__(self) -> None:
        if not 0 < self.near_m < self.far_m or self.pixels_per_m <= 0:
            raise ConfigError("road_marks: need 0 < near_m < far_m and a positive pixels_per_m")
        if not 0 < self.lane_half_width_m <= self.zebra_half_width_m:
            raise ConfigError("road_marks: need 0 < lane_half_width_m <= zebra_half_width_m")


MAX_ASPECT_CHANGE = 0.03
"""An image whose width over height differs from the calibration's by more than this share is another camera's
(or a crop), not the calibrated camera's at another resolution."""


def camera_for_image(camera: PinholeCamera, width_px: int, height_px: int) -> PinholeCamera:
    """The camera's model for an image of another size than its calibration's (the same field of view). An image
    of another shape is refused: the mount would place everything on the ground at a wrong distance (a 160x120
    image read as the SDC kart's 848x480 centre camera takes its hood and the sky for the road)."""
    if (camera.width_px, camera.height_px) == (width_px, height_px):
        return camera
    if abs((width_px / height_px) / (camera.width_px / camera.height_px) - 1.0) > MAX_ASPECT_CHANGE:
        raise ConfigError(f"the image is {width_px}x{height_px} and the camera that places it on the ground is "
                          f"calibrated at {camera.width_px}x{camera.height_px}, another shape: give this camera's "
                          "own calibration and mount (--rig)")
    sx, sy = width_px / camera.width_px, height_px / camera.height_px
    return replace(camera, fx_px=camera.fx_px * sx, fy_px=camera.fy_px * sy, cx_px=(camera.cx_px + 0.5) * sx - 0.5,
                   cy_px=(camera.cy_px + 0.5) * sy - 0.5, width_px=width_px, height_px=height_px)


def detect_road_marks(image: Image, camera: PinholeCamera | None, config: RoadMarkConfig = RoadMarkConfig()
                      ) -> list[Detection]:
    """Stop lines and zebra crossings ahead, each with its near edge's distance on the ground."""
    if camera is None:
        return []
    h, w = image.shape[:2]
    camera = camera_for_image(camera, w, h)
    view = BirdseyeView((config.near_m, config.far_m), (-config.zebra_half_width_m, config.zebra_half_width_m),
                        config.pixels_per_m)
    bw, bh = view.size_wh
    homography = birdseye_homography(camera, view)
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    ground = cv2.warpPerspective(gray, homography, (bw, bh), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    valid = cv2.warpPerspective(np.full((h, w), 255, np.uint8), homography, (bw, bh),
                                flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP) > 0
    valid &= _in_front(view, camera)
    if valid.sum() < 50:
        return []
    k = max(3, round(1.2 * config.pixels_per_m) | 1)
    tophat = cv2.morphologyEx(ground, cv2.MORPH_TOPHAT, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
    paint = (tophat > _row_thresholds(tophat, valid, config)[:, None]) & valid
    out: list[Detection] = []
    ys = (np.arange(bw) + 0.5) / config.pixels_per_m  # lateral offset of each column, left positive, from the right
    lateral = config.zebra_half_width_m - ys
    lane = np.abs(lateral) <= config.lane_half_width_m
    zebra_cols = np.abs(lateral) <= config.zebra_half_width_m
    cover = (paint[:, lane].sum(axis=1) / np.maximum(valid[:, lane].sum(axis=1), 1)) * (
        valid[:, lane].mean(axis=1) > 0.6)
    for r0, r1 in _bands(cover >= config.stop_cover):
        depth = (r1 - r0) / config.pixels_per_m
        if config.stop_depth_m[0] <= depth <= config.stop_depth_m[1]:
            out.append(_detection("stop_line", view, camera, (r0, r1), lane, float(np.mean(cover[r0:r1])), w, h))
    stripe_px = (config.stripe_width_m[0] * config.pixels_per_m, config.stripe_width_m[1] * config.pixels_per_m)
    stripes = np.array([_count_runs(row[zebra_cols], stripe_px) for row in paint])
    for r0, r1 in _bands(stripes >= config.zebra_min_stripes):
        if (r1 - r0) / config.pixels_per_m >= config.zebra_min_length_m:
            share = min(1.0, float(np.mean(stripes[r0:r1])) / (2 * config.zebra_min_stripes))
            out.append(_detection("zebra", view, camera, (r0, r1), zebra_cols, 0.5 + 0.5 * share, w, h))
    return out


def _row_thresholds(tophat: np.ndarray, valid: np.ndarray, config: RoadMarkConfig) -> np.ndarray:
    """Each row's paint threshold from the ground within ``stats_half_window_m`` of it (a running median of the
    rows' own median and spread): near ground is seen sharp (its grain stands out), far ground blurred, so one
    threshold for all rows takes the near grain for paint. A stop line or a zebra fills fewer than half the rows
    of the window, so it does not raise its own threshold."""
    values = np.where(valid, tophat.astype(np.float32), np.nan)
    seen = valid.sum(axis=1) >= 10
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        median = np.nanmedian(values, axis=1)
        mad = np.nanmedian(np.abs(values - median[:, None]), axis=1)
    size = 2 * max(1, round(config.stats_half_window_m * config.pixels_per_m)) + 1
    if seen.any():
        rows = np.flatnonzero(seen)
        median[~seen] = np.interp(np.flatnonzero(~seen), rows, median[rows])
        mad[~seen] = np.interp(np.flatnonzero(~seen), rows, mad[rows])
        median = median_filter(median, size=size, mode="nearest")
        mad = median_filter(mad, size=size, mode="nearest")
    out = np.maximum(median + config.noise_sigmas * 1.4826 * np.maximum(mad, 1.0), config.min_contrast)
    return np.where(seen, out, np.inf)


def _in_front(view: BirdseyeView, camera: PinholeCamera) -> np.ndarray:
    """Ground pixels well in front of the camera (the homography folds what lies behind it onto the image)."""
    bw, bh = view.size_wh
    grid = np.stack(np.meshgrid(np.arange(bw), np.arange(bh)), axis=-1).reshape(-1, 2).astype(np.float64)
    ground = np.column_stack([grid, np.ones(len(grid))]) @ view.ground_from_pixels().T
    cam_body = np.linalg.inv(camera.pose_body_cam_array)
    depth = np.column_stack([ground[:, :2], np.zeros(len(ground))]) @ cam_body[2, :3] + cam_body[2, 3]
    return (depth > 0.3).reshape(bh, bw)


def _bands(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first, past-last) of each run of True."""
    padded = np.r_[False, flags, False].astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _count_runs(row: np.ndarray, width_px: tuple[float, float]) -> int:
    return sum(1 for a, b in _bands(row) if width_px[0] <= b - a <= width_px[1])


def _detection(label: str, view: BirdseyeView, camera: PinholeCamera, rows: tuple[int, int], cols: np.ndarray,
               confidence: float, w: int, h: int) -> Detection:
    """The mark's box in the image (its ground rectangle's corners projected) and its near edge's distance."""
    c = np.flatnonzero(cols)
    corners = np.array([[c[0], rows[0]], [c[-1] + 1, rows[0]], [c[-1] + 1, rows[1]], [c[0], rows[1]]], np.float64)
    ground = np.column_stack([corners, np.ones(4)]) @ view.ground_from_pixels().T
    cam_body = np.linalg.inv(camera.pose_body_cam_array)
    pts = np.column_stack([ground[:, :2], np.zeros(4)]) @ cam_body[:3, :3].T + cam_body[:3, 3]
    px = camera.project(pts)
    box = (float(np.clip(px[:, 0].min(), 0, w - 1)), float(np.clip(px[:, 1].min(), 0, h - 1)),
           float(np.clip(px[:, 0].max(), 0, w - 1)), float(np.clip(px[:, 1].max(), 0, h - 1)))
    near_x = float(ground[:, 0].min())
    return Detection(label, box, float(min(max(confidence, 0.0), 1.0)), distance_m=near_x, lateral_m=0.0)

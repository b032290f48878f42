"""Stereo depth on a rectified pair: feature triangulation with the thesis's
filters, and dense block matching (StereoBM / StereoSGBM, optional WLS filter).

For a rectified pair the linear triangulation of a correspondence reduces to
``Z = fx * b / d``, ``X = (u - cx) * Z / fx``, ``Y = (v - cy) * Z / fy`` with the
disparity ``d = u_left - u_right`` (Hartley and Zisserman, ch. 12); it is exact
and cheaper than ``cv2.triangulatePoints``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.core.camera import StereoRig
from kartpilot.core.errors import ConfigError, PerceptionError
from kartpilot.core.geometry import Array
from kartpilot.core.types import Image

__all__ = [
    "BlockMatchConfig",
    "StereoFilterConfig",
    "compute_disparity",
    "refine_disparity_zncc",
    "stereo_filter_mask",
    "stereo_match_margin",
    "triangulate_rectified",
]


@dataclass(frozen=True)
class StereoFilterConfig:
    """The thesis's filters on stereo correspondences.

    Attributes:
        epipolar_band_px: largest row difference of a match (the thesis found 2 px ideal).
        min_depth_m, max_depth_m: depth range filter (the thesis used 1 to 45 m).
    """

    epipolar_band_px: float = 2.0
    min_depth_m: float = 1.0
    max_depth_m: float = 45.0

    def __post_init__(self) -> None:
        if self.epipolar_band_px < 0:
            raise ConfigError("stereo.epipolar_band_px must not be negative")
        if not 0 < self.min_depth_m < self.max_depth_m:
            raise ConfigError(
                f"stereo depth range must satisfy 0 < min < max, got {self.min_depth_m}..{self.max_depth_m}"
            )

    def disparity_range_px(self, rig: StereoRig) -> tuple[float, float]:
        """Disparities that correspond to the depth range on ``rig``."""
        focal_baseline = rig.camera.fx_px * rig.baseline_m
        return focal_baseline / self.max_depth_m, focal_baseline / self.min_depth_m


def triangulate_rectified(rig: StereoRig, left_px: Array, right_px: Array) -> Array:
    """3D points (N, 3) in the left camera frame from rectified correspondences.

    Points with non-positive disparity get ``inf`` depth; filter them with
    :func:`stereo_filter_mask` first.
    """
    left = np.asarray(left_px, dtype=np.float64).reshape(-1, 2)
    right = np.asarray(right_px, dtype=np.float64).reshape(-1, 2)
    camera = rig.camera
    disparity = left[:, 0] - right[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(disparity > 0, camera.fx_px * rig.baseline_m / disparity, np.inf)
    row = 0.5 * (left[:, 1] + right[:, 1])
    x = (left[:, 0] - camera.cx_px) * depth / camera.fx_px
    y = (row - camera.cy_px) * depth / camera.fy_px
    return np.stack([x, y, depth], axis=1)


def stereo_filter_mask(rig: StereoRig, left_px: Array, right_px: Array,
                       config: StereoFilterConfig) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """The epipolar and depth-range filters.

    Returns:
        (epipolar_ok, depth_ok): the first keeps matches whose rows differ by at most
        the band and whose disparity is positive; the second additionally keeps only
        depths inside the range.
    """
    left = np.asarray(left_px, dtype=np.float64).reshape(-1, 2)
    right = np.asarray(right_px, dtype=np.float64).reshape(-1, 2)
    disparity = left[:, 0] - right[:, 0]
    epipolar_ok = (np.abs(left[:, 1] - right[:, 1]) <= config.epipolar_band_px) & (disparity > 0)
    low, high = config.disparity_range_px(rig)
    depth_ok = epipolar_ok & (disparity >= low) & (disparity <= high)
    return epipolar_ok, depth_ok


def refine_disparity_zncc(
    left: Image, right: Image, left_px: NDArray[np.float32], disparity_px: NDArray[np.float32],
    half_window_px: int = 5, search_px: int = 1,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.bool_]]:
    """Sub-pixel disparity by zero-mean normalised cross-correlation along the row.

    Each left point is rounded to its pixel, and its patch is compared with the right
    patches at integer disparities ``round(d) - search .. round(d) + search``. Between
    the best integer disparity and its better neighbour, the right patch is linearly
    interpolated and the ZNCC maximised over the fraction in closed form: the score is
    a linear function over the square root of a quadratic, so its maximum solves a
    linear equation (Psarakis and Evangelidis, "An enhanced correlation-based method
    for stereo correspondence with subpixel accuracy", ICCV 2005). A parabola through
    the integer scores, the usual shortcut, pulls the result toward whole pixels
    ("pixel locking"); this does not. ZNCC is invariant to gain and offset between the
    cameras, which biases SSD-based trackers (KLT) when the two exposures differ.

    Returns:
        (left pixels rounded, refined disparity, valid mask); invalid where the window
        leaves the image, the peak lies outside the searched range, the texture is flat
        or the best correlation is below 0.7.
    """
    count = len(left_px)
    height, width = left.shape
    h = half_window_px
    u = np.rint(left_px[:, 0]).astype(np.int64)
    v = np.rint(left_px[:, 1]).astype(np.int64)
    d0 = np.rint(disparity_px).astype(np.int64)
    offsets = np.arange(-search_px - 1, search_px + 2)  # one extra each side for the interpolation
    valid = (v - h >= 0) & (v + h < height) & (u + h < width) & (u - d0 - search_px - 1 - h >= 0) & (u - h >= 0)
    rounded = np.stack([u, v], axis=1).astype(np.float32)
    refined = np.full(count, np.nan, dtype=np.float32)
    index = np.flatnonzero(valid)
    if index.size == 0:
        return rounded, refined, valid
    window = np.arange(-h, h + 1)
    rows = (v[index, None, None] + window[None, :, None])  # (M, W, 1)
    cols_left = (u[index, None, None] + window[None, None, :])  # (M, 1, W)
    patch_left = left[rows, cols_left].astype(np.float32).reshape(index.size, -1)
    cols_right = (u[index, None, None, None] - d0[index, None, None, None] - offsets[None, :, None, None]
                  + window[None, None, None, :])  # (M, S, 1, W)
    patch_right = right[rows[:, None, :, :], cols_right].astype(np.float32).reshape(index.size, offsets.size, -1)
    zl = patch_left - patch_left.mean(axis=1, keepdims=True)
    zr = patch_right - patch_right.mean(axis=2, keepdims=True)
    norm_l = np.sqrt((zl**2).sum(axis=1))
    cross = np.einsum("mk,msk->ms", zl, zr)  # <left, right at offset s>
    power = np.einsum("msk,msk->ms", zr, zr)  # |right at s|^2
    adjacent = np.einsum("msk,msk->ms", zr[:, :-1], zr[:, 1:])  # <right at s, right at s + 1>
    score = cross / np.maximum(norm_l[:, None] * np.sqrt(power), 1e-6)
    # the outer offsets only serve the interpolation: a peak beyond the searched range
    # shows up as a neighbour scoring higher, which the fraction's range test rejects
    best = np.argmax(score[:, 1:-1], axis=1) + 1
    m = np.arange(index.size)
    low = np.where(score[m, best - 1] > score[m, best + 1], best - 1, best)  # the peak lies in [low, low + 1]
    # right(t) = (1 - t) A + t B: <left, right(t)> = l0 + l1 t, |right(t)|^2 = q0 + q1 t + q2 t^2;
    # d/dt of (l0 + l1 t) / sqrt(q) vanishes where 2 l1 q - (l0 + l1 t) q' = 0, linear in t
    l0, l1 = cross[m, low], cross[m, low + 1] - cross[m, low]
    q0 = power[m, low]
    q1 = 2.0 * (adjacent[m, low] - q0)
    q2 = q0 - 2.0 * adjacent[m, low] + power[m, low + 1]
    denominator = l1 * q1 - 2.0 * l0 * q2
    solvable = np.abs(denominator) > 1e-9 * np.maximum(np.abs(l0 * q1), 1.0)
    fraction = np.where(solvable, (l0 * q1 - 2.0 * l1 * q0) / np.where(solvable, denominator, 1.0), np.nan)
    textured = (norm_l > 1e-3 * patch_left.shape[1]) & (score[m, best] > 0.7)
    # a fraction outside [0, 1] means the interpolated score has no maximum between the two
    ok = textured & solvable & (fraction >= -0.01) & (fraction <= 1.01)
    refined[index] = (d0[index] + offsets[low] + np.clip(fraction, 0.0, 1.0)).astype(np.float32)
    valid[index] = ok
    return rounded, refined, valid


def stereo_match_margin(
    left: Image, right: Image, left_px: Array, disparity_px: Array, min_disparity_px: float,
    max_disparity_px: float, half_window_px: int = 5, exclusion_px: float = 2.0,
) -> Array:
    """How much better each stereo match is than the best other disparity along its row.

    The ZNCC of the left patch is computed at every integer disparity of the range; the margin is the
    score at the match's disparity minus the highest score farther than ``exclusion_px`` from it.
    Repeated structure (a row of cones, a fence, windows) gives a margin near zero or below: the
    match may be the wrong copy, and its depth is then wrong by metres although every filter passes
    (the uniqueness test of block matchers, applied to sparse matches).

    Returns:
        (N,) margins; ``inf`` where nothing else along the row fits in the image, NaN where the
        match's own window does not.
    """
    height, width = left.shape
    h = half_window_px
    margins = np.full(len(left_px), np.nan)
    low, high = max(int(np.floor(min_disparity_px)), 0), int(np.ceil(max_disparity_px))
    for k, ((x, y), d) in enumerate(zip(np.rint(left_px).astype(np.int64), disparity_px, strict=True)):
        if not (h <= y < height - h and h <= x < width - h) or not np.isfinite(d):
            continue
        first = max(x - high - h, 0)  # right column of the largest disparity's window start
        last = x - low + h + 1
        if last - first < 2 * h + 2 or x - int(np.rint(d)) - h < first:
            continue
        strip = right[y - h:y + h + 1, first:min(last, width)]
        scores = cv2.matchTemplate(strip, left[y - h:y + h + 1, x - h:x + h + 1], cv2.TM_CCOEFF_NORMED).ravel()
        disparities = x - (first + h + np.arange(scores.size))
        own = np.abs(disparities - d) <= 0.5 + 1e-9
        others = np.abs(disparities - d) > exclusion_px
        if not own.any():
            continue
        margins[k] = float(scores[own].max()) - (float(scores[others].max()) if others.any() else -np.inf)
    return margins


@dataclass(frozen=True)
class BlockMatchConfig:
    """Dense stereo matching (OpenCV StereoBM / StereoSGBM, optional WLS post-filter).

    Attributes:
        method: ``bm`` or ``sgbm``.
        num_disparities: search range in pixels (rounded up to a multiple of 16).
        block_size: matching window (odd).
        wls: apply the weighted-least-squares filter (Min et al., "Fast global image
            smoothing based on weighted least squares", TIP 2014) using a right-to-left match.
        wls_lambda, wls_sigma: the filter's smoothness and edge sensitivity.
    """

    method: Literal["bm", "sgbm"] = "sgbm"
    num_disparities: int = 128
    block_size: int = 5
    wls: bool = False
    wls_lambda: float = 8000.0
    wls_sigma: float = 1.5

    def __post_init__(self) -> None:
        if self.block_size < 3 or self.block_size % 2 == 0:
            raise ConfigError(f"block_match.block_size must be odd and at least 3, got {self.block_size}")
        if self.num_disparities < 16:
            raise ConfigError("block_match.num_disparities must be at least 16")


def _create_matcher(config: BlockMatchConfig) -> cv2.StereoMatcher:
    disparities = int(np.ceil(config.num_disparities / 16) * 16)
    if config.method == "bm":
        matcher = cv2.StereoBM_create(numDisparities=disparities, blockSize=max(config.block_size, 5))
        matcher.setUniquenessRatio(10)
        matcher.setTextureThreshold(10)
        return matcher
    block = config.block_size
    return cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=disparities, blockSize=block,
        P1=8 * block * block, P2=32 * block * block, disp12MaxDiff=1, uniquenessRatio=10,
        speckleWindowSize=100, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)


def compute_disparity(left: Image, right: Image, config: BlockMatchConfig) -> NDArray[np.float32]:
    """Dense disparity in pixels for the left image; invalid pixels are NaN."""
    if left.shape != right.shape or left.ndim != 2:
        raise PerceptionError(f"block matching needs two grayscale images of one size, got {left.shape}, {right.shape}")
    matcher = _create_matcher(config)
    raw_left = matcher.compute(left, right)
    if config.wls:
        right_matcher = cv2.ximgproc.createRightMatcher(matcher)
        raw_right = right_matcher.compute(right, left)
        wls = cv2.ximgproc.createDisparityWLSFilter(matcher)
        wls.setLambda(config.wls_lambda)
        wls.setSigmaColor(config.wls_sigma)
        raw_left = wls.filter(raw_left, left, disparity_map_right=raw_right)
    disparity = raw_left.astype(np.float32) / 16.0
    disparity[disparity <= 0] = np.nan
    return disparity

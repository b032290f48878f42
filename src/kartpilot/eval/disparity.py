"""Dense disparity accuracy: the Middlebury "bad-t" error.

Scharstein and Szeliski, "A taxonomy and evaluation of dense two-frame stereo
correspondence algorithms", IJCV 2002: the share of pixels with known ground
truth whose disparity error exceeds ``t`` pixels; pixels without an estimate
count as bad (the Middlebury v3 "all" convention).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.core.errors import DataError
from kartpilot.core.images import read_gray, read_image

__all__ = ["DisparityScore", "bad_pixel_rate", "disparity_search_range_px", "load_middlebury_pair"]


@dataclass(frozen=True)
class DisparityScore:
    bad_percent: float
    invalid_percent: float
    threshold_px: float
    pixels_with_truth: int


def bad_pixel_rate(
    estimate: NDArray[np.float32], truth: NDArray[np.float32], threshold_px: float = 2.0
) -> DisparityScore:
    """Score a disparity map (NaN = no estimate) against ground truth (NaN/inf/0 = unknown)."""
    if estimate.shape != truth.shape:
        raise DataError(f"disparity shapes differ: {estimate.shape} vs {truth.shape}")
    known = np.isfinite(truth) & (truth > 0)
    count = int(known.sum())
    if count == 0:
        raise DataError("the ground truth has no known pixels")
    missing = known & ~np.isfinite(estimate)
    error = np.abs(np.where(np.isfinite(estimate), estimate, 0.0) - np.where(known, truth, 0.0))
    bad = missing | (known & (error > threshold_px))
    return DisparityScore(100.0 * bad.sum() / count, 100.0 * missing.sum() / count, threshold_px, count)


def disparity_search_range_px(truth: NDArray[np.float32]) -> int:
    """A block matcher's ``num_disparities`` covering the ground truth: a multiple of 16, with a margin."""
    known = truth[np.isfinite(truth)]
    if known.size == 0:
        raise DataError("the ground truth has no known pixels")
    return int(np.ceil(float(known.max()) / 16) * 16 + 16)


def load_middlebury_pair(folder: str | Path) -> tuple[np.ndarray, np.ndarray, NDArray[np.float32]]:
    """Load a pair from ``../shared/data/stereo-pairs``: left, right (grayscale) and the truth disparity.

    Supports the 2014 layout (``*_left.png``, ``*_right.png``, ``*_disp.npz``) and the
    2006 layout (``*L.jpg``, ``*R.jpg``, ``*GT.png``, disparities in px, 0 = unknown).
    """
    folder = Path(folder)
    left = sorted(folder.glob("*_left.png")) or sorted(folder.glob("*L.jpg"))
    right = sorted(folder.glob("*_right.png")) or sorted(folder.glob("*R.jpg"))
    if not left or not right:
        raise DataError(f"no stereo pair in {folder}")
    left_image, right_image = read_gray(left[0]), read_gray(right[0])
    npz = sorted(folder.glob("*_disp.npz"))
    if npz:
        truth = np.load(npz[0])["arr_0"].astype(np.float32)
    else:
        gt = sorted(folder.glob("*GT.png"))
        if not gt:
            raise DataError(f"no ground-truth disparity in {folder}")
        truth = read_image(gt[0], cv2.IMREAD_UNCHANGED).astype(np.float32)
        truth[truth == 0] = np.nan
    if truth.shape != left_image.shape or right_image.shape != left_image.shape:
        raise DataError(f"{folder}: images {left_image.shape}/{right_image.shape} and ground truth {truth.shape} "
                        "differ in size")
    return left_image, right_image, truth

"""Descriptor matching: brute force or FLANN with Lowe's ratio test, and stereo
matching restricted to the epipolar band of a rectified pair.

Lowe, "Distinctive image features from scale-invariant keypoints", IJCV 2004:
a match is kept when its distance is below ``ratio`` times the second best.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.core.errors import ConfigError

__all__ = ["MatchConfig", "Matches", "descriptor_distances", "match_descriptors", "match_in_band"]

IndexArray = NDArray[np.intp]

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


@dataclass(frozen=True)
class MatchConfig:
    """Descriptor matching settings.

    Attributes:
        matcher: ``bf`` (exact brute force) or ``flann`` (approximate; LSH for binary descriptors).
        ratio: Lowe's ratio threshold (the thesis chose 0.7 for SIFT; 0.8 is Lowe's value).
        cross_check: keep only mutual best matches.
    """

    matcher: Literal["bf", "flann"] = "bf"
    ratio: float = 0.8
    cross_check: bool = False

    def __post_init__(self) -> None:
        if not 0.0 < self.ratio <= 1.0:
            raise ConfigError(f"matching.ratio must be in (0, 1], got {self.ratio}")


@dataclass(frozen=True)
class Matches:
    """Index pairs into two feature sets, with descriptor distances."""

    index_a: IndexArray
    index_b: IndexArray
    distance: NDArray[np.float32]

    def __len__(self) -> int:
        return int(self.index_a.shape[0])


def _empty() -> Matches:
    return Matches(np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0, np.float32))


def _make_matcher(config: MatchConfig, binary: bool) -> cv2.DescriptorMatcher:
    if config.matcher == "bf":
        return cv2.BFMatcher(cv2.NORM_HAMMING if binary else cv2.NORM_L2)
    if binary:
        index_params = {"algorithm": 6, "table_number": 6, "key_size": 12, "multi_probe_level": 1}
    else:
        index_params = {"algorithm": 1, "trees": 4}
    return cv2.FlannBasedMatcher(index_params, {"checks": 50})


def _ratio_matches(matcher: cv2.DescriptorMatcher, desc_a: np.ndarray, desc_b: np.ndarray,
                   ratio: float) -> dict[int, tuple[int, float]]:
    best: dict[int, tuple[int, float]] = {}
    for pair in matcher.knnMatch(desc_a, desc_b, k=2):
        if not pair:
            continue
        first = pair[0]
        if len(pair) == 1 or first.distance < ratio * pair[1].distance:
            best[first.queryIdx] = (first.trainIdx, first.distance)
    return best


def match_descriptors(desc_a: np.ndarray, desc_b: np.ndarray, binary: bool, config: MatchConfig) -> Matches:
    """Match every descriptor of ``a`` to ``b`` with the ratio test (and optional cross-check)."""
    if len(desc_a) < 2 or len(desc_b) < 2:
        return _empty()
    if not binary:
        desc_a, desc_b = desc_a.astype(np.float32), desc_b.astype(np.float32)
    matcher = _make_matcher(config, binary)
    forward = _ratio_matches(matcher, desc_a, desc_b, config.ratio)
    if config.cross_check:
        backward = _ratio_matches(matcher, desc_b, desc_a, config.ratio)
        forward = {a: (b, d) for a, (b, d) in forward.items() if backward.get(b, (-1, 0.0))[0] == a}
    if not forward:
        return _empty()
    index_a = np.fromiter(forward.keys(), dtype=np.intp, count=len(forward))
    values = np.array(list(forward.values()))
    return Matches(index_a, values[:, 0].astype(np.intp), values[:, 1].astype(np.float32))


def descriptor_distances(desc_a: np.ndarray, desc_b: np.ndarray, binary: bool) -> NDArray[np.float32]:
    """Row-wise distances between two equally long descriptor arrays (Hamming or L2)."""
    if binary:
        xor = np.bitwise_xor(desc_a, desc_b)
        if hasattr(np, "bitwise_count") and xor.shape[1] % 8 == 0:
            words = np.ascontiguousarray(xor).view(np.uint64)
            return np.bitwise_count(words).sum(axis=1, dtype=np.int32).astype(np.float32)
        return _POPCOUNT[xor].sum(axis=1, dtype=np.int32).astype(np.float32)
    diff = desc_a.astype(np.float32) - desc_b.astype(np.float32)
    return np.sqrt(np.einsum("ij,ij->i", diff, diff)).astype(np.float32)


def match_in_band(
    points_left: NDArray[np.float32], desc_left: np.ndarray,
    points_right: NDArray[np.float32], desc_right: np.ndarray, binary: bool,
    band_px: float, min_disparity_px: float, max_disparity_px: float, ratio: float,
) -> Matches:
    """Stereo matches on a rectified pair, searching only the epipolar band.

    A left keypoint at (u, v) is compared only with right keypoints whose row
    differs by at most ``band_px`` and whose disparity ``u - u_right`` lies in
    ``[min_disparity_px, max_disparity_px]``. This is both the thesis's epipolar
    filter and a large speed-up over matching all pairs. The ratio test is applied
    among the band's candidates, and each right keypoint keeps only its best left match.
    """
    if len(points_left) == 0 or len(points_right) == 0:
        return _empty()
    order = np.argsort(points_right[:, 1], kind="stable")
    right_rows = points_right[order, 1]
    lo = np.searchsorted(right_rows, points_left[:, 1] - band_px, side="left")
    hi = np.searchsorted(right_rows, points_left[:, 1] + band_px, side="right")
    counts = hi - lo
    total = int(counts.sum())
    if total == 0:
        return _empty()
    left_index = np.repeat(np.arange(len(points_left)), counts)
    offsets = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    right_index = order[np.repeat(lo, counts) + offsets]
    disparity = points_left[left_index, 0] - points_right[right_index, 0]
    keep = (disparity >= min_disparity_px) & (disparity <= max_disparity_px)
    left_index, right_index = left_index[keep], right_index[keep]
    if left_index.size == 0:
        return _empty()
    distance = descriptor_distances(desc_left[left_index], desc_right[right_index], binary)
    # candidates are grouped by left keypoint (np.repeat keeps them contiguous): reduce per group
    starts = np.r_[0, np.flatnonzero(np.diff(left_index)) + 1]
    best = np.minimum.reduceat(distance, starts)
    group = np.repeat(np.arange(starts.size), np.diff(np.r_[starts, left_index.size]))
    is_best = distance == best[group]
    # position of the first minimum in each group
    best_position = np.full(starts.size, -1, dtype=np.intp)
    candidates = np.flatnonzero(is_best)
    best_position[group[candidates][::-1]] = candidates[::-1]
    without_best = distance.astype(np.float32).copy()
    without_best[best_position] = np.inf
    second = np.minimum.reduceat(without_best, starts)
    passed = best < ratio * second
    chosen = best_position[passed]
    result_left, result_right, result_dist = left_index[chosen], right_index[chosen], best[passed]
    # a right keypoint may be claimed by one left keypoint only: keep the closest
    unique_order = np.lexsort((result_dist, result_right))
    first = np.r_[True, np.diff(result_right[unique_order]) != 0]
    final = unique_order[first]
    return Matches(result_left[final], result_right[final], result_dist[final])

"""The detectors' fast kernels give exactly what the plain NumPy and OpenCV calls they replace give.

Each kernel was written for speed (``benchmarks/detect.py``'s timing): medians of 8-bit values by a counting
sort, the ground's geometry kept between frames, a colour mask's blobs labelled in the box that holds them, small
medians and quartiles without NumPy's overhead. None may move a detection; these tests hold each to the call it
stands for, on random values and on the edge cases (even counts whose median falls between two values, empty
masks, blobs at odd rows and columns).
"""

from __future__ import annotations

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from kartpilot.perception.colour import mask_components
from kartpilot.perception.obstacles import _leading_run, _lower_quartile, _median, _road_spread
from kartpilot.perception.road_marks import _row_middle_sum, medians_u8


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 64), rows=st.integers(1, 6))
def test_medians_of_bytes_are_numpy_medians(seed: int, n: int, rows: int) -> None:
    values = np.random.default_rng(seed).integers(0, 256, (rows, 3, n), dtype=np.uint8)
    got = medians_u8(values)
    assert got.dtype == np.float32
    assert np.array_equal(got, np.median(values.astype(np.float32), axis=-1))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 40))
def test_row_medians_of_the_inside_values_are_nanmedians(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    values = rng.integers(0, 256, (7, n)).astype(np.uint16)
    inside = rng.random((7, n)) < 0.6
    inside[:, 0] = True  # each row holds some
    twice = _row_middle_sum(np.where(inside, values, 256), inside)
    assert np.array_equal(twice / 2, np.nanmedian(np.where(inside, values.astype(np.float64), np.nan), axis=1))


def test_the_road_spread_is_the_float_statistics() -> None:
    """Twice the median is whole: a median of 97.5 (an even count's two middle values) must not be taken as 97."""
    rng = np.random.default_rng(3)
    for _ in range(40):
        lab = rng.integers(80, 140, (60, 90, 3), dtype=np.uint8)
        lab[48:, 31:58, 0] = rng.choice([97, 98], (12, 27))  # a median between two values in the road patch
        patch = lab[48:, 31:58].reshape(-1, 3).astype(np.float32)
        mad = np.median(np.abs(patch - np.median(patch, axis=0)), axis=0)
        assert np.array_equal(_road_spread(lab, 60, 90), np.maximum(1.4826 * mad, 2.0))


@settings(max_examples=80, deadline=None)
@given(values=st.lists(st.integers(-50, 250), min_size=1, max_size=40))
def test_the_small_median_and_quartile_are_numpy_s(values: list[int]) -> None:
    floats = [float(v) for v in values]
    assert _median(floats) == float(np.median(floats))
    assert _lower_quartile(floats) == float(np.percentile(floats, 25))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), share=st.floats(0.0, 1.0))
def test_the_leading_run_is_the_cumulative_product(seed: int, share: float) -> None:
    mask = np.random.default_rng(seed).random((30, 17)) < share
    assert np.array_equal(_leading_run(mask), np.cumprod(mask, axis=0).sum(axis=0))


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), blobs=st.integers(0, 6))
def test_blobs_labelled_in_their_box_are_the_whole_mask_s(seed: int, blobs: int) -> None:
    """The same components, numbered alike, with the same statistics once the box's corner is added, wherever the
    blobs lie (at odd rows and columns too), and none in an empty mask."""
    rng = np.random.default_rng(seed)
    mask = np.zeros((61, 87), np.uint8)
    for _ in range(blobs):
        x, y = int(rng.integers(0, 80)), int(rng.integers(0, 55))
        mask[y:y + int(rng.integers(1, 7)), x:x + int(rng.integers(1, 8))] = 255
        mask[rng.random(mask.shape) < 0.002] = 255  # specks
    count, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_BBDT)
    got_count, got_labels, got_stats, (x0, y0) = mask_components(mask)
    assert got_count == count
    if count == 1:
        return
    h, w = got_labels.shape
    assert np.array_equal(labels[y0:y0 + h, x0:x0 + w], got_labels)
    assert np.count_nonzero(labels) == np.count_nonzero(got_labels)
    assert np.array_equal(got_stats[1:, :2] + (x0, y0), stats[1:, :2])
    assert np.array_equal(got_stats[1:, 2:], stats[1:, 2:])

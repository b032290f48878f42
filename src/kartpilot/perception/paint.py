"""Painted boundaries as curves on the ground: the lane finder for real road paint seen from a low kart camera.

The thesis's centre-camera pipeline (Canny, Hough, slope filters; :mod:`kartpilot.perception.lanes`) finds
straight edges. On the real SDC kart's camera at the venue, 60 cm or less above the asphalt, the white lines of
an S-bend are curves that leave the image through its sides, and the Hough filters keep none of them. This
finder looks for *paint*, not edges, and fits *curves*, not lines:

1. **Whiteness.** Paint is white: all three channels are bright. The darkest channel of each pixel keeps the
   white paint and drops what is coloured however bright it is (a red barrier, the kart's red frame, grass).
2. **Ridges.** A boundary line is a bright stripe narrower than the asphalt around it. A morphological white
   top-hat along the rows keeps structures narrower than its kernel; the kernel grows with the distance below
   the horizon, as a stripe of fixed width on the ground does (its width in pixels is proportional to the row's
   distance from the horizon). Wide bright things (a stop line across the lane, a car, a crosswalk bar) are
   wider than the kernel and drop out. The top-hat runs in a few bands of rows, each with the kernel of its
   nearest row, which at the band's far rows is wider than those rows' own: what passed there wider than its
   own row's kernel is dropped too (a zebra's bars, 0.5 m wide and running along the road as a boundary does,
   passed whole and were taken for the lane's boundaries by a kart moving off just before the crossing).
3. **Threshold from the image itself.** A pixel is paint when its ridge response stands out from the asphalt's
   texture: more than ``noise_sigmas`` robust standard deviations (from the median absolute deviation) above the
   region's median, and at least ``min_contrast`` grey levels. Nothing is fitted to one image's brightness.
4. **Strokes.** Connected pieces of paint; compact blobs (a calibration board's squares, gravel glints) are not
   strokes: a stroke is long for its area.
5. **Curves on the ground.** A boundary on a flat ground, ``lateral = k0 + k1 d + k2 d^2`` at distance ``d``
   ahead, appears in the image of a level camera as ``x(y) = a + b (y - y_h) + c / (y - y_h)`` with ``y_h`` the
   horizon's row: three coefficients, linear in the pixels, exact for a parabola on the ground (Kluge's model).
   Each side's boundary is the stroke nearest the kart on that side, where the stroke comes nearest (``x - cx``
   over ``y - y_h`` is the lateral offset over the camera's height), and passing beside the camera, not under it
   (``min_lateral_ratio``: upright things such as a barrier's stripes are vertical in the image, which as a
   ground line would run beneath the camera); strokes that lie on its curve join it (the
   dashes of a centre line, a line broken by wear); the curve is fitted to all of them by least squares with
   outliers dropped.
6. **Confidence** is the share of the rows, between the nearest and the farthest row where the curve lies inside
   the image, that paint supports; both sides' shares averaged. A curve crossing its twin within the image is
   dropped, the weaker first.

The curves are reported in input pixels so a boundary can be checked at any row (:meth:`LaneCurve.x_at`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.core.types import Image

__all__ = ["LaneCurve", "PaintConfig", "PaintStrokes", "find_paint_curves", "fit_curve", "paint_mask"]


@dataclass(frozen=True)
class PaintConfig:
    """Attributes:
        horizon: the horizon's row as a fraction of the height (from the camera's mount; the real SDC kart's
            centre camera: 0.34, from its ground calibration).
        top_margin: the region starts this fraction of the height below the horizon (far paint is too thin).
        paint_width_ratio: a line's width over the camera's height above the ground (a 0.12 m line seen from
            0.55 m: 0.22); sets the ridge kernel, with ``kernel_factor`` of slack.
        kernel_factor: the ridge kernel's width over the expected width of a line at that row.
        bands: how many bands of rows, each with its own kernel.
        noise_sigmas, min_contrast: the ridge threshold (robust sigmas above the median; a grey-level floor).
        min_stroke_px: the least pixels of a stroke (at the processing scale).
        min_elongation: a stroke's bounding box's longer side squared over its area (1 for a square).
        join_px: a stroke joins a side's curve when its points lie within this fraction of the width of it.
        min_rows: the fewest rows (fraction of the region's height) a side's curve must span.
        min_lateral_ratio: a boundary passes beside the camera, not under it: where the curve passes the
            camera, its lateral offset over the camera's height (``-b`` on the left, ``b`` on the right, for a level
            camera) is at least this. Upright things standing on the ground (a barrier's white stripes, a post)
            are vertical in the image, which as ground lines would run under the camera (``b`` near 0).
    """

    horizon: float = 0.34
    top_margin: float = 0.035
    paint_width_ratio: float = 0.22
    kernel_factor: float = 3.0
    bands: int = 4
    noise_sigmas: float = 5.0
    min_contrast: float = 18.0
    min_stroke_px: int = 12
    min_elongation: float = 3.0
    join_px: float = 0.025
    min_rows: float = 0.06
    min_lateral_ratio: float = 0.25


@dataclass(frozen=True)
class LaneCurve:
    """A boundary ``x(y) = a + b (y - horizon_y) + c / (y - horizon_y)`` in input pixels, seen from row
    ``y_far`` to ``y_near`` (extrapolated outside them, as the ground model says)."""

    a: float
    b: float
    c: float
    horizon_y: float
    y_far: float
    y_near: float
    support: float

    def x_at(self, y: float | NDArray[np.float64]) -> NDArray[np.float64] | float:
        dy = np.maximum(np.asarray(y, dtype=np.float64) - self.horizon_y, 1e-3)
        x = self.a + self.b * dy + self.c / dy
        return float(x) if np.ndim(x) == 0 else x


@dataclass
class PaintStrokes:
    """Intermediate results (filled when asked for): the paint mask of the region and its rows' offset."""

    mask: Image | None = None
    top_px: int = 0
    scale: float = 1.0


def _kernel_px(rows: NDArray[np.float64] | float, top: int, horizon: float, scale: float, config: PaintConfig
               ) -> NDArray[np.float64] | float:
    """The ridge kernel's width (processing pixels) at processing ``rows`` of the region starting at ``top``: a
    line's width there, with ``kernel_factor`` of slack."""
    below = (top + rows) / scale - horizon  # in input pixels below the horizon
    return config.kernel_factor * config.paint_width_ratio * below * scale


def _kernel_widths(rows: int, top: int, horizon: float, scale: float, config: PaintConfig
                   ) -> list[tuple[int, int, int]]:
    """(first row, last row, kernel) of each band, in processing pixels: each band's kernel its nearest row's."""
    edges = np.linspace(0, rows, config.bands + 1).astype(int)
    out = []
    for r0, r1 in itertools.pairwise(edges):
        k = round(float(_kernel_px(float(r1), top, horizon, scale, config))) | 1
        out.append((int(r0), int(r1), max(k, 3)))
    return out


def paint_mask(image: Image, top: int, horizon_y: float, scale: float, config: PaintConfig,
               mask: Image | None = None) -> Image:
    """A uint8 mask of paint pixels in ``image[top:]`` at ``scale`` (255 paint); ``mask`` (input size,
    non-zero where the kart's body is) is excluded."""
    region = image[top:]
    if region.ndim == 3:
        b, g, r = cv2.split(region)
        white = cv2.min(cv2.min(b, g), r)
    else:
        white = region
    small = white if scale == 1.0 else cv2.resize(white, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    ridge = np.empty_like(small)
    top_small = round(top * scale)
    for r0, r1, k in _kernel_widths(small.shape[0], top_small, horizon_y, scale, config):
        lo, hi = max(r0 - 2, 0), min(r1 + 2, small.shape[0])
        kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (k, 1))
        ridge[r0:r1] = cv2.morphologyEx(small[lo:hi], cv2.MORPH_TOPHAT, kernel)[r0 - lo:r0 - lo + r1 - r0]
    sample = ridge[::2, ::2]
    median = float(np.median(sample))
    mad = float(np.median(np.abs(sample.astype(np.float32) - median)))
    threshold = max(median + config.noise_sigmas * 1.4826 * max(mad, 1.0), config.min_contrast)
    out = np.where(ridge > threshold, np.uint8(255), np.uint8(0))
    _drop_wide_runs(out, np.asarray(_kernel_px(np.arange(out.shape[0]) + 0.5, top_small, horizon_y, scale, config)))
    if mask is not None:
        body = mask[top:]
        if scale != 1.0:
            body = cv2.resize(body, (out.shape[1], out.shape[0]), interpolation=cv2.INTER_NEAREST)
        out[body > 0] = 0
    return out


def _drop_wide_runs(mask: Image, widths: NDArray[np.float64]) -> None:
    """Clear, in place, each run of set pixels along a row of ``mask`` longer than that row's ``widths``."""
    h, w = mask.shape
    padded = np.zeros((h, w + 2), np.int8)
    padded[:, 1:-1] = mask > 0
    steps = np.diff(padded, axis=1).ravel()  # h rows of w + 1: +1 where a run starts, -1 just past its end
    starts, ends = np.flatnonzero(steps == 1), np.flatnonzero(steps == -1)
    wide = ends - starts > widths[starts // (w + 1)]
    if wide.any():  # a step is one run's start or another's end, never both: plain indexing marks them
        delta = np.zeros(steps.size, np.int32)
        delta[starts[wide]], delta[ends[wide]] = 1, -1
        mask[np.cumsum(delta).reshape(h, w + 1)[:, :w] > 0] = 0


def fit_curve(xs: NDArray[np.float64], ys: NDArray[np.float64], horizon_y: float) -> NDArray[np.float64] | None:
    """(a, b, c) of ``x = a + b (y - h) + c / (y - h)`` by least squares. Points over too short a stretch of
    rows to tell a bend from a slope get a straight line (c = 0): a curve through them would be noise."""
    dy = ys - horizon_y
    if len(xs) < 3 or np.any(dy <= 0):
        return None
    curved = len(np.unique(np.round(ys))) >= 8 and float(np.ptp(dy)) > _CURVE_SPAN * float(dy.max())
    columns = [np.ones_like(dy), dy] + ([1.0 / dy] if curved else [])
    design = np.column_stack(columns)
    coef = np.linalg.lstsq(design, xs, rcond=None)[0].astype(np.float64)
    return np.r_[coef, 0.0] if not curved else coef


_CURVE_SPAN = 0.35  # the least span of rows, over the nearest row's distance below the horizon, for a curve


def _eval(coef: NDArray[np.float64], ys: NDArray[np.float64], horizon_y: float) -> NDArray[np.float64]:
    dy = np.maximum(ys - horizon_y, 1e-3)
    return coef[0] + coef[1] * dy + coef[2] / dy


@dataclass
class _Stroke:
    xs: NDArray[np.float64]
    ys: NDArray[np.float64]
    coef: NDArray[np.float64]


def _strokes(mask: Image, top: int, scale: float, horizon_y: float, config: PaintConfig) -> list[_Stroke]:
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=4)
    if count <= 1:
        return []
    area = stats[1:, cv2.CC_STAT_AREA].astype(np.float64)
    longest = np.maximum(stats[1:, cv2.CC_STAT_WIDTH], stats[1:, cv2.CC_STAT_HEIGHT]).astype(np.float64)
    tall = stats[1:, cv2.CC_STAT_HEIGHT] >= 3
    keep = np.flatnonzero((area >= config.min_stroke_px) & (longest ** 2 / area >= config.min_elongation) & tall) + 1
    if len(keep) == 0:
        return []
    rows, cols = np.nonzero(np.isin(labels, keep))
    which = labels[rows, cols]
    order = np.argsort(which, kind="stable")
    rows, cols, which = rows[order], cols[order], which[order]
    starts = np.searchsorted(which, keep)
    ends = np.searchsorted(which, keep, side="right")
    out = []
    for s, e in zip(starts, ends, strict=True):
        # one point per row: the stroke's middle in that row (paint is a stripe; its centre is the boundary)
        r, c = rows[s:e], cols[s:e].astype(np.float64)
        uniq, inverse = np.unique(r, return_inverse=True)
        mid = np.bincount(inverse, weights=c) / np.bincount(inverse)
        ys = ((uniq + 0.5) / scale - 0.5 + top).astype(np.float64)
        xs = ((mid + 0.5) / scale - 0.5).astype(np.float64)
        coef = fit_curve(xs, ys, horizon_y)
        if coef is not None:
            out.append(_Stroke(xs, ys, coef))
    return out


def _grow(seed: _Stroke, others: list[_Stroke], horizon_y: float, tolerance: float
          ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    xs, ys, coef = seed.xs, seed.ys, seed.coef
    pending = [s for s in others if s is not seed]
    while pending:
        # the stroke nearest the curve's rows next: a dash at a time, so a short dash's fit is extended
        # by its neighbour before it reaches the far ones; the farther it extrapolates, the looser the test
        lo, hi = ys.min(), ys.max()
        gaps = [max(lo - s.ys.max(), s.ys.min() - hi, 0.0) for s in pending]
        k = int(np.argmin(gaps))
        other = pending.pop(k)
        loose = tolerance * (1.0 + gaps[k] / max(hi - lo, 1.0))
        if np.median(np.abs(_eval(coef, other.ys, horizon_y) - other.xs)) >= loose:
            continue
        # the joined curve must still pass through both: a far stroke that only bends the fit stays out
        jx, jy = np.r_[xs, other.xs], np.r_[ys, other.ys]
        refit = fit_curve(jx, jy, horizon_y)
        if refit is None:
            continue
        residual = np.abs(_eval(refit, jy, horizon_y) - jx)
        if np.percentile(residual, 90) < tolerance:
            xs, ys, coef = jx, jy, refit
    for _ in range(2):  # drop the points far from the curve and fit again
        residual = np.abs(_eval(coef, ys, horizon_y) - xs)
        inliers = residual < max(tolerance, 2.5 * float(np.median(residual)))
        if inliers.sum() < 3:
            break
        refit = fit_curve(xs[inliers], ys[inliers], horizon_y)
        if refit is None:
            break
        xs, ys, coef = xs[inliers], ys[inliers], refit
    return xs, ys, coef


def _support(coef: NDArray[np.float64], ys: NDArray[np.float64], width: int, height: int, top: int,
             horizon_y: float, row_step: float) -> tuple[float, float, float]:
    """(share of the in-image rows that paint supports, nearest row seen, farthest row seen)."""
    grid = np.arange(top, height, row_step, dtype=np.float64)
    xg = _eval(coef, grid, horizon_y)
    inside = (xg >= 0) & (xg <= width - 1)
    if not inside.any():
        return 0.0, float(ys.max()), float(ys.min())
    seen = np.zeros(len(grid), bool)
    seen[np.clip(((ys - top) / row_step).astype(int), 0, len(grid) - 1)] = True
    share = float((seen & inside).sum() / inside.sum())
    return min(share, 1.0), float(ys.max()), float(ys.min())


def find_paint_curves(image: Image, config: PaintConfig, scale: float, mask: Image | None = None,
                      stages: PaintStrokes | None = None) -> tuple[LaneCurve | None, LaneCurve | None, int]:
    """The ego lane's left and right boundaries as curves (None where not found), and the region's top row."""
    h, w = image.shape[:2]
    horizon_y = config.horizon * h
    top = min(int(np.ceil(horizon_y + config.top_margin * h)), h - 8)
    paint = paint_mask(image, top, horizon_y, scale, config, mask)
    if stages is not None:
        stages.mask, stages.top_px, stages.scale = paint, top, scale
    strokes = _strokes(paint, top, scale, horizon_y, config)
    cx, bottom = (w - 1) / 2.0, h - 1.0
    tolerance = config.join_px * w
    min_span = config.min_rows * (h - top)
    row_step = max(1.0 / scale, 1.0)
    found: dict[str, LaneCurve] = {}
    for side, sign in (("left", -1.0), ("right", 1.0)):
        # the strokes on this side, nearest the kart first: the lateral offset (over the camera's height) where
        # each stroke comes nearest, from its own pixels there; a far stroke's curve extrapolated to the bottom
        # row can land anywhere (the far end of the right line, cut off by a barrier, looked nearest on the left)
        offsets = [sign * (float(s.xs[np.argmax(s.ys)]) - cx) / max(float(s.ys.max()) - horizon_y, 1.0)
                   for s in strokes]
        candidates = [s for _, s in sorted(((o, s) for o, s in zip(offsets, strokes, strict=True)
                                            if o > 0 and sign * s.coef[1] >= config.min_lateral_ratio),
                                           key=lambda pair: pair[0])]
        for seed in candidates:
            _, ys, coef = _grow(seed, candidates, horizon_y, tolerance)
            if (np.ptp(ys) < min_span or sign * (_eval(coef, np.array([bottom]), horizon_y)[0] - cx) <= 0
                    or sign * coef[1] < config.min_lateral_ratio):
                continue
            share, near, far = _support(coef, ys, w, h, top, horizon_y, row_step)
            found[side] = LaneCurve(float(coef[0]), float(coef[1]), float(coef[2]), horizon_y, far, near, share)
            break
    left, right = found.get("left"), found.get("right")
    if left is not None and right is not None:
        # where both are seen, the left boundary lies left of the right one
        grid = np.arange(max(left.y_far, right.y_far), h, 2.0)
        if len(grid) and np.any(np.asarray(left.x_at(grid)) >= np.asarray(right.x_at(grid))):
            if left.support >= right.support:
                right = None
            else:
                left = None
    return left, right, top

"""Lane-boundary detection: the thesis's centre-camera pipeline, stage by stage, as pure functions.

grayscale -> Gaussian blur -> Canny -> region of interest -> Hough lines (probabilistic or standard)
-> position filter (a left candidate must lie mostly in the left half, and vice versa)
-> slope and intercept thresholds -> left/right by the sign of the slope
-> clustering (keep lines whose intercept is beyond the side's mean: the inner ones, which drops road
   edges and the bases of tyre walls) -> merge each side into one line.

Merging fits one line x(y) through the survivors' end points weighted by their length (the thesis
averaged the end points; the fit is the same for agreeing segments and less swayed by a short stray).
A side with no line is replaced by the image's extreme column on that side (the thesis's rule for
wide turns) and flagged as such. Processing runs on the region of interest only, optionally
downscaled; the lines are returned in pixels of the input image.

``method: paint`` replaces the edge-and-Hough stages with :mod:`kartpilot.perception.paint`: white paint found
as ridges and fitted as curves on the ground, for real painted lines seen from a low kart camera (the real SDC
kart's cameras at the venue, where the Hough stages find no boundary). Both report the same observation; the
paint method also reports each boundary as a curve that can be read at any row.

Image coordinates: x right, y down, origin at the top-left pixel centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.calibration.ground import ground_points
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import PerceptionError
from kartpilot.core.geometry import invert_pose, transform_points
from kartpilot.core.types import Image
from kartpilot.perception.paint import LaneCurve, PaintConfig, PaintStrokes, find_paint_curves

__all__ = [
    "LaneConfig",
    "LaneCurve",
    "LaneLine",
    "LaneObservation",
    "LaneStages",
    "SideObservation",
    "SideSearchConfig",
    "detect_lanes",
    "detect_side_boundary",
    "draw_lanes",
    "heading_deviation_rad",
    "intersection",
    "lane_on_ground",
]

Source = Literal["detected", "extreme", "none"]
Segments = NDArray[np.float64]  # (N, 4): x1, y1, x2, y2 in input pixels


@dataclass(frozen=True)
class LaneConfig:
    """Centre-camera lane finding. Fractions are of the image width or height, so one config serves
    several resolutions.

    Attributes:
        roi_top, roi_top_width, roi_bottom_width: the trapezoidal region of interest: its top edge (as a
            fraction of the height) and the widths of its top and bottom edges (fractions of the width).
        process_scale: resolution at which the region is processed (1 = full).
        blur_px: Gaussian kernel size at the processing scale (odd).
        canny_low, canny_high: Canny thresholds; with ``auto_canny`` they are scaled by the region's
            median grey level over 128, which keeps the edge count steady when the exposure changes.
        hough: ``probabilistic`` (segments) or ``standard`` (infinite lines clipped to the region).
        min_abs_slope, max_abs_slope: |dy/dx| kept (drops near-horizontal and near-vertical lines).
        max_top_offset: intercept threshold: a line extended to the region's top must pass within this
            fraction of the width of the centre column (boundaries converge toward the vanishing point).
        centre_tolerance: how far past the middle a side's line may reach at its midpoint, as a fraction
            of the width (the thesis: a third of a boundary lies in its own half unless the kart is off track).
        cluster: keep only the lines with an intercept beyond the side's mean (the thesis's clustering).
        min_brightness_contrast: a boundary must be this many grey levels brighter than the region's median
            beside it (paint is; tyre marks, shadows and barrier bases are darker). 0: off, as in the thesis.
        paint: ``dark`` for dark tape on a light floor (the check then wants darker lines).
        yellow_boost: add this times max(0, min(R, G) - B) to the grey level, so yellow paint stands out on
            light concrete where plain grey has no contrast (0: plain grayscale, as in the thesis).
        method: ``hough`` (the thesis's edges and straight lines; the settings above) or ``paint`` (white paint
            as curves, :mod:`kartpilot.perception.paint`; ``paint`` holds its settings, and ``process_scale``
            applies to both).
        aim_below_horizon: ``paint``: the row the follower aims at, as a fraction of the way from the horizon
            down to the bottom row (0.35: about 4 m ahead of the real kart's camera). Each boundary is reported
            as its chord from the bottom row to this row, and the aim is the lane's centre there; the thesis's
            aim, the meeting point of the two lines, lies at the horizon, where a curve's bend is exaggerated
            and the kart cuts into the bend before it starts (the venue's 10 m S-bend in the simulator).
            0: the region's top and the chords' meeting point.
    """

    roi_top: float = 0.58
    roi_top_width: float = 0.30
    roi_bottom_width: float = 1.0
    process_scale: float = 0.5
    blur_px: int = 5
    canny_low: float = 50.0
    canny_high: float = 150.0
    auto_canny: bool = True
    hough: Literal["probabilistic", "standard"] = "probabilistic"
    hough_threshold: int = 15
    min_line_length: float = 0.03
    max_line_gap: float = 0.02
    min_abs_slope: float = 0.35
    max_abs_slope: float = 6.0
    max_top_offset: float = 0.3
    centre_tolerance: float = 0.05
    cluster: bool = True
    yellow_boost: float = 1.0
    min_brightness_contrast: float = 30.0
    paint: Literal["bright", "dark"] = "bright"
    method: Literal["hough", "paint"] = "hough"
    curves: PaintConfig = field(default_factory=PaintConfig)
    aim_below_horizon: float = 0.35

    def __post_init__(self) -> None:
        if not 0.0 <= self.roi_top < 1.0:
            raise ValueError("roi_top must be in [0, 1)")
        if not 0.0 <= self.aim_below_horizon < 1.0:
            raise ValueError("aim_below_horizon must be in [0, 1)")
        if not 0.05 <= self.process_scale <= 1.0:
            raise ValueError("process_scale must be in [0.05, 1]")


@dataclass(frozen=True)
class LaneLine:
    """A boundary as a segment from the bottom of the region (x_bottom, y_bottom) to its top."""

    x_bottom: float
    y_bottom: float
    x_top: float
    y_top: float

    def x_at(self, y: float) -> float:
        if abs(self.y_bottom - self.y_top) < 1e-9:
            return self.x_bottom
        t = (y - self.y_bottom) / (self.y_top - self.y_bottom)
        return self.x_bottom + t * (self.x_top - self.x_bottom)

    def as_tuple(self) -> tuple[float, float, float, float]:
        return self.x_bottom, self.y_bottom, self.x_top, self.y_top


@dataclass(frozen=True)
class LaneObservation:
    """One frame's result.

    Attributes:
        left, right: the boundaries (the image's extreme column when ``*_source`` is ``extreme``).
        intersection_px: the point the follower aims at: where the two boundaries meet, or None if parallel;
            for curves (``paint``) with both boundaries found, the lane's centre at the aim row.
        confidence: 0 to 1, from how much line length supports each detected side (``paint``: the share of
            the rows where each boundary lies in the image that paint supports).
        left_curve, right_curve: the boundaries as curves (``method: paint``; None otherwise or where not found).
    """

    width_px: int
    height_px: int
    left: LaneLine
    right: LaneLine
    left_source: Source
    right_source: Source
    intersection_px: tuple[float, float] | None
    confidence: float
    left_curve: LaneCurve | None = None
    right_curve: LaneCurve | None = None

    @property
    def any_detected(self) -> bool:
        return "detected" in (self.left_source, self.right_source)

    @property
    def both_detected(self) -> bool:
        return self.left_source == "detected" and self.right_source == "detected"


@dataclass
class LaneStages:
    """Intermediate results, for the thesis's figures 11 and 12 (filled when asked for)."""

    edges: Image | None = None
    raw: Segments = field(default_factory=lambda: np.zeros((0, 4)))
    after_position: Segments = field(default_factory=lambda: np.zeros((0, 4)))
    after_slope: Segments = field(default_factory=lambda: np.zeros((0, 4)))
    left_cluster: Segments = field(default_factory=lambda: np.zeros((0, 4)))
    right_cluster: Segments = field(default_factory=lambda: np.zeros((0, 4)))
    paint: PaintStrokes | None = None


def detect_lanes(image: Image, config: LaneConfig = LaneConfig(), stages: LaneStages | None = None,
                 body_mask: Image | None = None) -> LaneObservation:
    """Find the ego lane's left and right boundaries in a centre-camera image (BGR or gray).

    ``body_mask`` (the image's size, non-zero on the kart's own body) is left out of the search.
    """
    if image is None or image.size == 0:
        raise PerceptionError("empty image")
    if body_mask is not None and body_mask.shape[:2] != image.shape[:2]:
        raise PerceptionError(f"the body mask is {body_mask.shape[1]}x{body_mask.shape[0]}, the image "
                              f"{image.shape[1]}x{image.shape[0]}")
    if config.method == "paint":
        return _detect_paint(image, config, stages, body_mask)
    h, w = image.shape[:2]
    top = round(config.roi_top * h)
    region = _lane_gray(image[top:], config.yellow_boost)  # only the region of interest is converted
    segments, edges, median = _hough_segments(region, config, w, top, None if body_mask is None else body_mask[top:])
    if stages is not None:
        stages.edges = edges
        stages.raw = segments
    segments = _inside_roi(segments, config, w, h)
    left, right = _split_by_position(segments, w, config.centre_tolerance)
    if stages is not None:
        stages.after_position = np.vstack([left, right])
    left, right = _slope_filter(left, config, w, top), _slope_filter(right, config, w, top)
    left, right = _longest(left, _MAX_SEGMENTS), _longest(right, _MAX_SEGMENTS)
    if config.min_brightness_contrast > 0:
        sign = 1.0 if config.paint == "bright" else -1.0
        floor = sign * median + config.min_brightness_contrast
        left, right = _painted(region, left, floor, sign, top), _painted(region, right, floor, sign, top)
    if stages is not None:
        stages.after_slope = np.vstack([left, right])
    if config.cluster:
        left, right = _cluster(left, "left"), _cluster(right, "right")
    if stages is not None:
        stages.left_cluster, stages.right_cluster = left, right
    y_top, y_bottom = float(top), float(h - 1)
    left_line, right_line = _merge(left, y_bottom, y_top, w), _merge(right, y_bottom, y_top, w)
    left_source: Source = "detected" if left_line is not None else "extreme"
    right_source: Source = "detected" if right_line is not None else "extreme"
    if left_line is None:
        left_line = LaneLine(0.0, y_bottom, 0.0, y_top)
    if right_line is None:
        right_line = LaneLine(w - 1.0, y_bottom, w - 1.0, y_top)
    support = sum(min(1.0, _length(s).sum() / (0.6 * (h - top))) for s in (left, right)) / 2
    return LaneObservation(w, h, left_line, right_line, left_source, right_source,
                           intersection(left_line, right_line), float(support))


def _detect_paint(image: Image, config: LaneConfig, stages: LaneStages | None, body_mask: Image | None
                  ) -> LaneObservation:
    h, w = image.shape[:2]
    if body_mask is not None and body_mask.shape[:2] != (h, w):
        raise PerceptionError(f"the body mask is {body_mask.shape[1]}x{body_mask.shape[0]}, the image {w}x{h}")
    paint_stages = PaintStrokes() if stages is not None else None
    left, right, top = find_paint_curves(image, config.curves, config.process_scale, body_mask, paint_stages)
    if stages is not None:
        stages.paint = paint_stages
    horizon_y = config.curves.horizon * h
    y_aim = horizon_y + config.aim_below_horizon * (h - 1 - horizon_y)
    y_top, y_bottom = (max(float(top), y_aim) if config.aim_below_horizon > 0 else float(top)), float(h - 1)

    def chord(curve: LaneCurve | None, extreme: float) -> LaneLine:
        if curve is None:
            return LaneLine(extreme, y_bottom, extreme, y_top)
        return LaneLine(float(curve.x_at(y_bottom)), y_bottom, float(curve.x_at(y_top)), y_top)

    left_line, right_line = chord(left, 0.0), chord(right, w - 1.0)
    support = sum(c.support for c in (left, right) if c is not None) / 2
    aim = intersection(left_line, right_line)
    if left is not None and right is not None and config.aim_below_horizon > 0:
        aim = ((left_line.x_top + right_line.x_top) / 2, y_top)
    return LaneObservation(w, h, left_line, right_line, "detected" if left else "extreme",
                           "detected" if right else "extreme", aim, float(support), left, right)


def heading_deviation_rad(observation: LaneObservation, point: tuple[float, float] | None = None) -> float:
    """The thesis's equation 1: the angle between the image's vertical through its bottom centre and the
    ray to the boundaries' intersection (or ``point``), positive when it lies to the right."""
    target = point if point is not None else observation.intersection_px
    if target is None:
        return 0.0
    x1, y1 = (observation.width_px - 1) / 2, observation.height_px - 1.0
    x2, y2 = target
    return math.atan2(x2 - x1, max(y1 - y2, 1.0))


# --- side cameras -------------------------------------------------------------------------------

@dataclass(frozen=True)
class SideSearchConfig:
    """Off-track avoidance in a side camera.

    The region of search is a band of rows in which the boundary appears only when the kart is near it
    (computed from the camera's calibration by the caller). A line's crossing of the band's inner
    column, from the band's top (far) to its bottom (near), gives a steer away from 0 to 1.

    Attributes:
        min_brightness_contrast: a boundary line must be this many grey levels brighter than the band's
            median (painted lines are; tyre marks are darker than the tarmac, the thesis's false positives).
    """

    process_scale: float = 0.5
    blur_px: int = 5
    canny_low: float = 80.0
    canny_high: float = 200.0
    hough_threshold: int = 20
    min_line_length: float = 0.15
    max_line_gap: float = 0.03
    max_abs_slope: float = 1.2
    min_brightness_contrast: float = 25.0


@dataclass(frozen=True)
class SideObservation:
    steer: float
    line: tuple[float, float, float, float] | None


def detect_side_boundary(image: Image, band_rows: tuple[int, int], inner_column: int,
                         config: SideSearchConfig = SideSearchConfig(), body_mask: Image | None = None
                         ) -> SideObservation:
    """The proportional steer away from a boundary seen by a side camera (0 when none is in the band).

    Args:
        band_rows: (far_row, near_row) of the region of search; the near row is closer to the kart.
        inner_column: the column of the band's inner edge (the one toward the kart's front).
        body_mask: non-zero where the image shows the kart itself (the camera's ``body_mask``): its edges,
            and the outline where the body meets the ground, are not a boundary.
    """
    gray = _gray(image)
    h, w = gray.shape
    far, near = sorted(band_rows)
    far, near = max(0, far), min(h, near)
    if near - far < 4:
        raise PerceptionError(f"the side region of search {band_rows} is empty in a {w}x{h} image")
    if body_mask is not None and body_mask.shape[:2] != (h, w):
        raise PerceptionError(f"the body mask is {body_mask.shape[1]}x{body_mask.shape[0]}, the image {w}x{h}")
    scale = config.process_scale
    band = gray[far:near]
    small = band if scale == 1.0 else cv2.resize(band, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    edges = cv2.Canny(cv2.GaussianBlur(small, (config.blur_px, config.blur_px), 0), config.canny_low,
                      config.canny_high)
    if body_mask is not None:
        body = body_mask[far:near]
        if scale != 1.0:
            body = cv2.resize(body, (edges.shape[1], edges.shape[0]), interpolation=cv2.INTER_NEAREST)
        edges[cv2.dilate(body, np.ones((5, 5), np.uint8)) > 0] = 0
    found = cv2.HoughLinesP(edges, 1, np.pi / 180, config.hough_threshold,
                            minLineLength=config.min_line_length * w * scale,
                            maxLineGap=config.max_line_gap * w * scale)
    if found is None:
        return SideObservation(0.0, None)
    segs = _longest(found.reshape(-1, 4).astype(np.float64) / scale, _MAX_SEGMENTS)
    dx, dy = segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]
    segs = segs[np.abs(dy) <= config.max_abs_slope * np.abs(dx) + 1e-9]
    if len(segs) == 0:
        return SideObservation(0.0, None)
    median = float(np.median(small[::4, ::4]))  # a sparse sample is as good and four times cheaper
    bright = list(segs[_segment_brightness(band, segs) > median + config.min_brightness_contrast])
    if not bright:
        return SideObservation(0.0, None)
    # the nearest bright line at the inner column sets the steer
    rows = []
    for x1, y1, x2, y2 in bright:
        t = 0.0 if abs(x2 - x1) < 1e-9 else (inner_column - x1) / (x2 - x1)
        rows.append(y1 + t * (y2 - y1))
    k = int(np.argmax(rows))
    row = float(np.clip(rows[k], 0.0, near - far - 1.0))
    steer = row / max(near - far - 1.0, 1.0)
    x1, y1, x2, y2 = bright[k]
    return SideObservation(float(steer), (float(x1), float(y1 + far), float(x2), float(y2 + far)))


# --- drawing -----------------------------------------------------------------------------------

def draw_lanes(image: Image, observation: LaneObservation, steer_rad: float | None = None,
               stages: LaneStages | None = None) -> Image:
    """The input with the boundaries (green detected, orange extreme), their intersection and the steer."""
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    if stages is not None:
        for x1, y1, x2, y2 in stages.raw:
            cv2.line(canvas, (int(x1), int(y1)), (int(x2), int(y2)), (90, 90, 255), 1, cv2.LINE_AA)
        for x1, y1, x2, y2 in np.vstack([stages.left_cluster, stages.right_cluster]):
            cv2.line(canvas, (int(x1), int(y1)), (int(x2), int(y2)), (255, 200, 0), 2, cv2.LINE_AA)
    h, w = canvas.shape[:2]
    if stages is not None and stages.paint is not None and stages.paint.mask is not None:
        paint = stages.paint
        mask = cv2.resize(paint.mask, (w, h - paint.top_px), interpolation=cv2.INTER_NEAREST)
        canvas[paint.top_px:][mask > 0] = (255, 0, 255)
    for line, source, curve in ((observation.left, observation.left_source, observation.left_curve),
                                (observation.right, observation.right_source, observation.right_curve)):
        colour = (0, 220, 0) if source == "detected" else (0, 140, 255)
        if curve is not None:
            rows = np.arange(line.y_top, h, 2.0)
            points = np.column_stack([np.clip(curve.x_at(rows), -4 * w, 5 * w), rows])
            cv2.polylines(canvas, [np.round(points).astype(np.int32)], False, colour, 3, cv2.LINE_AA)
            continue
        cv2.line(canvas, (round(line.x_bottom), round(line.y_bottom)),
                 (round(line.x_top), round(line.y_top)), colour, 3, cv2.LINE_AA)
    base = (w // 2, h - 1)
    if observation.intersection_px is not None:
        x, y = observation.intersection_px
        if -w < x < 2 * w and -h < y < 2 * h:
            cv2.circle(canvas, (int(x), int(y)), 6, (0, 0, 255), -1)
            cv2.line(canvas, base, (int(x), int(y)), (0, 0, 255), 1, cv2.LINE_AA)
    if steer_rad is not None:
        text = f"steer {math.degrees(steer_rad):+.1f} deg  conf {observation.confidence:.2f}"
        cv2.putText(canvas, text, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(canvas, text, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 1, cv2.LINE_AA)
    return canvas


# --- stages ------------------------------------------------------------------------------------

def _gray(image: Image) -> Image:
    if image is None or image.size == 0:
        raise PerceptionError("empty image")
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image


def _lane_gray(image: Image, yellow_boost: float) -> Image:
    if image.ndim == 2 or yellow_boost <= 0:
        return _gray(image)
    blue, green, red = cv2.split(image)
    yellow = cv2.subtract(cv2.min(red, green), blue)
    return cv2.addWeighted(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), 1.0, yellow, yellow_boost, 0.0)


def _hough_segments(region: Image, config: LaneConfig, width: int, top: int, body: Image | None = None
                    ) -> tuple[Segments, Image, float]:
    """Segments in input pixels, the edge image, and the region's median grey level; no edges on ``body``
    (the region's part of the body mask)."""
    scale = config.process_scale
    small = region if scale == 1.0 else cv2.resize(region, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    k = config.blur_px | 1
    blurred = cv2.GaussianBlur(small, (k, k), 0)
    low, high = config.canny_low, config.canny_high
    median = float(np.median(blurred[::4, ::4]))
    if config.auto_canny:
        gain = max(median, 16.0) / 128.0
        low, high = low * gain, high * gain
    edges = cv2.Canny(blurred, low, high)
    if body is not None:
        if scale != 1.0:
            body = cv2.resize(body, (edges.shape[1], edges.shape[0]), interpolation=cv2.INTER_NEAREST)
        edges[cv2.dilate(body, np.ones((5, 5), np.uint8)) > 0] = 0
    w_small = small.shape[1]
    if config.hough == "probabilistic":
        found = cv2.HoughLinesP(edges, 1, np.pi / 180, config.hough_threshold,
                                minLineLength=config.min_line_length * w_small,
                                maxLineGap=config.max_line_gap * w_small)
        segs = np.zeros((0, 4)) if found is None else found.reshape(-1, 4).astype(np.float64)
    else:
        found = cv2.HoughLines(edges, 1, np.pi / 180, max(config.hough_threshold * 3, 1))
        segs = np.zeros((0, 4)) if found is None else _clip_infinite(found.reshape(-1, 2), small.shape)
    segs = segs / scale
    segs[:, [1, 3]] += top
    return segs, edges, median


def _clip_infinite(lines: NDArray[np.float32], shape: tuple[int, ...]) -> Segments:
    """Standard Hough (rho, theta) lines as segments across the region's height."""
    h = shape[0]
    out = []
    for rho, theta in lines[:20]:
        c, s = math.cos(theta), math.sin(theta)
        if abs(c) < 1e-6:
            continue  # horizontal
        out.append(((rho - 0 * s) / c, 0.0, (rho - (h - 1) * s) / c, h - 1.0))
    return np.asarray(out, np.float64).reshape(-1, 4)


def _inside_roi(segs: Segments, config: LaneConfig, w: int, h: int) -> Segments:
    """Keep segments whose midpoint lies in the trapezoid."""
    if len(segs) == 0:
        return segs
    top = config.roi_top * h
    mid_x, mid_y = (segs[:, 0] + segs[:, 2]) / 2, (segs[:, 1] + segs[:, 3]) / 2
    t = np.clip((mid_y - top) / max(h - 1 - top, 1.0), 0.0, 1.0)
    half = 0.5 * w * (config.roi_top_width + t * (config.roi_bottom_width - config.roi_top_width))
    return segs[np.abs(mid_x - (w - 1) / 2) <= half]


def _split_by_position(segs: Segments, w: int, tolerance: float) -> tuple[Segments, Segments]:
    """Left candidates slope up to the right (dy/dx < 0 with y down) and lie in the left half."""
    if len(segs) == 0:
        return segs, segs
    dx, dy = segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]
    slope_sign = np.sign(dx * dy)
    mid_x = (segs[:, 0] + segs[:, 2]) / 2
    centre, margin = (w - 1) / 2, tolerance * w
    left = segs[(slope_sign < 0) & (mid_x < centre + margin)]
    right = segs[(slope_sign > 0) & (mid_x > centre - margin)]
    return left, right


def _slope_filter(segs: Segments, config: LaneConfig, w: int, top: float) -> Segments:
    """Slope thresholds, then the intercept threshold at the region's top row."""
    if len(segs) == 0:
        return segs
    dx, dy = segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]
    slope = np.abs(dy) / np.maximum(np.abs(dx), 1e-9)
    segs = segs[(slope >= config.min_abs_slope) & (slope <= config.max_abs_slope)]
    if len(segs) == 0:
        return segs
    x_top = np.array([_x_at(seg, top) for seg in segs])
    return segs[np.abs(x_top - (w - 1) / 2) <= config.max_top_offset * w]


_MAX_SEGMENTS = 40  # per side: the longest ones carry the boundary; more only cost time


def _longest(segs: Segments, count: int) -> Segments:
    if len(segs) <= count:
        return segs
    return segs[np.argsort(-_length(segs))[:count]]


def _painted(region: Image, segs: Segments, floor: float, sign: float, top: int) -> Segments:
    """Segments beside which the region is brighter (sign 1) or darker (sign -1) than the floor."""
    if len(segs) == 0:
        return segs
    source = region if sign > 0 else cv2.bitwise_not(region)
    local = segs - np.array([0.0, top, 0.0, top])
    brightness = _segment_brightness(source, local)
    return segs[brightness > floor + (255.0 if sign < 0 else 0.0)]


def _segment_brightness(gray: Image, segs: Segments, samples: int = 16) -> NDArray[np.float64]:
    """Per segment, how bright the image is beside it: 3 px to either side, the brighter side's upper
    quartile (an edge lies between paint and tarmac; the quartile ignores the gaps of a dashed line)."""
    t = np.linspace(0.0, 1.0, samples)
    xs = segs[:, 0:1] + t * (segs[:, 2:3] - segs[:, 0:1])
    ys = segs[:, 1:2] + t * (segs[:, 3:4] - segs[:, 1:2])
    h, w = gray.shape[:2]
    cols = np.clip(np.rint(xs).astype(np.intp), 0, w - 1)
    sides = [np.percentile(gray[np.clip(np.rint(ys + d).astype(np.intp), 0, h - 1), cols], 75, axis=1)
             for d in (-3, 3)]
    return np.maximum(sides[0], sides[1])


def _cluster(segs: Segments, side: str) -> Segments:
    """The thesis's clustering: keep lines whose intercept is beyond the side's mean. Here the intercept
    is the line's column at the bottom of the image, and "beyond" means toward the lane (inner)."""
    if len(segs) < 3:
        return segs
    bottom_row = max(float(segs[:, [1, 3]].max()), 1.0)
    x_bottom = np.array([_x_at(s, bottom_row) for s in segs])
    weights = _length(segs)
    mean = float(np.average(x_bottom, weights=weights))
    keep = x_bottom >= mean if side == "left" else x_bottom <= mean
    return segs[keep]


def _merge(segs: Segments, y_bottom: float, y_top: float, width: int) -> LaneLine | None:
    """One line x = a y + b through the end points of the segments that agree with the majority.

    Each segment is extended to the region's bottom and top rows; the length-weighted medians of those
    two columns pick the dominant line, and segments far from it (a stray edge that survived the
    filters) are left out of the fit.
    """
    if len(segs) == 0:
        return None
    lengths = _length(segs)
    x_b = np.array([_x_at(seg, y_bottom) for seg in segs])
    x_t = np.array([_x_at(seg, y_top) for seg in segs])
    agree = (np.abs(x_b - _weighted_median(x_b, lengths)) < 0.08 * width) & (
        np.abs(x_t - _weighted_median(x_t, lengths)) < 0.05 * width)
    segs, lengths = segs[agree], lengths[agree]
    ys = np.r_[segs[:, 1], segs[:, 3]]
    xs = np.r_[segs[:, 0], segs[:, 2]]
    if len(segs) == 0 or np.ptp(ys) < 1e-6:
        return None
    a, b = np.polyfit(ys, xs, 1, w=np.sqrt(np.r_[lengths, lengths]))
    return LaneLine(float(a * y_bottom + b), y_bottom, float(a * y_top + b), y_top)


def _weighted_median(values: NDArray[np.float64], weights: NDArray[np.float64]) -> float:
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def intersection(left: LaneLine, right: LaneLine) -> tuple[float, float] | None:
    """Where two boundary lines meet (None when parallel)."""
    # x = a y + b for both
    def coeffs(line: LaneLine) -> tuple[float, float]:
        a = (line.x_top - line.x_bottom) / (line.y_top - line.y_bottom)
        return a, line.x_bottom - a * line.y_bottom

    a1, b1 = coeffs(left)
    a2, b2 = coeffs(right)
    if abs(a1 - a2) < 1e-9:
        return None
    y = (b2 - b1) / (a1 - a2)
    return float(a1 * y + b1), float(y)


def _x_at(seg: NDArray[np.float64], y: float) -> float:
    x1, y1, x2, y2 = seg
    if abs(y2 - y1) < 1e-9:
        return float((x1 + x2) / 2)
    return float(x1 + (y - y1) * (x2 - x1) / (y2 - y1))


def _length(segs: Segments) -> NDArray[np.float64]:
    return np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) if len(segs) else np.zeros(0)


def lane_on_ground(observation: LaneObservation | None, camera: PinholeCamera, near_m: float = 3.0,
                   far_m: float = 8.0) -> tuple[float, float] | None:
    """Where the lane's centre runs on the ground in the kart's body frame, from both boundaries' curves
    (``paint``): (its lateral place at the body's origin, metres, left positive; its heading, rad, left
    positive), from the centre's points ``near_m`` and ``far_m`` ahead. None without both curves."""
    if observation is None or observation.left_curve is None or observation.right_curve is None:
        return None
    ahead = np.array([[near_m, 0.0, 0.0], [far_m, 0.0, 0.0]])
    rows = camera.project(transform_points(invert_pose(camera.pose_body_cam_array), ahead))[:, 1]
    sx = observation.width_px / camera.width_px  # the observation's pixels may be another size's
    sy = observation.height_px / camera.height_px
    centre = [((observation.left_curve.x_at(r * sy) + observation.right_curve.x_at(r * sy)) / 2 / sx, r)
              for r in rows]
    points = ground_points(camera, np.array(centre, dtype=np.float64))
    if not np.all(np.isfinite(points)):
        return None
    (x1, y1), (x2, y2) = points[0, :2], points[1, :2]
    heading = math.atan2(y2 - y1, x2 - x1)
    return float(y1 - x1 * math.tan(heading)), float(heading)

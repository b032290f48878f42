"""Small-scale tracks marked with tape: where to steer, from the ground seen through a wide-angle lens.

A small kart's camera sits a few centimetres above the floor behind a wide-angle lens, so a taped track's
borders are tight arcs in the image, a turn's outer border runs right across the view, and often only one
border is in sight. Straight lines in the image (the road pipeline, :mod:`kartpilot.perception.lanes`) do not
describe that. This pipeline works on the ground instead:

1. **Tape.** In the region of the image that shows the ground up to a little beyond the lookahead, a pixel
   is tape when it differs from the floor (the region's median grey level) by ``contrast`` toward the tape's
   side: brighter on a dark floor, darker on a light one (``paint: auto`` picks by the floor; glare on a
   glossy light floor is brighter, so it is not taken), or strongly coloured (``paint: colour``, and
   ``auto`` too). A 3x3 median drops lone pixels.
2. **The nearest border per column**: scanning each column up from the bottom, the first tape pixel. Those
   pixels are the inner edges of the borders that bound the free floor in front of the kart.
3. **The lens and the top view.** Those pixels (and the region's top row where a column meets no tape) go
   through the lens model to rays, and the rays meet the floor: points in metres ahead of and beside the
   camera (inverse perspective mapping of just the pixels that matter). The lens is a guessed ideal
   equidistant fisheye (``fov_diag_deg``, OpenCV's fisheye model with no distortion terms) pitched down so
   that the horizon falls on ``horizon_frac`` of the image's height; measure those two once per camera.
4. **The target.** On an arc of radius ``lookahead`` (``lookahead_widths`` times the track's width), each
   candidate bearing scores how close its point is to half a track width from the nearest border (the
   track's centre), less a small preference for straight ahead; a bearing whose ray meets a border before
   the arc is ruled out. A soft arg-max of the scores (``softness``) gives the target bearing. With one
   border in sight, the point half a width from it is the centre of the track, the thesis's missing-side
   rule in metres instead of the image's extreme column.

The target bearing is the heading deviation the follower steers by (the thesis's equation 1, toward a point
on the track instead of the boundaries' intersection). Everything is a pure function of the image and the
configuration; nothing is fitted to a recording: the physical inputs are the track's width, the camera's
height, its field of view and its horizon.

Ground frame: x to the right, z ahead, metres, from the point on the floor below the camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.core.errors import PerceptionError
from kartpilot.core.types import Image

__all__ = ["TapeConfig", "TapeObservation", "detect_tape_track", "draw_tape_track", "floor_points",
           "nearest_tape_rows", "tape_mask"]


@dataclass(frozen=True)
class TapeConfig:
    """A taped track and the camera that sees it.

    Attributes:
        paint: ``bright`` tape on a dark floor, ``dark`` on a light floor, ``colour`` (saturated tape on a grey
            floor), or ``auto``: bright or dark by the floor's grey level, and coloured tape as well.
        contrast: grey levels between the floor's median and tape.
        min_saturation: HSV saturation (0 to 255) above which a pixel is coloured tape.
        fov_diag_deg: the lens's diagonal field of view (an ideal equidistant fisheye).
        horizon_frac: where the horizon falls, as a fraction of the image's height from the top (the camera's
            pitch).
        camera_height_m: the camera's height above the floor.
        track_width_m: the distance between the track's borders.
        lookahead_widths: how far ahead the target lies, in track widths.
        region_beyond: the region of the image searched reaches this many lookaheads ahead.
        max_bearing_rad, bearings: the candidate bearings, evenly spread over +-max_bearing_rad.
        straight_preference: score lost per radian away from straight ahead (breaks ties toward it).
        softness: the soft arg-max's temperature, in score units (0: the plain arg-max).
    """

    paint: Literal["auto", "bright", "dark", "colour"] = "auto"
    contrast: float = 40.0
    min_saturation: float = 60.0
    fov_diag_deg: float = 170.0
    horizon_frac: float = 0.18
    camera_height_m: float = 0.08
    track_width_m: float = 0.5
    lookahead_widths: float = 0.7
    region_beyond: float = 1.1
    max_bearing_rad: float = 1.0
    bearings: int = 61
    straight_preference: float = 0.05
    softness: float = 0.1

    def __post_init__(self) -> None:
        checks = {
            "contrast": 0 < self.contrast < 255,
            "min_saturation": 0 < self.min_saturation <= 255,
            "fov_diag_deg": 30 <= self.fov_diag_deg < 180,
            "horizon_frac": 0 <= self.horizon_frac < 0.9,
            "camera_height_m": self.camera_height_m > 0,
            "track_width_m": self.track_width_m > 0,
            "lookahead_widths": self.lookahead_widths > 0,
            "region_beyond": self.region_beyond >= 1,
            "max_bearing_rad": 0 < self.max_bearing_rad < math.pi / 2,
            "bearings": self.bearings >= 3,
            "straight_preference": self.straight_preference >= 0,
            "softness": self.softness >= 0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"{bad[0]} is out of range ({getattr(self, bad[0])!r})")

    @property
    def lookahead_m(self) -> float:
        return self.lookahead_widths * self.track_width_m


@dataclass(frozen=True)
class TapeObservation:
    """One frame's result.

    Attributes:
        bearing_rad: the target's bearing, positive to the right (the heading deviation).
        target_m: the target on the floor (x right, z ahead).
        confidence: 0 to 1: the share of the searched columns that meet tape (0: no border in sight).
        border_px: (N, 2) the nearest tape pixel of each column that met tape (x, y).
        region_top_px: the top row of the region searched.
    """

    width_px: int
    height_px: int
    bearing_rad: float
    target_m: tuple[float, float]
    confidence: float
    border_px: NDArray[np.float64]
    region_top_px: int

    @property
    def any_detected(self) -> bool:
        return len(self.border_px) > 0

    @property
    def seen_bearing_rad(self) -> float | None:
        """The target's bearing, or None when no border was in sight (what the follower steers by)."""
        return self.bearing_rad if self.any_detected else None


def _camera_matrix(width: int, height: int, config: TapeConfig) -> NDArray[np.float64]:
    focal = math.hypot(width, height) / 2 / math.radians(config.fov_diag_deg / 2)
    return np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])


def _pitch_rad(height: int, focal: float, config: TapeConfig) -> float:
    return ((height - 1) / 2 - config.horizon_frac * height) / focal


def floor_points(pixels: NDArray[np.float64], width: int, height: int, config: TapeConfig
                 ) -> NDArray[np.float64]:
    """Pixels (N, 2) to points on the floor (N, 2: x right, z ahead, metres); NaN for pixels above the
    horizon."""
    if len(pixels) == 0:
        return np.zeros((0, 2))
    matrix = _camera_matrix(width, height, config)
    rays = cv2.fisheye.undistortPoints(pixels.reshape(-1, 1, 2).astype(np.float64), matrix,
                                       np.zeros(4)).reshape(-1, 2)
    pitch = _pitch_rad(height, matrix[0, 0], config)
    down = rays[:, 1] * math.cos(pitch) + math.sin(pitch)
    ahead = -rays[:, 1] * math.sin(pitch) + math.cos(pitch)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(down > 1e-6, config.camera_height_m / down, np.nan)
    return np.column_stack([rays[:, 0] * scale, ahead * scale])


def _row_at_distance(width: int, height: int, distance_m: float, config: TapeConfig) -> int:
    """The image row, in the centre column, of the floor ``distance_m`` ahead (the horizon's row at most)."""
    matrix = _camera_matrix(width, height, config)
    focal, cy = matrix[0, 0], matrix[1, 2]
    depression = math.atan2(config.camera_height_m, distance_m)  # below the horizon
    row = cy - focal * (_pitch_rad(height, focal, config) - depression)
    return int(np.clip(math.ceil(row), math.ceil(config.horizon_frac * height) + 1, height - 2))


def tape_mask(region: Image, config: TapeConfig) -> NDArray[np.uint8]:
    """1 where ``region`` (BGR or gray) shows tape, 0 where it shows floor."""
    gray = cv2.cvtColor(region, cv2.COLOR_BGR2GRAY) if region.ndim == 3 else region
    floor = float(np.median(gray[::2, ::2]))
    paint = config.paint
    if paint == "auto":
        paint_gray: str = "bright" if floor < 128 else "dark"
    else:
        paint_gray = paint
    mask = np.zeros(gray.shape, np.uint8)
    if paint_gray == "bright":
        mask |= (gray > floor + config.contrast).astype(np.uint8)
    elif paint_gray == "dark":
        mask |= (gray < floor - config.contrast).astype(np.uint8)
    if paint in ("auto", "colour") and region.ndim == 3:
        hsv = cv2.cvtColor(region, cv2.COLOR_BGR2HSV)
        mask |= ((hsv[..., 1] > config.min_saturation) & (hsv[..., 2] > config.contrast)).astype(np.uint8)
    return cv2.medianBlur(mask, 3)  # drops lone pixels, keeps lines two pixels wide, and is left-right symmetric


def nearest_tape_rows(mask: NDArray[np.uint8]) -> NDArray[np.int64]:
    """Per column, the row (in the mask) of the lowest tape pixel; -1 where the column has none."""
    flipped = mask[::-1]
    found = flipped.any(axis=0)
    rows = mask.shape[0] - 1 - flipped.argmax(axis=0)
    return np.where(found, rows, -1).astype(np.int64)


def detect_tape_track(image: Image, config: TapeConfig = TapeConfig()) -> TapeObservation:
    """The bearing to steer toward on a taped track (see the module's description)."""
    if image is None or image.size == 0:
        raise PerceptionError("empty image")
    if image.ndim == 3 and image.shape[2] != 3:
        raise PerceptionError(f"expected a BGR or gray image, got {image.shape[2]} channels")
    height, width = image.shape[:2]
    top = _row_at_distance(width, height, config.region_beyond * config.lookahead_m, config)
    rows = nearest_tape_rows(tape_mask(image[top:], config))
    met = rows >= 0
    columns = np.arange(width, dtype=np.float64)
    pixels = np.column_stack([columns, np.where(met, rows + top, top).astype(np.float64)])
    ground = floor_points(pixels, width, height, config)
    valid = np.isfinite(ground).all(axis=1)
    border = ground[met & valid]
    lookahead = config.lookahead_m
    bearings = np.linspace(-config.max_bearing_rad, config.max_bearing_rad, config.bearings)
    if len(border) == 0:
        return TapeObservation(width, height, 0.0, (0.0, lookahead), 0.0, np.zeros((0, 2)), top)
    # how far each candidate bearing is free: the columns' rays, sorted by bearing (out of view: the edge's)
    ray_bearing = np.arctan2(ground[valid, 0], ground[valid, 1])
    ray_free = np.where(met[valid], np.hypot(ground[valid, 0], ground[valid, 1]), np.inf)
    order = np.argsort(ray_bearing)
    free = np.interp(bearings, ray_bearing[order], ray_free[order])
    candidates = lookahead * np.column_stack([np.sin(bearings), np.cos(bearings)])
    clearance = np.sqrt(((candidates[:, None, :] - border[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
    half = config.track_width_m / 2
    score = -np.abs(clearance - half) / half - config.straight_preference * np.abs(bearings)
    score[free < lookahead] -= 10.0
    if config.softness > 0:
        weights = np.exp((score - score.max()) / config.softness)
        bearing = float((weights * bearings).sum() / weights.sum())
    else:
        bearing = float(bearings[np.argmax(score)])
    target = (lookahead * math.sin(bearing), lookahead * math.cos(bearing))
    return TapeObservation(width, height, bearing, target, float(met.mean()),
                           pixels[met], top)


def draw_tape_track(image: Image, observation: TapeObservation, steer_rad: float | None = None) -> Image:
    """The input with the region searched, the nearest border pixels (green) and the target's bearing (red);
    text scaled to the image."""
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    h, w = canvas.shape[:2]
    thickness = max(1, round(w / 320))
    cv2.line(canvas, (0, observation.region_top_px), (w - 1, observation.region_top_px), (255, 160, 0), thickness)
    for x, y in observation.border_px.astype(int):
        cv2.circle(canvas, (int(x), int(y)), thickness, (0, 220, 0), -1)
    base = (w // 2, h - 1)
    length = 0.6 * (h - observation.region_top_px)
    tip = (int(base[0] + length * math.sin(observation.bearing_rad)),
           int(base[1] - length * math.cos(observation.bearing_rad)))
    cv2.line(canvas, base, tip, (0, 0, 255), thickness + 1, cv2.LINE_AA)
    if steer_rad is not None:
        scale = w / 1000
        text = f"steer {math.degrees(steer_rad):+.1f} deg  conf {observation.confidence:.2f}"
        origin = (max(2, w // 60), max(10, round(28 * scale * 1.4)))
        cv2.putText(canvas, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.7 * scale * 1.4, (0, 0, 0), thickness + 2,
                    cv2.LINE_AA)
        cv2.putText(canvas, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.7 * scale * 1.4, (255, 255, 255), thickness,
                    cv2.LINE_AA)
    return canvas

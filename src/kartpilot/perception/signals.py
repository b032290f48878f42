"""Traffic lights and speed-limit signs by colour and shape: fast, on the CPU, and shy of false alarms.

**Traffic light** (the event's: one signal head on a tripod, red above green). A lamp that is on is small, round,
bright and strongly coloured (red or green); that alone also fits a red barrier, a sign's red ring, a red jacket or
a red car light, so a lamp counts only inside its **housing**: the dark box around it (a dark ring about the lamp),
which holds the other lamp, off and dark, beside it (below a red lamp, above a green one). A barrier or a ring has
no dark box around it. The lamp stands above the camera (the head is higher than 0.56 m), so it lies above the
horizon row.

**Speed sign** (a Dutch round sign: a red ring around a white disc with a black number). The ring is found as a red
region with a hole; the hole must be mostly white with a few dark strokes (the digits), which a red light, a barrier
or a car's rear light do not have. Colours are judged with the road as the grey reference where the frame's colour
cast is more than asphalt's own (:func:`road_grey`), and the ring's least brightness scales with the frame's
exposure, as a lamp's does. On its pole a sign stands higher than the camera, so its middle lies above
the horizon row (with a warm white balance, dark tyre marks on reddish asphalt made a ring with dark strokes on
the road). The number is read (in the disc's middle and in the whole of the ring's hole, the better reading) by
comparing the digits, cut out and scaled, with each value
of ``values_kmh`` drawn in two unlike fonts (normalised correlation, smoothed): a small classifier with no training
data and nothing to download. Signs stand on the right of the road in the Netherlands; one on the left (``sign_side``)
belongs to the other direction.

Distances: neither stands on the ground where the camera sees it (a tripod's head, a sign on a pole), so each is
placed from its size: a lamp of ``lamp_diameter_m`` or a sign of ``sign_diameter_m`` ``d`` pixels across is ``f *
size / d`` metres ahead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache, partial
from typing import Literal, NamedTuple

import cv2
import numpy as np

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array
from kartpilot.core.glyphs import text_mask
from kartpilot.core.types import Image
from kartpilot.perception.colour import ColourPlanes, green_mask, mask_components, red_mask
from kartpilot.perception.objects import Detection

__all__ = ["SignalConfig", "detect_signals", "detect_speed_signs", "detect_traffic_lights", "exposure",
           "place_by_size", "read_speed_value", "road_colour", "road_grey", "view_to_m"]


@dataclass(frozen=True)
class SignalConfig:
    """Attributes:
        horizon: the horizon's row as a fraction of the height (from the camera's mount; a lamp lies above it).
        min_lamp_px, max_lamp_px: a lit lamp's diameter in pixels, as a fraction of the image's height (the
            least: 7 px at 480, a lamp 6 px across inside it, whose housing ring, a quarter of that wide, is still
            a pixel or two: a lamp of 5 px, 27 m away, is at the grain of noise, and a speck in dark trees with a
            lamp's colour passed for one, in altered real and rendered frames).
        lamp_saturation, lamp_value: a lit lamp's least HSV saturation and value (0-255; the value in a frame
            exposed for daylight, scaled by :func:`exposure` in a darker one).
        housing_dark: the housing's brightest grey level (the dark box and the unlit lamp; scaled as lamp_value).
        sky_level, min_exposure: a frame whose sky's bright end (its 99th percentile grey level) reaches
            sky_level is exposed for daylight; a darker one's brightness thresholds are scaled by its sky over
            sky_level, down to min_exposure (a frame with no bright sky is not taken for one darker than that).
            The rendered overcast sky is 220 to 235, the real venue's 253.
        housing_share: the least share of the housing's pixels (beside the lamp) that are that dark.
        lamp_contrast: a lit lamp glows: its mean HSV value is at least this many times the median value of the
            dark housing around it (the ring's pixels that count as dark; a far head's ring reaches past its
            housing into the sky). The real lights: 1.65 or more under every alteration of their frames (the
            venue's green, the Hanze red 5.2); a dark red shirt, which passes for a lamp in its own dark housing:
            about 1.0.
        lamp_extent: a lamp is the pixels of its colour at least this share of its brightest pixel's value, or
            the lit level (``lamp_value``, scaled), whichever is less; its brightest pixel must reach the lit level.
            A bright lamp is its pixels at the lit level (lower takes in its glow on the housing, whose ring, placed
            by the lamp's size, then reaches past the housing); the venue's dim, grainy green lamp (its brightest
            pixels 120 to 160) under another camera's curve (gamma 1.5) kept only scattered specks at the lit level
            and was lost in 5 of 6 views (``signals_altered`` in ``benchmarks/detect.py``). 1: the lit level alone.
        lamp_colour_share: a lamp is its colour throughout: of its pixels (the closed blob that passed), at least
            this share have the lamp's hue and saturation themselves, at any brightness (the closing only mends
            specks that noise or glare took from it). A face in warm light, its hue at the edge of red's, before a
            dark tree over a dark jacket, was a red lamp in rendered pedestrian scenes (the kart waited for a green
            that never came): 0.46 to 0.60 of it had red's hue, the rest closed in. The real lamps (the Hanze red,
            the venue's green) at every size and alteration of ``signals_altered`` in ``benchmarks/detect.py``:
            0.94 or more.
        red_lamp_hue_max: a lit red lamp's hue reaches this far toward orange at most (OpenCV's hue, 0 to 180: 5 is
            10 degrees). A red signal lamp photographs at 340 to 360 degrees (the Hanze red, -8 to -2 in OpenCV's
            units under every alteration of ``signals_altered``; the simulator's lamp +1); skin in warm light
            begins about where red's wider window (up to 10, for a sign's ring, faded or overexposed) ends: the
            pedestrian's face before a dark tree over a dark jacket, through the real camera's compression and
            noise, was 96 % of one hue of 8 to 10 and a red lamp again (sweep events 10387, 10447).
        lamp_diameter_m, sign_diameter_m: real sizes, for the distance.
        min_lamp_height_m, camera_height_m: a lit lamp is at least this high above the ground, seen from a
            camera this high (the real kart's centre camera: 0.56 m).
        light_side: ``right``: only signal heads right of the centre column count (where the event puts them,
            and where Dutch signals stand); ``any``.
        min_sign_px: a sign's least diameter in pixels, as a fraction of the height (smaller: too far to read).
        ring_saturation: a sign's red ring's least HSV saturation (a faded or overexposed ring is pale).
        ring_value: its least HSV value in a frame exposed for daylight, scaled with the frame's exposure as the
            lamps' levels are (the Hanze sign, against the sky, darkened by 0.6: its ring's median value 48).
        min_hole_share: the ring's hole (the white disc) holds at least this share of the sign's area (a sign's
            disc about 0.64; half of it allows a far sign's ring thickened by blur).
        sign_white_saturation: the disc's white is less saturated than this (HSV, 0-255) and within 75 % of the
            disc's bright level (the 90th percentile); ``sign_white_share`` of the disc must be white.
        values_kmh: the speed limits the reader knows: the event's signs, 10, 15 and 20 (the teams' code knows
            these). Each value the reader knows is one more it can take a sign for: a far real 20's "2" correlates
            with a drawn "3" nearly as well as with a drawn "2", and the real 20s, knowing 30 and 50 as well, were
            often left unread and sometimes read as 30 (``sign_reading`` in ``benchmarks/detect.py``). A sign of
            a value the reader does not know is left unread or read as the nearest it knows (a drawn 30 as 10):
            add 30 or 50 where the kart drives among such signs (``kartpilot detect --config``, a drive's YAML).
        min_value_score: the least correlation for a value to be read (below it the sign is reported with no value).
        sign_ink_contrast: the disc's middle (where the digits stand) holds ink at least this share darker than
            the disc's white (its darkest 5 %), relative to the disc's own white, not a fixed share of it: the
            venue's 20 at 17 m, blurred by 1.5 px, holds its digits at 0.23 (their darkest tenth 0.72 to 0.78 of
            the white; a fixed half of it found it in 1 of 6 views). A plain white disc (the closed-road sign)
            keeps its middle within 0.12 of its white under every alteration of ``benchmarks/detect.py``
            (blurred, its red ring reaches the disc's edge, not its middle; compressed; noise).
        sign_side: ``right``: only signs right of the camera's centre column count (the Netherlands); ``any``.
        max_distance_m: objects farther than this are not reported.
    """

    horizon: float = 0.34
    min_lamp_px: float = 0.0145
    max_lamp_px: float = 0.15
    lamp_saturation: int = 110
    lamp_value: int = 100
    housing_dark: int = 90
    sky_level: int = 200
    min_exposure: float = 0.5
    housing_share: float = 0.45
    lamp_contrast: float = 1.3
    lamp_extent: float = 0.65
    lamp_colour_share: float = 0.8
    red_lamp_hue_max: int = 5
    lamp_diameter_m: float = 0.2
    min_lamp_height_m: float = 1.2
    camera_height_m: float = 0.56
    light_side: Literal["right", "any"] = "right"
    sign_diameter_m: float = 0.6
    min_sign_px: float = 0.035
    ring_saturation: int = 50
    ring_value: int = 60
    min_hole_share: float = 0.3
    sign_white_saturation: int = 70
    sign_white_share: float = 0.45
    values_kmh: tuple[int, ...] = (10, 15, 20)
    min_value_score: float = 0.35
    sign_ink_contrast: float = 0.18
    sign_side: Literal["right", "any"] = "right"
    max_distance_m: float = 40.0

    def __post_init__(self) -> None:
        if not 0.0 < self.min_lamp_px < self.max_lamp_px <= 1.0:
            raise ConfigError("signals: need 0 < min_lamp_px < max_lamp_px <= 1")
        if not 0.0 < self.lamp_extent <= 1.0:
            raise ConfigError("signals: lamp_extent must be in (0, 1] (a share of the lamp's brightest value)")
        if not 0.0 <= self.lamp_colour_share <= 1.0:
            raise ConfigError("signals: lamp_colour_share must be in [0, 1] (a share of the lamp's pixels)")
        if not 0 <= self.red_lamp_hue_max <= 10:
            raise ConfigError("signals: red_lamp_hue_max must be in [0, 10] (OpenCV's hue: 10 is 20 degrees, orange)")
        if self.lamp_contrast < 1.0:
            raise ConfigError("signals: lamp_contrast must be at least 1 (a lamp is brighter than its housing)")
        if not 0.0 < self.min_exposure <= 1.0 or not 0 < self.sky_level <= 255:
            raise ConfigError("signals: min_exposure must be in (0, 1] and sky_level in (0, 255]")
        if not 0 <= self.ring_value <= 255:
            raise ConfigError("signals: ring_value must be in [0, 255]")
        if not 0.0 <= self.min_hole_share < 1.0:
            raise ConfigError("signals: min_hole_share must be in [0, 1)")
        if not 0.0 < self.sign_ink_contrast < 1.0:
            raise ConfigError("signals: sign_ink_contrast must be in (0, 1) (a share of the disc's white)")
        if min(self.lamp_diameter_m, self.sign_diameter_m, self.max_distance_m) <= 0 or not self.values_kmh:
            raise ConfigError("signals: lamp_diameter_m, sign_diameter_m and max_distance_m must be positive and "
                              "values_kmh not empty")
        if min(self.values_kmh) <= 0 or len(set(self.values_kmh)) != len(self.values_kmh):
            raise ConfigError("signals: values_kmh must be positive and each given once (a value given twice "
                              "reads as well as itself, and no sign would be read)")


def place_by_size(detection: Detection, camera: PinholeCamera | None, width_px: int, size_m: float,
                  size_px: float | None = None) -> Detection:
    """The detection placed from its known size: ``f * size / d`` along the camera's axis (``d``: ``size_px``,
    else the box's larger side), in the body frame through the camera's mount."""
    if camera is None:
        return detection
    scale = camera.width_px / width_px
    diameter = (size_px if size_px is not None else max(detection.width_px, detection.height_px)) * scale
    if diameter <= 0:
        return detection
    depth = camera.fx_px * size_m / diameter  # along the camera's axis
    x = (detection.box_px[0] + detection.box_px[2]) / 2 * scale
    y = (detection.box_px[1] + detection.box_px[3]) / 2 * scale  # the same field of view: one scale
    rays = camera.rays(np.array([[x, y], [x, detection.box_px[1] * scale]]))
    pose = camera.pose_body_cam_array
    body, top = (pose[:3, :3] @ (rays * depth).T).T + pose[:3, 3]
    return replace(detection, distance_m=float(body[0]), lateral_m=float(body[1]),
                   view_to_m=float(body[0] - top[0] + view_to_m(camera, top)))


def view_to_m(camera: PinholeCamera, point_body: Array, margin_px: float = 2.0, step_m: float = 0.05) -> float:
    """The least distance ahead (body x) a point in the body frame can come to, the kart driving straight on, and
    still be in the camera's image (``margin_px`` inside its edges); NaN where it is not in view now."""
    ahead = np.arange(float(point_body[0]), 0.0, -step_m)
    points = np.c_[ahead, np.full((len(ahead), 2), np.asarray(point_body, float)[1:3])]
    pose = camera.pose_body_cam_array
    in_cam = (points - pose[:3, 3]) @ pose[:3, :3]  # R^T (p - t), row-wise
    front = in_cam[:, 2] > 1e-6
    uv = camera.project(np.where(front[:, None], in_cam, 1.0))
    seen = front & (uv[:, 0] >= margin_px) & (uv[:, 0] <= camera.width_px - 1 - margin_px) & (uv[:, 1] >= margin_px) \
        & (uv[:, 1] <= camera.height_px - 1 - margin_px)
    if len(seen) == 0 or not seen[0]:
        return math.nan
    lost = np.flatnonzero(~seen)
    return float(ahead[lost[0] - 1]) if len(lost) else float(ahead[-1])


def exposure(gray: Image, horizon_row: int, sky_level: float, least: float) -> float:
    """The frame's exposure against one exposed for daylight: the sky's bright end (the 99th percentile of the
    grey levels above the horizon row) over ``sky_level``, between ``least`` and 1. A lit lamp and its dark
    housing scale with it: the venue's real green light, a daylight lamp about 160 bright, was lost in the same
    frame darkened by 0.6 (as a camera exposing for the sun makes it) under the fixed threshold of 100."""
    top = gray[: max(horizon_row, 1)]
    return float(np.clip(_percentile_u8(top, 99.0) / sky_level, least, 1.0))


def _percentile_u8(values: Image, q: float) -> float:
    """``np.percentile(values, q)`` (its linear interpolation between the two nearest ranks) of 8-bit values, from
    their histogram: the same value at a third of the cost of sorting them."""
    hist = cv2.calcHist([np.ascontiguousarray(values)], [0], None, [256], [0, 256])
    counts = np.cumsum(hist.ravel().astype(np.int64))
    rank = q / 100.0 * (counts[-1] - 1)
    below = math.floor(rank)
    low, high = np.searchsorted(counts, [below, below + 1], side="right")
    return float(low + (rank - below) * (min(int(high), 255) - low))


def road_colour(image: Image) -> np.ndarray:
    """The road's colour, (B, G, R): the median of the image's lower middle, the asphalt ahead of the kart."""
    h, w = image.shape[:2]
    # every other row and column: the same median to a level or so, at a quarter of the cost
    return np.median(image[int(0.8 * h)::2, int(0.35 * w):int(0.65 * w):2].reshape(-1, 3), axis=0)


def road_grey(image: Image, tint: float = 0.1, max_gain: float = 1.3) -> Image:
    """``image`` white-balanced on the road where its colour cast is more than asphalt's own: each colour
    channel scaled so that the image's lower middle (the asphalt ahead of the kart) has the same median in each,
    less the ``tint`` asphalt itself may have (the venue's is off by less: ``signals_altered`` in
    ``benchmarks/detect.py``; left as it is, a faint far ring stays as red as it is) and by at most ``max_gain``
    either way; the image itself where no channel is off by more. Another camera's or another day's white
    balance tints a sign's white disc and the grey sky round it as it tints the road: warmer (blue x0.85, red
    x1.15), the discs of the real signs turned pink enough to be no white disc at any size, and the overcast sky
    round the venue's sign as red as a pale ring."""
    median = np.maximum(road_colour(image), 1.0)
    cast = np.log(float(median.mean()) / median)
    gains = np.exp(np.sign(cast) * np.clip(np.abs(cast) - math.log1p(tint), 0.0, math.log(max_gain)))
    if np.all(gains == 1.0):
        return image
    return cv2.transform(image, np.diag(gains).astype(np.float32))


class _Planes(NamedTuple):
    """What the light and the sign detectors both take from a frame, computed once: its HSV and grey planes, and
    its exposure (:func:`exposure`)."""

    hsv: Image
    gray: Image
    exposure: float


def _planes(image: Image, config: SignalConfig, colour: ColourPlanes | None = None) -> _Planes:
    if colour is None:
        colour = ColourPlanes.of(image)
    if colour.hsv is None:
        raise ConfigError("traffic lights and signs need a colour image")
    return _Planes(colour.hsv, colour.gray, exposure(colour.gray, int(config.horizon * image.shape[0]),
                                                     config.sky_level, config.min_exposure))


def detect_signals(image: Image, config: SignalConfig = SignalConfig(), camera: PinholeCamera | None = None,
                   planes: ColourPlanes | None = None) -> list[Detection]:
    """:func:`detect_traffic_lights` and :func:`detect_speed_signs` on one frame, its planes computed once
    (``planes``: the frame's, where the caller has them)."""
    both = _planes(image, config, planes)
    return _lights(image, both, config, camera) + _signs(image, both, config, camera)


def detect_traffic_lights(image: Image, config: SignalConfig = SignalConfig(), camera: PinholeCamera | None = None
                          ) -> list[Detection]:
    """The lit lamps of signal heads, each as a ``traffic_light`` with state ``red`` or ``green`` and the whole
    head's box."""
    return _lights(image, _planes(image, config), config, camera)


def _lights(image: Image, planes: _Planes, config: SignalConfig, camera: PinholeCamera | None) -> list[Detection]:
    hsv, h = planes.hsv, image.shape[0]
    lit = round(config.lamp_value * planes.exposure)
    lamps: list[tuple[float, float, float, Detection]] = []  # (lamp's brightness, centre column, row, light)
    above = hsv[: int(config.horizon * h)]  # a lit lamp is above the horizon
    red_lamp = partial(red_mask, hue_max=config.red_lamp_hue_max)
    for state, colour in (("red", red_lamp), ("green", green_mask)):
        hued = colour(above, config.lamp_saturation, 0)
        coloured = cv2.bitwise_and(hued, cv2.inRange(above[..., 2], round(config.lamp_extent * lit), 255))
        count, labels, stats, (x0, y0) = mask_components(cv2.morphologyEx(coloured, cv2.MORPH_CLOSE, _SQUARE))
        value = hsv[y0:y0 + labels.shape[0], x0:x0 + labels.shape[1], 2]  # the labelled box's
        coloured = coloured[y0:y0 + labels.shape[0], x0:x0 + labels.shape[1]]
        hued = hued[y0:y0 + labels.shape[0], x0:x0 + labels.shape[1]]
        for k in np.flatnonzero(np.maximum(stats[1:count, 2], stats[1:count, 3]) >= config.min_lamp_px * h) + 1:
            found = [(core.edge, lamp) for core in _lamp_cores(value, coloured, hued, labels, int(k), stats[k], lit,
                                                                config.lamp_extent, (x0, y0))
                     if (lamp := _light(state, core, planes, lit, config, camera)) is not None]
            # a dim lamp as its whole glass where that passes, not its brightest specks (sized by the glass)
            lamps += [lamp for edge, lamp in found if edge < lit] or [lamp for _, lamp in found]
    return _one_lamp_per_head(lamps)


class _Core(NamedTuple):
    """A lamp's candidate pixels (:func:`_lamp_cores`): its box's size, area, centre, mean value, and the value it
    reaches down to."""

    width: int
    height: int
    area: int
    cx: float
    cy: float
    level: float
    edge: int
    own: int  # of its pixels, those of the lamp's hue and saturation


def _light(state: str, core: _Core, planes: _Planes, lit: int, config: SignalConfig,
           camera: PinholeCamera | None) -> tuple[float, float, float, Detection] | None:
    """The light a lamp's candidate pixels make, as (its brightness, centre column, row, the light); None where
    they are no lamp: no lamp's shape or size, too low, left of the kart, no dark housing round them, no glow."""
    hsv, gray, scale = planes
    h, w = gray.shape
    bw, bh, area, cx, cy, level, edge, own = core
    horizon = config.horizon * h
    if not config.min_lamp_px * h <= max(bw, bh) <= config.max_lamp_px * h or not 0.6 <= bw / max(bh, 1) <= 1.6 \
            or area < 0.45 * bw * bh or own < config.lamp_colour_share * area:
        return None
    # the lamp's diameter: a thresholded disc's box is about a pixel wider than the disc (a partly covered pixel at
    # each edge passes, since a lamp's colour mixed with its dark housing keeps its saturation)
    d = max(bw, bh) - 1.0
    # the lamp stands at least min_lamp_height_m up: at the distance its size gives, that many rows above the
    # horizon (a green fence or a red jacket near the horizon is lower)
    if horizon - cy < d * (config.min_lamp_height_m - config.camera_height_m) / config.lamp_diameter_m:
        return None
    if config.light_side == "right" and cx < (w - 1) / 2:
        return None
    # the housing: the lamp's own width beside it, and the other lamp's place (below red, above green)
    dark = round(config.housing_dark * scale)
    other = (cy + 0.9 * d, cy + 2.0 * d) if state == "red" else (cy - 2.0 * d, cy - 0.9 * d)
    box = (cx - 0.8 * d, min(other[0], cy - 0.7 * d), cx + 0.8 * d, max(other[1], cy + 0.7 * d))
    share = _dark_share(gray, (cx - 0.5 * d, other[0], cx + 0.5 * d, other[1]), dark)
    ring = _ring((cx, cy), d, gray, hsv[..., 2])
    if ring is None or min(share, float(np.mean(ring[0] <= dark))) < config.housing_share:
        return None  # no dark box around it: a red jacket, a barrier, a leaf in the sun
    ring_gray, ring_value = ring
    # it glows: a dark red shirt is its own dark housing. A dim lamp taken to its extent glows to its edge: trees in
    # sensor noise, one speck reaching the lit level, made one of leaves a little brighter than their shade (its
    # mean 1.32 times its surround, its edge 1.09; the venue's dim green lamp under gamma 1.5: 2.6 or more; the same
    # lamp blurred, 1.23 to 1.47, is found at the lit level)
    housing = config.lamp_contrast * max(float(np.median(ring_value[ring_gray <= dark])), 1.0)
    if level < housing or (edge < lit and edge < housing):
        return None
    confidence = min(1.0, share) * min(1.0, area / (0.75 * bw * bh))
    det = Detection("traffic_light", _clip(box, w, h), float(confidence), state)
    det = place_by_size(det, camera, w, config.lamp_diameter_m, size_px=d)
    return None if det.distance_m > config.max_distance_m else (level, cx, cy, det)


_SQUARE = np.ones((3, 3), np.uint8)
"""The 3x3 kernel of every closing and erosion here."""


def _lamp_cores(value: Image, coloured: Image, hued: Image, labels: Image, k: int, stat: np.ndarray, lit: int,
                extent: float, origin: tuple[int, int] = (0, 0)) -> list[_Core]:
    """The lamps that component ``k`` of the lamp-coloured pixels (``coloured``, at least ``extent * lit`` bright,
    closed) may hold: the pieces of it at ``lit`` (the detector's lamps until 2026-11-27) and, where its brightest
    pixel is under ``lit / extent``, the pieces down to ``extent`` of that brightest too; each reaching ``lit``
    somewhere.

    A lamp is its bright core and the pixels around it that are nearly as bright. A bright lamp's extent is its
    pixels at ``lit`` (lower takes in its glow on the housing, and the housing's ring, placed by the lamp's size,
    then reaches past the housing: the Hanze red lamp was lost at a lit level of 75). A dim lamp (the venue's green
    in daylight, its brightest pixels 120 to 160) under another camera's curve (gamma 1.5) kept only scattered
    specks at ``lit``, too sparse a shape for a lamp; down to ``extent`` of its brightest it is the whole glass.
    ``hued``: the pixels of the lamp's hue and saturation at any brightness (each core counts its own).
    ``value``, ``coloured``, ``hued``, ``labels`` and ``stat`` are of a box of the image whose top-left is
    ``origin``; the cores' centres are the image's."""
    x0, y0, bw0, bh0 = (int(v) for v in stat[:4])
    inside = labels[y0:y0 + bh0, x0:x0 + bw0] == k
    crop = value[y0:y0 + bh0, x0:x0 + bw0]
    hue_crop = hued[y0:y0 + bh0, x0:x0 + bw0]
    peak = int(crop[inside].max())
    if peak < lit:
        return []
    # the lamp's own colour, then closed as the component was (not the component's closed pixels: those would
    # take in the pale glow beside a bright lamp)
    own_colour = inside & (coloured[y0:y0 + bh0, x0:x0 + bw0] > 0)
    out = []
    for edge in sorted({lit, min(lit, round(extent * peak))}, reverse=True):
        # a pixel of margin: the closing's erosion takes the crop's outside for set, and would keep its dilation
        core = np.pad((own_colour & (crop >= edge)).view(np.uint8), 1)
        core = np.ascontiguousarray(cv2.morphologyEx(core, cv2.MORPH_CLOSE, _SQUARE)[1:-1, 1:-1])
        count, pieces, stats, centroids = cv2.connectedComponentsWithStats(core, 8)
        for j in range(1, count):
            x, y, bw, bh, area = (int(v) for v in stats[j])
            if max(bw, bh) < 3:
                continue
            piece = pieces[y:y + bh, x:x + bw] == j
            own = crop[y:y + bh, x:x + bw][piece]
            if int(own.max()) >= lit:
                out.append(_Core(bw, bh, area, origin[0] + x0 + float(centroids[j][0]),
                                 origin[1] + y0 + float(centroids[j][1]),
                                 float(np.mean(own)), edge,
                                 int(np.count_nonzero(hue_crop[y:y + bh, x:x + bw][piece]))))
    return out


def _one_lamp_per_head(lamps: list[tuple[float, float, float, Detection]]) -> list[Detection]:
    """The lights, one per signal head: a head shows one colour at a time, so of two lamps in one head (the
    dimmer one's centre inside the brighter one's head box) the brighter is the lit one. The unlit one passes for
    lit where the image is bright: the real green light at the venue, its frame brightened by 1.4, was also a red
    light 27 m away (its dark red lamp, small, as its own head)."""
    kept: list[int] = []
    for k in sorted(range(len(lamps)), key=lambda k: -lamps[k][0]):
        _, cx, cy, _ = lamps[k]
        if not any(b[0] <= cx <= b[2] and b[1] <= cy <= b[3] for b in (lamps[j][3].box_px for j in kept)):
            kept.append(k)
    return [lamps[k][3] for k in sorted(kept)]


def _dark_share(gray: Image, box: tuple[float, float, float, float], dark: int) -> float:
    h, w = gray.shape
    x0, y0, x1, y1 = (round(v) for v in box)
    x0, x1, y0, y1 = max(x0, 0), min(x1, w), max(y0, 0), min(y1, h)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return 0.0
    return float(np.mean(gray[y0:y1, x0:x1] <= dark))


def _ring(centre: tuple[float, float], d: float, *channels: Image) -> tuple[np.ndarray, ...] | None:
    """The pixels of the housing's ring around a lamp, in each of ``channels`` (one image's planes): the square
    of side 1.8 d about it, less the lamp's disc (0.65 d in radius); None where the image's edge cuts the ring,
    whose housing cannot be checked (a person's face at the image's top, in a dark hood cut off by the edge, was
    taken for a red lamp for a frame; a real lamp reaches the edge only a few metres from the kart, which has acted
    on it by then)."""
    h, w = channels[0].shape[:2]
    r = 0.9 * d
    if not (r <= centre[0] <= w - 1 - r and r <= centre[1] <= h - 1 - r):
        return None
    x0, x1 = int(centre[0] - r), int(centre[0] + r) + 1
    y0, y1 = int(centre[1] - r), int(centre[1] + r) + 1
    if x1 - x0 < 3 or y1 - y0 < 3:
        return None
    yy, xx = np.mgrid[y0:y1, x0:x1]
    ring = (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 > (0.65 * d) ** 2
    return tuple(channel[y0:y1, x0:x1][ring] for channel in channels)


def _clip(box: tuple[float, float, float, float], w: int, h: int) -> tuple[float, float, float, float]:
    return (float(max(box[0], 0)), float(max(box[1], 0)), float(min(box[2], w - 1)), float(min(box[3], h - 1)))


def detect_speed_signs(image: Image, config: SignalConfig = SignalConfig(), camera: PinholeCamera | None = None
                       ) -> list[Detection]:
    """Round red-ringed signs with a white disc, each as a ``speed_sign`` with its value (state, km/h) where it
    can be read."""
    return _signs(image, _planes(image, config), config, camera)


def _signs(image: Image, planes: _Planes, config: SignalConfig, camera: PinholeCamera | None) -> list[Detection]:
    balanced = road_grey(image)
    hsv = planes.hsv if balanced is image else cv2.cvtColor(balanced, cv2.COLOR_BGR2HSV)
    gray, scale = planes.gray, planes.exposure
    h, w = image.shape[:2]
    red = cv2.morphologyEx(red_mask(hsv, config.ring_saturation, round(config.ring_value * scale)), cv2.MORPH_CLOSE,
                           _SQUARE)
    contours, hierarchy = cv2.findContours(red, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return []
    out = []
    for k, contour in enumerate(contours):
        if hierarchy[0][k][3] != -1 or hierarchy[0][k][2] == -1 or len(contour) < 5:
            continue  # an outer contour with a hole: a ring
        x, y, bw, bh = cv2.boundingRect(contour)
        if max(bw, bh) < config.min_sign_px * h or not 0.6 <= bw / max(bh, 1) <= 1.6:
            continue
        (ex, ey), (ma, mb), _ = cv2.fitEllipse(contour)
        if min(ma, mb) / max(ma, mb, 1e-6) < 0.6:
            continue
        # a ring round one disc: its hole holds most of its area (a sign's white disc is about 0.8 of its
        # diameter, 0.64 of its area); a striped barrier's red, closed into one shape, has many small holes
        (hole, largest), child = (0.0, -1), int(hierarchy[0][k][2])
        while child != -1:  # its holes: the first child, then that child's next siblings
            hole, largest = max((hole, largest), (cv2.contourArea(contours[child]), child))
            child = int(hierarchy[0][child][0])
        if hole < config.min_hole_share * cv2.contourArea(contour):
            continue
        if config.sign_side == "right" and ex < (w - 1) / 2:
            continue
        if ey >= config.horizon * h:
            continue  # on its pole a sign stands higher than the camera: this is on the ground, not one
        # the sign's neighbourhood (its ring's box and the fitted ellipse's, with a margin): every mask below is
        # drawn there, not over the whole frame
        reach = 0.5 * max(ma, mb)
        x0, y0 = max(min(x, math.floor(ex - reach)) - 2, 0), max(min(y, math.floor(ey - reach)) - 2, 0)
        x1 = min(max(x + bw, math.ceil(ex + reach)) + 3, w)
        y1 = min(max(y + bh, math.ceil(ey + reach)) + 3, h)
        near_gray = gray[y0:y1, x0:x1]
        disc = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.ellipse(disc, ((ex - x0, ey - y0), (0.62 * ma, 0.62 * mb), 0.0), 255, -1)
        inside = near_gray[disc > 0]
        if inside.size < 20:
            continue
        # white: unsaturated (once the road is grey: :func:`road_grey`) and near the disc's brightest (a backlit
        # sign's white is grey, not bright)
        pale = hsv[y0:y1, x0:x1, 1][disc > 0] < config.sign_white_saturation
        bright = float(np.percentile(inside, 90))
        white = float(np.mean(pale & (inside >= 0.75 * bright)))
        if white < config.sign_white_share or np.mean(inside < 0.5 * bright) > 0.5:
            continue  # not a white disc: a lamp, a barrier's stripes, the scene seen through a red hoop
        if _ink_contrast(gray, (ex, ey), (ma, mb), bright) < config.sign_ink_contrast:
            continue  # a plain white disc (the closed-road sign), or one with nothing dark in its middle
        # the number is read in the disc's middle and in the whole of the ring's hole, the better of the two: a
        # sign's digits may reach beyond the middle (the Hanze sign's nearly fill its white), and a far or blurred
        # sign's ring bleeds into its hole's edge
        whole = np.zeros_like(disc)
        cv2.drawContours(whole, contours, largest, 255, -1, offset=(-x0, -y0))
        whole = cv2.erode(whole, _SQUARE)
        value, score = max(read_speed_value(near_gray, disc, config.values_kmh),
                           read_speed_value(near_gray, whole, config.values_kmh) if np.any(whole) else (0, -1.0),
                           key=lambda read: read[1])
        state = str(value) if score >= config.min_value_score else ""
        confidence = white * (0.5 + 0.5 * max(score, 0.0))
        det = Detection("speed_sign", _clip((x, y, x + bw, y + bh), w, h), float(min(confidence, 1.0)), state)
        det = place_by_size(det, camera, w, config.sign_diameter_m)
        if not det.distance_m > config.max_distance_m:
            out.append(det)
    return out


def _ink_contrast(gray: Image, centre: tuple[float, float], axes: tuple[float, float], white: float) -> float:
    """How much darker than the disc's ``white`` its middle's ink is (its 5th percentile, a share of the white):
    the middle of the ring's ellipse (``axes``, its full lengths), 0.45 of them across, where a sign's digits stand
    and a blurred ring's red does not reach."""
    h, w = gray.shape[:2]
    half = (0.225 * axes[0], 0.225 * axes[1])
    x0, x1 = max(int(centre[0] - half[0]), 0), min(math.ceil(centre[0] + half[0]) + 1, w)
    y0, y1 = max(int(centre[1] - half[1]), 0), min(math.ceil(centre[1] + half[1]) + 1, h)
    core = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.ellipse(core, ((centre[0] - x0, centre[1] - y0), (2 * half[0], 2 * half[1]), 0.0), 255, -1)
    middle = gray[y0:y1, x0:x1][core > 0]
    if middle.size == 0 or white <= 0:
        return 0.0
    return (white - float(np.percentile(middle, 5))) / white


_TEMPLATE = (24, 32)  # (width, height) the digits are compared at
_SMOOTH_PX = 1.2
"""The probe and the templates are compared smoothed by a Gaussian of this many pixels (of the 24x32 grid): a far
sign's strokes are a pixel wide, a font's several; unsmoothed, their correlation measured the strokes' width more
than the digits' shapes (the real 20 at 26 px read 0.41 as 20 and 0.42 as 30)."""
_FONTS = ("hershey-simplex", "dejavu-sans")
"""The fonts the digits are compared in, the best of them per value: OpenCV's stroke font and a filled sans-serif
(:mod:`kartpilot.core.glyphs`). A real sign's font is neither (the Dutch signs': narrow and heavy); two unlike
fonts teach the reader what a digit's shape is rather than one font's. The renderer draws its signs in a third
(DejaVu Sans Bold, narrowed), which the reader has no template of."""


def read_speed_value(gray: Image, disc_mask: Image, values_kmh: tuple[int, ...]) -> tuple[int, float]:
    """(value, score) of the number inside a sign's disc: its dark strokes, cut out and scaled, against each
    value drawn in each of :data:`_FONTS`; score is the normalised correlation (-1 to 1) of the value's best
    font, or -1 where the best value does not stand out from the next (a far sign's digits are a few pixels
    tall: 2 and 3 look alike). The strokes are taken as how dark each pixel is between the disc's white and its
    darkest ink, not as a threshold's yes or no: a far or blurred digit's edge pixels carry its shape."""
    ys, xs = np.nonzero(disc_mask)
    region = gray[ys.min():ys.max() + 1, xs.min():xs.max() + 1].astype(np.float32)
    inside = disc_mask[ys.min():ys.max() + 1, xs.min():xs.max() + 1] > 0
    white, ink_level = float(np.percentile(region[inside], 90)), float(np.percentile(region[inside], 5))
    rows, cols = np.nonzero((region < 0.5 * white + 0.5 * ink_level) & inside)
    if len(rows) < 6:
        return values_kmh[0], -1.0
    darkness = np.clip((white - region) / max(white - ink_level, 1.0), 0.0, 1.0) * inside
    probe = _smooth(cv2.resize(darkness[rows.min():rows.max() + 1, cols.min():cols.max() + 1], _TEMPLATE,
                               interpolation=cv2.INTER_AREA))
    scores = sorted(((max(_correlation(probe, t) for t in _digits_templates(v)), v) for v in values_kmh),
                    reverse=True)
    best, score = scores[0][1], scores[0][0]
    if len(scores) > 1 and score - scores[1][0] < _MARGIN:
        return best, -1.0  # two values read about as well: too small or blurred to tell
    return best, score


_MARGIN = 0.05  # the best value's correlation must beat the next one's by this much


def _smooth(image: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(image.astype(np.float32), (0, 0), _SMOOTH_PX)


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    norm = math.sqrt(float((a * a).sum()) * float((b * b).sum()))
    return float((a * b).sum() / norm) if norm > 0 else -1.0


@lru_cache(maxsize=32)
def _digits_templates(value: int) -> tuple[np.ndarray, ...]:
    """The number in each of :data:`_FONTS` (a plain, upright face, as road signs' digits are), cut to its ink,
    scaled to the comparison grid and smoothed."""
    return tuple(_smooth(cv2.resize(_digits_ink(str(value), font), _TEMPLATE, interpolation=cv2.INTER_AREA))
                 for font in _FONTS)


def _digits_ink(text: str, font: str) -> np.ndarray:
    """``text`` in ``font`` (OpenCV's ``hershey-simplex`` or a :data:`kartpilot.core.glyphs.FONTS` name), 0 to 1,
    cut to its ink, about 90 px tall (the stroke font) or 120 (an outline font)."""
    if font != "hershey-simplex":
        return text_mask(text, font, 120).astype(np.float32) / 255.0
    canvas = np.zeros((120, 60 * len(text) + 40), np.uint8)
    cv2.putText(canvas, text, (10, 100), cv2.FONT_HERSHEY_SIMPLEX, 3.2, 255, 11, cv2.LINE_AA)
    rows, cols = np.nonzero(canvas > 127)
    return (canvas[rows.min():rows.max() + 1, cols.min():cols.max() + 1] > 127).astype(np.float32)

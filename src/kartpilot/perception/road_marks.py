"""Paint across the lane, on the ground: stop lines and zebra crossings (the ``crosswalk`` class), through the
camera's mount.

The centre image is warped to the ground from above (the camera's pose over the ground, from ``kartpilot calibrate
ground``), where a stop line is a bar across the lane of a fixed depth and a zebra a row of bars along the road,
whatever their distance. Paint is what is brighter than the asphalt around it by more than the ground's own texture
(a grey top-hat a metre wide, its pixel grain taken out by a 3-pixel median, thresholded at the median plus
``noise_sigmas`` robust standard deviations of the ground within a few metres of each row), on the road: not on
grass, and not on what stands on the ground. A lane boundary, which runs along the road, covers little of any row
across the lane; a stop line's rows are one run of paint over most of a lane's width (``stop_cover``), the same
columns in each, over a depth of ``stop_depth_m``, with bare asphalt before and behind it, brighter than that
asphalt by as much as paint is and brighter than the road's sunlit asphalt anywhere in the view (a strip of sun
between two shadows across the road is brighter than what lies before and behind it too); a zebra's rows hold at
least ``zebra_min_stripes`` bars side by side in a regular pattern over ``zebra_min_length_m`` along the road.
Both are sought across ``search_half_width_m`` either side of the kart's line, not only straight ahead: 15 m into a
bend the lane lies metres to the side. Each is reported with the lateral offset of its middle.

Without a camera mount there is no ground and nothing is reported: these marks are told apart by their size on the
ground, not by how they look in the image.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np
from scipy.ndimage import median_filter

from kartpilot.calibration.ground import BirdseyeView, birdseye_homography
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import Image
from kartpilot.perception.colour import ColourPlanes, grass
from kartpilot.perception.objects import Detection

__all__ = ["RoadMarkConfig", "camera_for_image", "detect_road_marks", "medians_u8"]


@dataclass(frozen=True)
class RoadMarkConfig:
    """Attributes:
        near_m, far_m: the stretch of ground ahead that is searched, from the ground under the camera (not the
            body frame's origin, which one rig puts at the rear axle and another under the camera: the SDC
            kart's centre camera is 1.2 m ahead of its rear axle, so the defaults search 1.2 to 19 m there).
        search_half_width_m: the marks are sought this far either side of the kart's line: in the venue's
            S-bend (10 m radius, 45 degrees each way) a crossing 15 m ahead, the far end of where the kart must
            see one, has its middle 5 to 7 m to the side and reaches 3 m beyond it. At 8 m, a crossing there was
            cut to fewer than three bars and missed: on the real frames, the venue's own crossing as the kart
            leaves the S-bend (taken then for white blocks beside the course, which they are not).
        lane_half_width_m: half the lane's width: a stop line covers most of a stretch this wide (wherever it
            lies in the search).
        pixels_per_m: the ground view's resolution.
        noise_sigmas, min_contrast: the paint threshold (robust sigmas above the median top-hat; a floor).
        stop_cover: the least share of the lane's width that a stop line's rows cover.
        stop_depth_m: a stop line's depth along the road (least, most).
        stripe_width_m: a zebra stripe's width across the road (least, most).
        zebra_min_stripes, zebra_min_length_m: the fewest stripes side by side, over at least this length.
        sunlit_percentile: a stop line is brighter than this percentile of the road's own asphalt in the view
            (paint is brighter than sunlit asphalt; a sunlit strip between two shadows is not).
        stats_half_window_m: each row's paint threshold comes from the rows this far either side of it (a
            running median of the rows' own statistics; wider than half a zebra's length, so a zebra's rows,
            a third paint, do not raise their own threshold).
    """

    near_m: float = 0.0
    far_m: float = 17.8
    search_half_width_m: float = 10.5
    lane_half_width_m: float = 1.4
    pixels_per_m: float = 20.0
    noise_sigmas: float = 5.0
    min_contrast: float = 20.0
    stop_cover: float = 0.6
    stop_depth_m: tuple[float, float] = (0.15, 0.8)
    stripe_width_m: tuple[float, float] = (0.2, 1.0)
    zebra_min_stripes: int = 3
    zebra_min_length_m: float = 1.0
    stats_half_window_m: float = 4.0
    sunlit_percentile: float = 90.0

    def __post_init__(self) -> None:
        if not 0 <= self.near_m < self.far_m or self.pixels_per_m <= 0:
            raise ConfigError("road_marks: need 0 <= near_m < far_m and a positive pixels_per_m")
        if not 0 < self.lane_half_width_m <= self.search_half_width_m:
            raise ConfigError("road_marks: need 0 < lane_half_width_m <= search_half_width_m")
        if not 0.0 <= self.sunlit_percentile <= 100.0:
            raise ConfigError("road_marks: sunlit_percentile must be between 0 and 100")


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


def medians_u8(values: np.ndarray) -> np.ndarray:
    """The median along the last axis of 8-bit values, as ``np.median`` gives it (float32), at a third of its
    cost: a stable sort of 8-bit values is a counting sort, where the median's partition compares."""
    ordered = np.sort(values, axis=-1, kind="stable")
    n = values.shape[-1]
    return (ordered[..., (n - 1) // 2].astype(np.float32) + ordered[..., n // 2]) / 2


def detect_road_marks(image: Image, camera: PinholeCamera | None, config: RoadMarkConfig = RoadMarkConfig(),
                      upright: Sequence[tuple[float, float, float, float]] = (),
                      columns: Sequence[tuple[float, float, float, float]] = (),
                      planes: ColourPlanes | None = None) -> list[Detection]:
    """Stop lines and zebra crossings ahead, each with its near edge's distance on the ground.

    ``upright``: the image boxes of things found standing on the ground (barriers, cars, people), which are not
    ground: seen from above, a barrier's white stripes would lie across the road as far as the eye reaches.
    ``columns``: the boxes of other upright things, whose foot is less sure (a far thing's column can run on down
    into the paint before it): not ground for a stop line (a bright edge along a thing's foot is a bar across the
    view), but ground for a zebra, whose pattern of bars such an edge does not make. ``planes``: the frame's, where
    the caller has them."""
    if camera is None:
        return []
    h, w = image.shape[:2]
    camera = camera_for_image(camera, w, h)
    half = config.search_half_width_m
    foot = float(camera.pose_body_cam_array[0, 3])
    view = BirdseyeView((foot + config.near_m, foot + config.far_m), (-half, half), config.pixels_per_m)
    bw, bh = view.size_wh
    homography, in_view, smear = _ground_geometry(camera, view)
    hsv, gray = planes if planes is not None else ColourPlanes.of(image)
    ground = cv2.warpPerspective(gray, homography, (bw, bh), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    # paint lies on the road: not on grass, and not on what stands on the ground
    off_road = (grass(hsv) if hsv is not None else np.zeros((h, w), bool)).astype(np.uint8)
    _mark_boxes(off_road, upright, 1)
    _mark_boxes(off_road, columns, 2)
    seen = cv2.warpPerspective(off_road, homography, (bw, bh), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP)
    valid = in_view & (seen != 1)
    bare = valid & (seen == 0)  # the ground a stop line may lie on
    if valid.sum() < 50:
        return []
    k = max(3, round(1.2 * config.pixels_per_m) | 1)
    tophat = cv2.morphologyEx(ground, cv2.MORPH_TOPHAT, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
    # the asphalt's grain, sharp near the camera, is as bright as paint pixel by pixel but not over three: a
    # median keeps every mark here (a stop line's depth and a zebra's bars are several pixels) and loses the grain
    tophat = cv2.medianBlur(tophat, 3)
    paint = (tophat > _row_thresholds(tophat, valid, config)[:, None]) & valid
    out: list[Detection] = []
    # a stop line: a row's longest run of paint spans most of a lane's width (or of what is seen of it); a zebra's
    # stripes or a barrier's, side by side, are many short runs
    lane_px = 2 * config.lane_half_width_m * config.pixels_per_m
    gap = max(3, round(0.12 * config.pixels_per_m) | 1)  # pinholes the asphalt's grain leaves in paint
    closed = cv2.morphologyEx(paint.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((1, gap), np.uint8)).astype(bool)
    rows, starts, ends = _row_runs(closed & bare)
    order = np.lexsort((ends - starts, rows))  # per row, its longest run last
    last = np.ones(rows.size, bool)
    last[:-1] = rows[order][1:] != rows[order][:-1]
    longest = np.zeros((bh, 2), np.int64)
    longest[rows[order][last]] = np.column_stack([starts, ends])[order][last]
    length = (longest[:, 1] - longest[:, 0]).astype(np.float64)
    width = bare.sum(axis=1)
    line = (width >= 0.6 * lane_px) & (length >= config.stop_cover * np.minimum(width, lane_px))
    sunlit: float | None = None  # the road's sunlit level, found once a candidate needs it (most frames: none)
    for r0, r1 in _bands(line):
        depth = (r1 - r0) / config.pixels_per_m
        # far away, one image row spans more ground than the line is deep: the line is seen as deep as a row or
        # two there
        if not config.stop_depth_m[0] <= depth <= config.stop_depth_m[1] + 2.0 * float(smear[(r0 + r1) // 2]):
            continue
        # a bar across the road covers the same columns in each of its rows; a lane line curving across the view
        # (a bend's boundary, nearly square to the kart for a moment) covers a long stretch of each row, but one
        # that moves along the row from row to row
        common = np.percentile(longest[r0:r1, 1], 25) - np.percentile(longest[r0:r1, 0], 75)
        cols = _span(bw, longest[r0:r1])
        # and it lies on the road: bare asphalt before and behind it (a white car's body, seen from above, is
        # paint running on behind its bumper, or not ground at all)
        margin = max(2, round(0.3 * config.pixels_per_m))
        sides = [(max(r0 - margin, 0), r0), (r1, min(r1 + margin, bh))]
        asphalt = [float(np.mean((bare & ~paint)[a:b][:, cols])) if b > a else 0.0 for a, b in sides]
        if common >= 0.75 * float(np.median(length[r0:r1])) and min(asphalt) >= 0.5:
            c = np.flatnonzero(cols)
            level = float(np.median(ground[r0:r1, c[0]:c[-1] + 1]))
            # and brighter than the ground before and behind it, by as much as paint is: a band of a bright
            # patch beside the road (white gravel, a sunlit pavement, overexposed) has its like all round
            around = max(float(np.median(ground[a:b, c[0]:c[-1] + 1])) for a, b in sides if b > a)
            if level - around < config.min_contrast:
                continue
            if sunlit is None:
                sunlit = _sunlit_level(ground[bare & ~paint], config.sunlit_percentile)
            if level <= sunlit:
                continue
            corners = np.array([[c[0], r0], [c[-1] + 1, r0], [c[-1] + 1, r1], [c[0], r1]], np.float64)
            out.append(_detection("stop_line", view, camera, corners, float(np.mean(length[r0:r1]) / lane_px), w, h))
    for r0, near, cols, share in _zebra_bands(paint, config):
        c = np.flatnonzero(cols)
        corners = np.array([[c[0], r0], [c[-1] + 1, r0], [c[-1] + 1, near], [c[0], near]], np.float64)
        out.append(_detection("crosswalk", view, camera, corners, 0.5 + 0.5 * share, w, h))
    return out


def _sunlit_level(road: np.ndarray, percentile: float) -> float:
    """The brightness of the road's sunlit asphalt (its pixels, not paint): sunlit asphalt between two shadows
    across the road (a tree's, a post's) is brighter than the ground just before and behind it, as a line is, but
    no brighter than this; paint is. Where shadows lie on the road its asphalt is two levels, shaded and sunlit
    (Otsu's split between them); overcast, one, split in two halves."""
    if road.size < 50:
        return 0.0
    split, _ = cv2.threshold(road.reshape(1, -1), 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    upper = road[road > split]  # none where the ground is one grey (a black frame)
    return float(np.percentile(upper if upper.size else road, percentile))


def _zebra_bands(paint: np.ndarray, config: RoadMarkConfig) -> list[tuple[int, int, np.ndarray, float]]:
    """Zebra crossings whose bars run along the columns of ``paint``: each as its far row, past its near row,
    its columns and the share of its pattern seen."""
    bh, bw = paint.shape
    stripe_px = (config.stripe_width_m[0] * config.pixels_per_m, config.stripe_width_m[1] * config.pixels_per_m)
    stripes, outer = _regular_stripes(paint, stripe_px)
    # worn paint, a seam in the asphalt or a shadow breaks a few rows of a crossing's pattern
    bridge = max(1, round(0.25 * config.pixels_per_m))
    zebras: list[tuple[int, int, np.ndarray, float]] = []  # far row, past the near row, columns, share
    for r0, r1 in _bands(_bridged(stripes >= config.zebra_min_stripes, bridge)):
        if (r1 - r0) / config.pixels_per_m >= config.zebra_min_length_m:
            share = min(1.0, float(np.mean(stripes[r0:r1])) / (2 * config.zebra_min_stripes))
            cols = _span(bw, outer[r0:r1][stripes[r0:r1] >= config.zebra_min_stripes])
            # a crossing seen askew (in a bend) begins where its nearest bar does, before its bars run side by
            # side: its near edge is the last row on with a stripe under it
            under = np.array([stripes[r] >= 1 and cols[outer[r, 0]:max(outer[r, 1], outer[r, 0] + 1)].any()
                              for r in range(r1, bh)], bool)
            near = r1 + (_bands(_bridged(np.r_[True, under], bridge))[0][1] - 1)
            if zebras and zebras[-1][1] >= r0:  # the same crossing, a worn stretch between its parts
                r0, cols, share = zebras[-1][0], zebras[-1][2] | cols, max(share, zebras[-1][3])
                zebras.pop()
            zebras.append((r0, near, cols, share))
    return zebras


def _mark_boxes(mask: np.ndarray, boxes: Sequence[tuple[float, float, float, float]], value: int) -> None:
    """Each (left, top, right, bottom) box set to ``value`` in ``mask`` where it is 0, with the rows just under
    it (a thing's foot is found to a pixel or two, and a shadow lies at it)."""
    for left, top, right, bottom in boxes:
        foot = int(bottom + max(3.0, 0.1 * (bottom - top)))
        region = mask[max(int(top), 0):foot + 1, max(int(left), 0):int(right) + 1]
        region[region == 0] = value


def _bridged(flags: np.ndarray, gap: int) -> np.ndarray:
    """``flags`` with each run of False shorter than ``gap`` between two runs of True set True."""
    out = flags.copy()
    bands = _bands(flags)
    for (_, end), (start, _) in itertools.pairwise(bands):
        if start - end < gap:
            out[end:start] = True
    return out


def _row_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every run of True in every row: its row, first column and one past its last."""
    padded = np.pad(mask.astype(np.int8), ((0, 0), (1, 1)))
    rows, cols = np.nonzero(np.diff(padded, axis=1))  # row-major: each run's start, then its end
    return rows[::2], cols[::2], cols[1::2]


def _regular_stripes(paint: np.ndarray, width_px: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the most stripes side by side in a regular pattern (each a stripe's width, the next like it in
    width, within half to twice a width of it: a zebra's bars and their gaps are alike), and that pattern's first
    and past-last column. Two lane lines and a patch of worn asphalt between them are three runs, but not a
    pattern."""
    bh = paint.shape[0]
    rows, starts, ends = _row_runs(paint)
    width = ends - starts
    keep = (width >= width_px[0]) & (width <= width_px[1])
    rows, starts, ends, width = rows[keep], starts[keep], ends[keep], width[keep]
    mean = 0.5 * (width[1:] + width[:-1])
    gap = starts[1:] - ends[:-1]
    link = ((rows[1:] == rows[:-1]) & (np.maximum(width[1:], width[:-1]) <= 1.5 * np.minimum(width[1:], width[:-1]))
            & (gap >= 0.5 * mean) & (gap <= 2.0 * mean))
    count = np.zeros(bh, np.int64)
    outer = np.zeros((bh, 2), np.int64)
    for a, b in _bands(link):  # links a..b-1 join runs a..b: b - a + 1 stripes in one row
        r = rows[a]
        if b - a + 1 > count[r]:
            count[r], outer[r] = b - a + 1, (starts[a], ends[b])
    alone = count == 0  # a row with stripes but no pattern: one stripe, its first one
    count[rows[alone[rows]]] = 1
    first = np.r_[True, rows[1:] != rows[:-1]] & alone[rows]
    outer[rows[first]] = np.column_stack([starts[first], ends[first]])
    return count, outer


def _span(width: int, first_last: np.ndarray) -> np.ndarray:
    """The columns between the median first and the median last of rows' (first, past-last) columns."""
    cols = np.zeros(width, bool)
    cols[int(np.median(first_last[:, 0])):int(np.median(first_last[:, 1]))] = True
    return cols


@lru_cache(maxsize=8)
def _ground_geometry(camera: PinholeCamera, view: BirdseyeView) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the mount and the view fix, the same for every frame: the homography from ``view`` to the image, the
    ground pixels the image sees well in front of the camera, and the ground one image row spans per ground row
    (:func:`_row_length_m`: a far line's blur). Read-only: kept between frames."""
    bw, bh = view.size_wh
    homography = birdseye_homography(camera, view)
    in_view = cv2.warpPerspective(np.full((camera.height_px, camera.width_px), 255, np.uint8), homography, (bw, bh),
                                  flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP) > 0
    out = (homography, in_view & _in_front(view, camera), _row_length_m(view, camera))
    for array in out:
        array.setflags(write=False)
    return out


def _row_length_m(view: BirdseyeView, camera: PinholeCamera) -> np.ndarray:
    """For each ground row of ``view`` (straight ahead), the length along the ground that one image row spans."""
    bw, bh = view.size_wh
    rows = np.arange(bh, dtype=np.float64)
    pix = np.column_stack([np.full(bh, bw / 2), rows, np.ones(bh)])
    ground = pix @ view.ground_from_pixels().T
    cam_body = np.linalg.inv(camera.pose_body_cam_array)
    pts = np.column_stack([ground[:, 0], np.zeros(bh), np.zeros(bh)])
    v_near = camera.project(pts @ cam_body[:3, :3].T + cam_body[:3, 3])[:, 1]
    pts[:, 0] += 0.01
    v_far = camera.project(pts @ cam_body[:3, :3].T + cam_body[:3, 3])[:, 1]
    with np.errstate(divide="ignore"):
        return np.where(np.abs(v_near - v_far) > 1e-9, 0.01 / np.abs(v_near - v_far), 0.0)


def _row_thresholds(tophat: np.ndarray, valid: np.ndarray, config: RoadMarkConfig) -> np.ndarray:
    """Each row's paint threshold from the ground within ``stats_half_window_m`` of it (a running median of the
    rows' own median and spread): near ground is seen sharp (its grain stands out), far ground blurred, so one
    threshold for all rows takes the near grain for paint. A stop line or a zebra fills fewer than half the rows
    of the window, so it does not raise its own threshold. The window runs over the rows the camera sees, mirrored
    at their ends: a row at the view's edge weighs as much as any other (repeated to fill the window, as it was,
    a thing lying at the near edge, a board or a shadow, set the threshold of every near row)."""
    seen = valid.sum(axis=1) >= 10
    out = np.full(tophat.shape[0], np.inf)
    if not seen.any():
        return out
    # in integers, exactly as the float statistics of the valid values: twice the median and twice each value's
    # distance from it are whole, and an invalid value sorts last as one above every valid value
    inside = valid[seen]
    twice_median = _row_middle_sum(np.where(inside, tophat[seen].astype(np.uint16), 256), inside)
    twice_gap = np.abs(2 * tophat[seen].astype(np.int32) - twice_median[:, None]).astype(np.uint16)
    median = (twice_median / 2).astype(np.float32)
    mad = (_row_middle_sum(np.where(inside, twice_gap, 1024), inside) / 4).astype(np.float32)
    size = 2 * max(1, round(config.stats_half_window_m * config.pixels_per_m)) + 1
    median = median_filter(median, size=size, mode="mirror")
    mad = median_filter(mad, size=size, mode="mirror")
    out[seen] = np.maximum(median + config.noise_sigmas * 1.4826 * np.maximum(mad, 1.0), config.min_contrast)
    return out


def _row_middle_sum(values: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Twice each row's median of its ``values`` where ``inside`` (each row holds some; whole numbers under 2^16,
    those outside larger than every inside one), the sum of its two middle values: sorted as whole numbers (no NaN
    to carry, as a float sort of the inside values with NaN outside had), the inside values come first and their
    middle is read off."""
    ordered = np.sort(values, axis=1)
    count = np.count_nonzero(inside, axis=1)
    rows = np.arange(len(values))
    return ordered[rows, (count - 1) // 2].astype(np.int32) + ordered[rows, count // 2]


def _in_front(view: BirdseyeView, camera: PinholeCamera) -> np.ndarray:
    """Ground pixels well in front of the camera (the homography folds what lies behind it onto the image). The
    depth is affine in the view's pixels."""
    bw, bh = view.size_wh
    cam_body = np.linalg.inv(camera.pose_body_cam_array)
    to_ground = view.ground_from_pixels()  # (x, y, 1) per (column, row, 1)
    coeff = cam_body[2, :2] @ to_ground[:2]  # depth = coeff . (column, row, 1) + the camera's offset
    depth = coeff[0] * np.arange(bw)[None, :] + coeff[1] * np.arange(bh)[:, None] + coeff[2] + cam_body[2, 3]
    return depth > 0.3


def _bands(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first, past-last) of each run of True."""
    padded = np.r_[False, flags, False].astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _detection(label: str, view: BirdseyeView, camera: PinholeCamera, corners: np.ndarray, confidence: float,
               w: int, h: int) -> Detection:
    """The mark's box in the image (its ground rectangle's corners, the view's pixels, projected), its near
    edge's distance, its middle's lateral offset and its width across."""
    ground = np.column_stack([corners, np.ones(4)]) @ view.ground_from_pixels().T
    cam_body = np.linalg.inv(camera.pose_body_cam_array)
    pts = np.column_stack([ground[:, :2], np.zeros(4)]) @ cam_body[:3, :3].T + cam_body[:3, 3]
    px = camera.project(pts)
    box = (float(np.clip(px[:, 0].min(), 0, w - 1)), float(np.clip(px[:, 1].min(), 0, h - 1)),
           float(np.clip(px[:, 0].max(), 0, w - 1)), float(np.clip(px[:, 1].max(), 0, h - 1)))
    return Detection(label, box, float(min(max(confidence, 0.0), 1.0)), distance_m=float(ground[:, 0].min()),
                     lateral_m=float(ground[:, 1].mean()), width_m=float(np.ptp(ground[:, 1])))

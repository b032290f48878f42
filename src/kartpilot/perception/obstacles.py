"""Things standing on the track: people (OpenCV's HOG people detector), a car in the lane, barriers, a parking bay.

Each stands on the ground, so each is placed where its box's bottom meets the ground (the camera's mount), and each
is checked against that place: a thing that does not concern the kart is not reported.

- **People**: OpenCV's HOG people detector (Dalal and Triggs), shipped with OpenCV, run only where a person
  could stand: around each upright thing, at the scale a person standing there has (the ground plane's
  constraint on sliding windows). A box counts only if a person standing where its bottom meets the ground would
  be that tall in the image (``person_height_m``, within ``height_tolerance``): a tall box on a near point is a
  lamp post, a short one a bag. People beyond ``max_lateral_m`` from the kart's line (behind a spectator fence)
  or ``person_max_distance_m`` ahead are not reported.
- **Car**: something upright in the kart's corridor (``corridor_half_width_m`` either side of its line, ahead
  to ``max_distance_m``): a blob that is not asphalt (its colour far from the road's own, measured in the
  image's lower middle) and not grass, standing on the ground in the corridor and reaching the horizon row (a
  thing taller than the camera; paint on the ground never does), at least ``min_car_width_m`` wide on the ground.
- **Barrier**: a strongly red blob (its stripes joined) standing on the ground (its bottom below the horizon),
  as tall as a barrier where its foot stands, split where its foot jumps (one barrier behind another); a lit lamp
  is small and high, a sign's ring is high, a red jacket's lower edge is above the camera, so none is one.
- **Parking bay**: the next barrier behind another on the same side (the line between them turning less than a
  bend does from the kart's heading): the bay is the ground between them, its free length the gap from the near
  one's far end.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import cv2
import numpy as np

from kartpilot.calibration.ground import ground_points
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import invert_pose, transform_points
from kartpilot.core.types import Image
from kartpilot.perception.colour import ColourPlanes, grass, mask_components, red_mask
from kartpilot.perception.objects import Detection, box_iou, place_on_ground
from kartpilot.perception.road_marks import camera_for_image, medians_u8

__all__ = ["ObstacleConfig", "Upright", "a_tree_trunk", "detect_barriers", "detect_car", "detect_people",
           "detect_standing_people", "find_parking_bay", "ground_row", "horizon_row", "upright_things"]


@dataclass(frozen=True)
class ObstacleConfig:
    """Attributes:
        horizon: the horizon's row as a fraction of the height (used without a camera mount).
        person_height_m, height_tolerance: a standing person's height, and how far a box may be off it (a share).
        min_person_px: without a camera mount, the least box height HOG searches (fraction of the image's
            height; HOG's window is 128 px, so the image is scaled up to find smaller people, at a cost).
        hog_threshold: the least HOG score (the SVM's margin) a box needs.
        max_lateral_m: people and barriers farther than this from the kart's line are not reported.
        max_distance_m: nothing farther than this ahead is reported.
        corridor_half_width_m: the kart's corridor for a car: this far either side of its line.
        min_car_width_m, max_car_width_m: the width on the ground of an upright thing in the corridor that is a
            car (wider: the far end of the venue, its barriers, cars and fences run together at the horizon).
        colour_sigmas: a pixel is not asphalt when its colour is this many robust deviations from the road's.
        min_run_px: an upright thing's least run of pixels down from the horizon row, in the finder's own image
            (``stixel_focal_px``; 3 px: about 45 m away for the SDC kart's camera).
        stixel_focal_px: the upright-thing finder works on the image scaled down until the camera's focal length
            is this (320 px: half the SDC kart's 848x480 centre camera), or on the image as it is where that is
            smaller: its sizes in pixels (``min_run_px``, its smoothing) are then angles, the same for a camera
            of any resolution. Halving every image, as it did before, left a 424x240 frame 120 rows, where a
            row of a person's foot 27 m away is 10 m of ground.
        foot_row_share: a car (and a person) is reported only where one row of that image spans at most this
            share of its distance from the camera (``share * height * focal``: 18 m for the SDC kart's camera
            0.56 m up; the kart acts on a car from 14 m): farther, its foot is a row or two off by blur, and the
            far end of a road, a fence across it, was a car 28 m away (its foot two rows off).
        min_car_height_m: a car's least height (a low thing in the lane is not one).
        min_person_width_m, max_person_width_m: an upright thing this wide on the ground may be a person.
        shape_height_tolerance: how far an upright thing's height may be off a person's to be one (a share; tighter
            than HOG's, as the shape says nothing else).
        person_max_distance_m: people are found (by shape or by HOG) no farther than this, nor than
            ``foot_row_share`` allows (nearer only for an image smaller than 400x225 on the SDC kart's camera):
            beyond it a pixel of the foot's row is more than a metre on the ground, a far car's or barrier's
            column looks as tall as a person, and spectators beside the course stand 5 to 6 m to the side (the
            kart acts on people within 15 m).
        barrier_min_px: a barrier's least size (fraction of the image's height).
        barrier_height_m: a barrier's height (least, most), measured where its foot stands.
        min_foot_edge: an upright thing meets the ground at an edge: its pixels just above its foot differ from
            the ground just below it by at least this many of the road's robust deviations (the farthest colour
            channel, the median over its columns). The far end of a road, paler than the rows around it where
            verge fills them, runs into the nearer road without one, and was a person 16 m ahead in the venue's
            scene 1 enlarged by 1.4 (gamma 1.5, or noise): its edge 1.6 to 1.8. The rendered people and cars within
            20 m have 4.8 or more, the inflatable car in the venue's scene 0 9.0.
        trunk_foliage_share, trunk_colour_spread: a tree's trunk under its crown is as tall, thin and still as a
            person standing: a person's box is a tree's trunk where, in the band just above its top, at least
            ``trunk_foliage_share`` of the pixels across it and a width of it to either side are foliage (green),
            and its middle is one colour from top to foot (the medians of its fifths but the foot's, in Lab, all
            within ``trunk_colour_spread`` of their mean: a person's head, coat and legs differ). Both are asked, so
            that a person standing before a tree is still one. In rendered scenario frames the trunks' spread was 0 to 1
            and their foliage 0.90 to 1.0; the people's spread 45 to 77, with foliage above some of them 0.57 to
            0.69 (a tree behind).
    """

    horizon: float = 0.34
    person_height_m: float = 1.75
    height_tolerance: float = 0.35
    min_person_px: float = 0.2
    hog_threshold: float = 0.3
    max_lateral_m: float = 6.0
    max_distance_m: float = 30.0
    corridor_half_width_m: float = 1.3
    min_car_width_m: float = 1.2
    max_car_width_m: float = 3.0
    colour_sigmas: float = 6.0
    barrier_min_px: float = 0.02
    barrier_height_m: tuple[float, float] = (0.4, 1.6)
    min_run_px: int = 3
    stixel_focal_px: float = 320.0
    foot_row_share: float = 0.1
    min_car_height_m: float = 0.5
    min_person_width_m: float = 0.2
    max_person_width_m: float = 1.0
    shape_height_tolerance: float = 0.25
    person_max_distance_m: float = 18.0
    min_foot_edge: float = 3.0
    trunk_foliage_share: float = 0.8
    trunk_colour_spread: float = 12.0

    def __post_init__(self) -> None:
        if not 0 < self.height_tolerance < 1 or min(self.person_height_m, self.max_lateral_m,
                                                    self.max_distance_m, self.corridor_half_width_m) <= 0:
            raise ConfigError("obstacles: height_tolerance must be in (0, 1) and the sizes positive")
        if not self.person_max_distance_m > 0:
            raise ConfigError("obstacles: person_max_distance_m must be positive")
        if not self.stixel_focal_px > 0:
            raise ConfigError("obstacles: stixel_focal_px must be positive")
        if not 0 < self.foot_row_share <= 1:
            raise ConfigError("obstacles: foot_row_share must be in (0, 1]")
        if not 0 < self.barrier_height_m[0] < self.barrier_height_m[1]:
            raise ConfigError("obstacles: barrier_height_m must be (least, most) with 0 < least < most")
        if not 0 < self.trunk_foliage_share <= 1 or not self.trunk_colour_spread >= 0:
            raise ConfigError("obstacles: trunk_foliage_share must be in (0, 1] and trunk_colour_spread not negative")
        if not self.min_foot_edge >= 0:
            raise ConfigError("obstacles: min_foot_edge must not be negative")


_HOG: cv2.HOGDescriptor | None = None


def _hog() -> cv2.HOGDescriptor:
    global _HOG
    if _HOG is None:
        _HOG = cv2.HOGDescriptor()
        _HOG.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())
    return _HOG


def detect_people(image: Image, camera: PinholeCamera | None, config: ObstacleConfig = ObstacleConfig(),
                  things: list[Upright] | None = None) -> list[Detection]:
    """People standing on the ground, with their place, by OpenCV's HOG people detector.

    With the camera's mount, HOG looks only where a person could be: around each upright thing
    (:func:`upright_things`, computed here unless given) nearer than ``person_max_distance_m``, at the scales a
    person 1.5 to 2 m tall standing at the thing's foot would have, and their feet near its foot. A person is
    taller than the camera, so one is always an upright thing, and a box with no upright thing under it is not
    kept anyway (:func:`~kartpilot.perception.detect.detect_classical`). The search of the whole image at every
    scale costs about ten times more (``benchmarks/detect.py``); on the real venue frames it found one group of
    people, which this search finds too, where they stand (the geometric constraint of Sudowe and Leibe's sliding
    windows on the ground plane). Without a mount, the whole image at every scale down to ``min_person_px``,
    every box HOG is sure of."""
    h, w = image.shape[:2]
    if camera is None or image.ndim != 3:
        boxes, weights = _hog_whole(image, config)
    else:
        things = upright_things(image, camera, config) if things is None else things
        boxes, weights = _hog_around(image, camera_for_image(camera, w, h), things, config)
    if not boxes:
        return []
    kept = cv2.dnn.NMSBoxes([list(map(int, b)) for b in boxes], weights, config.hog_threshold, 0.4)
    out = []
    for k in np.ravel(kept):
        x, y, bw, bh = boxes[int(k)]
        # HOG's window has a margin around the person: about an eighth of its height above and below
        box = (x + 0.1 * bw, y + 0.06 * bh, x + 0.9 * bw, y + 0.94 * bh)
        out.append(Detection("person", box, float(1.0 - math.exp(-weights[int(k)])), source="classical"))
    return [d for d in place_on_ground(out, camera, (w, h)) if _plausible_person(d, camera, w, h, config)]


_WINDOW_PERSON = 0.88
"""The share of HOG's 128 px window a person's height fills (its margin is about 6 % above and below)."""


def _hog_whole(image: Image, config: ObstacleConfig) -> tuple[list[list[float]], list[float]]:
    """HOG over the whole image at every scale, its own grouping of the hits: (x, y, w, h) boxes, scores."""
    scale = max(1.0, 128.0 / (config.min_person_px * image.shape[0]))
    search = image if scale == 1.0 else cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
    boxes, weights = _hog().detectMultiScale(search, winStride=(8, 8), padding=(8, 8), scale=1.08)
    return [[float(v) / scale for v in b] for b in boxes], [float(v) for v in np.ravel(weights)]


def _hog_around(image: Image, cam: PinholeCamera, things: list[Upright], config: ObstacleConfig
                ) -> tuple[list[list[float]], list[float]]:
    """HOG's windows around each upright thing at a person's scale there (``cam`` fits the image's size): the
    hits that two or more other hits overlap (as HOG's own grouping asks of a cluster), as (x, y, w, h) boxes and
    scores."""
    h, w = image.shape[:2]
    ahead = float(cam.pose_body_cam_array[0, 3])
    farthest = min(config.person_max_distance_m, _placed_reach_m(cam, config)) - ahead
    boxes: list[list[float]] = []
    weights: list[float] = []
    for t in things:
        depth = t.distance_m - ahead
        if not 0.5 < depth <= farthest:
            continue
        person_px = cam.fy_px * config.person_height_m / depth
        foot = t.box_px[3]
        for size in (0.86, 1.0, 1.16):  # people of 1.5 to 2 m
            s = 128.0 * _WINDOW_PERSON / (person_px * size)
            win_w, win_h = 64.0 / s, 128.0 / s
            slack = 0.1 * person_px  # the thing's foot against the person's
            top = max(int(foot - slack - (1 - 0.06) * win_h), 0)
            bottom = min(math.ceil(foot + slack + 0.06 * win_h), h)
            left = max(int(t.box_px[0] - win_w), 0)
            right = min(math.ceil(t.box_px[2] + win_w), w)
            if (bottom - top) * s < 128 or (right - left) * s < 64:
                continue  # no whole window fits (a near person's head above the image)
            crop = cv2.resize(image[top:bottom, left:right], None, fx=s, fy=s, interpolation=cv2.INTER_LINEAR)
            found, scores = _hog().detect(crop, hitThreshold=0.0, winStride=(4, 4), padding=(0, 0))
            for (x, y), score in zip(np.reshape(found, (-1, 2)), np.ravel(scores), strict=True):
                boxes.append([left + float(x) / s, top + float(y) / s, win_w, win_h])
                weights.append(float(score))
    support = [sum(box_iou(_corners(a), _corners(b)) > 0.5 for b in boxes) for a in boxes]
    kept = [n for n, count in enumerate(support) if count >= 3]
    return [boxes[n] for n in kept], [weights[n] for n in kept]


def _corners(box: list[float]) -> tuple[float, float, float, float]:
    return box[0], box[1], box[0] + box[2], box[1] + box[3]


def _plausible_person(d: Detection, camera: PinholeCamera | None, w: int, h: int, config: ObstacleConfig) -> bool:
    if camera is None:
        return True
    if not math.isfinite(d.distance_m) or not 0 < d.distance_m <= config.max_distance_m:
        return False
    if abs(d.lateral_m) > config.max_lateral_m:
        return False  # behind the spectators' fence, across the field
    cam = camera_for_image(camera, w, h)
    depth = d.distance_m - float(cam.pose_body_cam_array[0, 3])
    expected = cam.fy_px * config.person_height_m / max(depth, 0.1)
    return abs(d.height_px / expected - 1.0) <= config.height_tolerance


def _road_spread(lab: Image, h: int, w: int, top: int = 0) -> np.ndarray:
    """The road's spread of colour, per channel (1.4826 times the median absolute deviation from the median, 2 at
    least; float32), from the image's lower middle (``lab``: the 8-bit image from row ``top`` down). In whole
    numbers, as the float statistics give it: twice the median and twice each value's distance from it are
    whole."""
    patch = np.ascontiguousarray(lab[int(0.8 * h) - top:, int(0.35 * w):int(0.65 * w)].reshape(-1, 3).T)
    twice_median = (2 * medians_u8(patch)).astype(np.int32)
    twice_gap = np.abs(2 * patch.astype(np.int32) - twice_median[:, None]).astype(np.uint16)
    ordered, n = np.sort(twice_gap, axis=1), patch.shape[1]
    mad = ((ordered[:, (n - 1) // 2].astype(np.int32) + ordered[:, n // 2]) / 4).astype(np.float32)
    return np.maximum(1.4826 * mad, 2.0)


class Upright(NamedTuple):
    """An upright thing standing on the ground (full-image pixels; metres on the ground)."""

    box_px: tuple[float, float, float, float]
    distance_m: float
    left_m: float
    right_m: float
    height_m: float
    top_clipped: bool

    @property
    def width_m(self) -> float:
        return abs(self.left_m - self.right_m)


def upright_things(image: Image, camera: PinholeCamera, config: ObstacleConfig = ObstacleConfig()) -> list[Upright]:
    """Things standing upright on the ground, found as columns (the "stixels" of road-scene vision): at the
    image's size where the camera's focal length is ``stixel_focal_px`` (half the SDC kart's 848x480; a smaller
    image as it is), a pixel is part of a thing when its colour is far from its row's (the road below the
    horizon, the sky and trees above it) and it is not grass; a column holds a thing when such pixels run down unbroken
    from the horizon row (a thing taller than the camera: paint on the ground never reaches it), and its bottom
    is where the thing meets the ground. Neighbouring columns are one thing (a car's wheels and shadow make its
    bottom uneven: split there, one car would be several narrow things); its foot is their median bottom, its
    height how far the pixels run up from the horizon, in metres at its distance. The reduced size's blur moves a
    foot down by about a pixel: at 18 m that is 2 m on the ground (placed about 10 % short), at 10 m 3 %."""
    full_h, full_w = image.shape[:2]
    scale = config.stixel_focal_px / camera_for_image(camera, full_w, full_h).fy_px
    if scale < 1.0:
        image = cv2.resize(image, (round(full_w * scale), round(full_h * scale)), interpolation=cv2.INTER_AREA)
    h, w = image.shape[:2]
    sx, sy = full_w / w, full_h / h
    cam = camera_for_image(camera, w, h)
    horizon = horizon_row(cam)
    row0 = math.ceil(horizon)
    if not 1 <= row0 < h - 4:
        return []
    lab8 = cv2.cvtColor(cv2.GaussianBlur(image, (5, 5), 0), cv2.COLOR_BGR2LAB)
    lab = lab8.astype(np.float32)
    spread = _road_spread(lab8[row0:], h, w, row0)
    # each row's own colour (the road pales with distance; the sky with height), smoothed over rows: a thing
    # covering less than half a row stands out from it
    rows = cv2.blur(medians_u8(np.ascontiguousarray(lab8.transpose(0, 2, 1)))[:, None, :], (1, 15))[:, 0, :]
    distance = np.abs(lab[..., 0] - rows[:, None, 0]) / spread[0]  # the farthest channel, one at a time: a third
    for channel in (1, 2):                                          # of the cost of one max over a 3-wide axis
        np.maximum(distance, np.abs(lab[..., channel] - rows[:, None, channel]) / spread[channel], out=distance)
    thing = ((distance > config.colour_sigmas) & ~grass(cv2.cvtColor(image, cv2.COLOR_BGR2HSV))).astype(np.uint8)
    thing = cv2.morphologyEx(thing, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)).astype(bool)
    down = _leading_run(thing[row0:])
    up = _leading_run(thing[row0 - 1::-1])
    standing = down >= config.min_run_px
    bottom = (row0 + down - 1).astype(np.float64)
    top = row0 - cv2.medianBlur(up.astype(np.uint8).reshape(1, -1), 5).ravel().astype(np.float64)
    out = []
    for start, stop in _segments(standing, top, bottom):
        foot = _median(bottom[start:stop].tolist()) + 0.5
        if _foot_edge(lab, spread, start, stop, int(foot)) < config.min_foot_edge:
            continue  # no edge where it meets the ground: the far road, paler than its rows, running on nearer
        head = _lower_quartile(top[start:stop].tolist())
        ahead = ground_points(cam, np.array([[start, foot], [stop, foot], [(start + stop) / 2, foot]]))
        if not np.all(np.isfinite(ahead)) or ahead[2, 0] <= 0:
            continue
        depth = float(ahead[2, 0]) - float(cam.pose_body_cam_array[0, 3])
        out.append(Upright((start * sx, head * sy, stop * sx, foot * sy), float(ahead[2, 0]), float(ahead[0, 1]),
                            float(ahead[1, 1]), (foot - head) * depth / cam.fy_px, head <= 0.5))
    return out


def _leading_run(mask: np.ndarray) -> np.ndarray:
    """Per column, how many of its first rows are all True (its first False's row; every row if none)."""
    return np.where(mask.all(axis=0), mask.shape[0], mask.argmin(axis=0))


def _median(values: list[float]) -> float:
    """``np.median`` of a few values, without its overhead (a thing is a few columns wide)."""
    ordered, n = sorted(values), len(values)
    return float(ordered[n // 2]) if n % 2 else (ordered[n // 2 - 1] + ordered[n // 2]) / 2


def _lower_quartile(values: list[float]) -> float:
    """``np.percentile(values, 25)`` (linear between the nearest ranks, as NumPy computes it), without its
    overhead."""
    ordered = sorted(values)
    position = 0.25 * (len(ordered) - 1)
    i = int(position)
    t = position - i
    if t == 0:
        return float(ordered[i])
    a, b = ordered[i], ordered[i + 1]
    return float(a + (b - a) * t) if t < 0.5 else float(b - (b - a) * (1 - t))


def _foot_edge(lab: np.ndarray, spread: np.ndarray, start: int, stop: int, foot: int) -> float:
    """How far a thing's pixels two rows above its ``foot`` (its lowest row) are from the ground three rows below
    it, in the road's robust deviations (``spread``, per channel; the farthest channel), the median over columns
    ``start`` to ``stop``: five rows apart, a step across the foot survives the finder's blur."""
    above, below = max(foot - 2, 0), min(foot + 3, lab.shape[0] - 1)
    return float(np.median(np.max(np.abs(lab[above, start:stop] - lab[below, start:stop]) / spread, axis=1)))


def _segments(standing: np.ndarray, top: np.ndarray, bottom: np.ndarray, min_px: int = 2
              ) -> list[tuple[int, int]]:
    """Runs of standing columns, split where the top jumps by more than a quarter of the thing's height (a person
    in front of a barrier, a post beside a car): (first column, one past the last)."""
    out = []
    u, w = 0, len(standing)
    while u < w:
        if not standing[u]:
            u += 1
            continue
        start = u
        while u + 1 < w and standing[u + 1] and abs(top[u + 1] - top[u]) <= max(
                4.0, 0.25 * (bottom[u] - min(top[u], top[u + 1]))):
            u += 1
        u += 1
        if u - start >= min_px:
            out.append((start, u))
    return out


def detect_car(image: Image, camera: PinholeCamera | None, config: ObstacleConfig = ObstacleConfig(),
               things: list[Upright] | None = None) -> list[Detection]:
    """An upright thing in the kart's corridor, as wide on the ground as a car (:func:`upright_things`), where
    its foot places it to a tenth of its distance (``foot_row_share``); needs the camera's mount."""
    if camera is None or image.ndim != 3:
        return []
    things = upright_things(image, camera, config) if things is None else things
    out = []
    corridor = config.corridor_half_width_m
    farthest = _placed_reach_m(camera_for_image(camera, image.shape[1], image.shape[0]), config)
    for t in _side_by_side(things, config):
        if not (0 < t.distance_m <= min(config.max_distance_m, farthest) and config.min_car_width_m <= t.width_m
                <= config.max_car_width_m) or min(t.left_m, t.right_m) > corridor or max(t.left_m,
                                                                                      t.right_m) < -corridor:
            continue
        if t.height_m < config.min_car_height_m and not t.top_clipped:
            continue
        if _red_share(image, t.box_px) >= 0.2:
            continue  # a red-and-white barrier in the lane: upright and as wide, but not a car
        confidence = min(1.0, t.width_m / 1.6) * min(1.0, t.height_m / 1.2)
        out.append(Detection("car", t.box_px, float(confidence), distance_m=t.distance_m,
                             lateral_m=(t.left_m + t.right_m) / 2))
    return out


def _placed_reach_m(cam: PinholeCamera, config: ObstacleConfig) -> float:
    """How far ahead (body frame) a thing's foot is placed to ``foot_row_share`` of its distance from the camera
    (``cam`` fits the image's size): one row of the upright-thing finder's image spans ``depth**2 / (height *
    focal)`` of ground there."""
    return float(cam.pose_body_cam_array[0, 3]) + config.foot_row_share * float(cam.pose_body_cam_array[2, 3]) * min(
        cam.fy_px, config.stixel_focal_px)


def _side_by_side(things: list[Upright], config: ObstacleConfig, foot_share: float = 0.1) -> list[Upright]:
    """Upright things whose columns touch and whose feet stand at the same distance (within ``foot_share``) as
    one, while it is no wider than a car: one thing, split where its top jumped. The real inflatable car 6.8 m
    ahead, its frame darkened to 0.6, was two things 0.7 and 0.9 m wide, its top broken in one column, and no car.
    A thing in front of another (a person before a car) stands nearer, and a person's shape beside a car is a
    person: both stay apart."""
    out: list[Upright] = []
    for t in sorted(things, key=lambda t: t.box_px[0]):
        last = out[-1] if out else None
        if (last is not None and t.box_px[0] <= last.box_px[2]
                and abs(t.distance_m - last.distance_m) <= foot_share * min(t.distance_m, last.distance_m)
                and abs(min(t.right_m, last.right_m) - max(t.left_m, last.left_m)) <= config.max_car_width_m
                and _person_fit(t, config) is None and _person_fit(last, config) is None):
            out[-1] = Upright((last.box_px[0], min(last.box_px[1], t.box_px[1]), t.box_px[2],
                               max(last.box_px[3], t.box_px[3])), min(last.distance_m, t.distance_m),
                              max(last.left_m, t.left_m), min(last.right_m, t.right_m),
                              max(last.height_m, t.height_m), last.top_clipped or t.top_clipped)
        else:
            out.append(t)
    return out


def _red_share(image: Image, box: tuple[float, float, float, float]) -> float:
    x0, y0 = max(int(box[0]), 0), max(int(box[1]), 0)
    patch = image[y0:max(int(box[3]), y0 + 1), x0:max(int(box[2]), x0 + 1)]
    if patch.size == 0:
        return 0.0
    return float(np.count_nonzero(red_mask(cv2.cvtColor(patch, cv2.COLOR_BGR2HSV), 110, 60))) / (
        patch.shape[0] * patch.shape[1])


def detect_standing_people(image: Image, camera: PinholeCamera | None, config: ObstacleConfig = ObstacleConfig(),
                           things: list[Upright] | None = None) -> list[Detection]:
    """People as upright things of a person's width and height on the ground (:func:`upright_things`): cheap,
    and it sees people HOG misses (small, side-on, simply drawn), but it knows only a shape's size, so it is held
    to the kart's side of the spectators' fence (``max_lateral_m``) and to a person's height."""
    if camera is None or image.ndim != 3:
        return []
    things = upright_things(image, camera, config) if things is None else things
    reach = _placed_reach_m(camera_for_image(camera, image.shape[1], image.shape[0]), config)
    out = []
    for t in things:
        fit = _person_fit(t, config, reach)
        if fit is not None:
            out.append(Detection("person", t.box_px, float(1.0 - fit), distance_m=t.distance_m,
                                 lateral_m=(t.left_m + t.right_m) / 2))
    return out


def _person_fit(t: Upright, config: ObstacleConfig, reach_m: float = math.inf) -> float | None:
    """How far an upright thing's height is off a person's (a share), where it has a person's width, stands
    where people are reported (and no farther than ``reach_m``, :func:`_placed_reach_m`) and is within
    ``shape_height_tolerance`` of that height; else None."""
    if not (0 < t.distance_m <= min(config.max_distance_m, config.person_max_distance_m, reach_m)
            and abs((t.left_m + t.right_m) / 2) <= config.max_lateral_m
            and config.min_person_width_m <= t.width_m <= config.max_person_width_m):
        return None
    fit = abs(t.height_m / config.person_height_m - 1.0)
    if t.top_clipped:  # the head is above the image: the height seen is the least the person is, so it must be a
        # person's already, and no more than the tallest one's (a trunk or a post cut by the image's top stands
        # metres taller where it is: 3.7 m, 13 m ahead, in sweep event overtake 40009)
        tolerance = config.shape_height_tolerance * config.person_height_m
        fit = 0.0 if abs(t.height_m - config.person_height_m) <= tolerance else 1.0
    return fit if fit <= config.shape_height_tolerance else None


def a_tree_trunk(image: Image, hsv: Image, box: tuple[float, float, float, float], config: ObstacleConfig) -> bool:
    """Whether a person's box (full-image pixels) is a tree's trunk under its crown: foliage in the band above it,
    across it and a width of it to either side, and its middle one colour from top to foot (``trunk_*``)."""
    h, w = image.shape[:2]
    x0, y0, x1, y1 = (round(v) for v in box)
    width = max(x1 - x0, 1)
    band = max(2, round(0.04 * (y1 - y0)))
    above = hsv[max(y0 - band, 0):max(y0, 0), max(x0 - width, 0):min(x1 + width, w)]
    if above.size == 0 or float(np.mean(grass(above))) < config.trunk_foliage_share:
        return False
    middle = image[max(y0, 0):min(y1, h), max(x0 + width // 4, 0):min(x1 - width // 4, w)]
    if middle.shape[0] < 5 or middle.shape[1] < 1:
        return False
    lab = cv2.cvtColor(np.ascontiguousarray(middle), cv2.COLOR_BGR2LAB).astype(np.float32)
    # the top four fifths: at its foot a trunk meets the ground, and the box's last rows mix its bark with the grass,
    # its shadow or the sun on it (a sunlit trunk's foot was 25 levels of lightness off the rest: a person 13 m ahead
    # in sweep event overtake 10532)
    medians = np.array([np.median(part.reshape(-1, 3), axis=0) for part in np.array_split(lab, 5, axis=0)[:4]])
    return float(np.max(np.linalg.norm(medians - medians.mean(axis=0), axis=1))) <= config.trunk_colour_spread


def detect_barriers(image: Image, camera: PinholeCamera | None, config: ObstacleConfig = ObstacleConfig(),
                    planes: ColourPlanes | None = None) -> list[Detection]:
    """Red-and-white barriers standing on the ground: red blobs (a barrier's stripes joined), split where one
    stands behind another, as tall as a barrier where they stand. With the mount, each is placed by its nearest
    foot and reports its farthest (``far_m``: a barrier beside the road shows its inner side, whose foot runs to
    its far end). ``planes``: the frame's, where the caller has them."""
    if image.ndim != 3:
        return []
    h, w = image.shape[:2]
    cam = camera_for_image(camera, w, h) if camera is not None else None
    horizon = horizon_row(cam) if cam is not None else config.horizon * h
    hsv = planes.hsv if planes is not None and planes.hsv is not None else cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    red = red_mask(hsv, 110, 60)
    red = cv2.morphologyEx(red, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    # a striped barrier's red blocks, joined across the white between them
    joined = cv2.morphologyEx(red, cv2.MORPH_CLOSE, np.ones((1, max(3, round(0.03 * w))), np.uint8))
    count, labels, stats, origin = mask_components(joined)
    pieces = [piece for k in range(1, count) for piece in _by_foot(labels, k, tuple(int(v) for v in stats[k][:4]),
                                                                   origin)]
    out = []
    for piece in _join_stripes(pieces):
        x, y, bw, bh = piece.box
        area = int(np.count_nonzero(red[y:y + bh, x:x + bw]))
        if max(bw, bh) < config.barrier_min_px * h or y + bh - 1 <= horizon:
            continue  # too small, or not standing on the ground seen below the horizon (a lamp, a sign's ring)
        if area < 0.25 * bw * bh or bw < 0.2 * bh:
            continue  # a barrier is mostly red, and even end on more than a fifth as wide as tall (not a sliver)
        if cam is None and bw < 1.2 * bh:
            continue  # with no ground to measure on: a barrier seen from the side is longer than tall
        if cam is not None and not config.barrier_height_m[0] <= _height_on_ground(cam, y, y + bh - 1) \
                <= config.barrier_height_m[1]:
            continue  # as tall as a barrier where it stands (seen end on, one is taller than wide in the image)
        pad = max(2, bh // 3)
        around = hsv[max(y - pad, 0):y + bh + pad, max(x - pad, 0):x + bw + pad]
        # its white stripes: unsaturated and bright
        stripes = float(np.mean(cv2.inRange(around, (0, 0, 150), (255, 59, 255)) > 0)) if around.size else 0.0
        box = (float(x), float(y), float(x + bw), float(y + bh - 1))
        found = Detection("barrier", box, min(1.0, 0.5 + 2.0 * stripes))
        if cam is not None:
            near, far = _ends(cam, piece)
            found = replace(place_on_ground([found], cam, (w, h))[0], distance_m=near, far_m=far)
        out.append(found)
    return [d for d in _not_within_another(out) if cam is None or (
        math.isfinite(d.distance_m) and d.distance_m <= config.max_distance_m
        and abs(d.lateral_m) <= config.max_lateral_m)]


def _not_within_another(barriers: list[Detection], slack_px: float = 2.0) -> list[Detection]:
    """The barriers less any whose box lies wholly within a larger one's: a barrier behind a nearer one of its
    height is hidden where the nearer one's box is, so what is seen there is part of the nearer one, split off where
    its foot seemed to jump (a near barrier's stripes, in a rendered frame at gamma 0.7, made a second barrier 12 m
    away inside it, and a parking bay between the two)."""
    def area(box: tuple[float, float, float, float]) -> float:
        return (box[2] - box[0]) * (box[3] - box[1])

    def within(inner: tuple[float, float, float, float], outer: tuple[float, float, float, float]) -> bool:
        return (inner[0] >= outer[0] - slack_px and inner[1] >= outer[1] - slack_px
                and inner[2] <= outer[2] + slack_px and inner[3] <= outer[3] + slack_px)

    return [d for d in barriers if not any(area(e.box_px) > area(d.box_px) and within(d.box_px, e.box_px)
                                           for e in barriers)]


def _ends(camera: PinholeCamera, piece: _Piece) -> tuple[float, float]:
    """How far ahead a barrier's near and far ends stand on the ground: the nearest and the farthest tenth of its
    feet, column by column, placed on the ground (a barrier beside the road shows its inner side, whose foot runs
    to its far end; a few columns' stray foot, where it meets another blob or its side lies in shadow, does not
    move either end)."""
    ahead = ground_points(camera, np.column_stack([piece.cols + 0.5, piece.feet + 0.5]))[:, 0]
    if not np.isfinite(ahead).any():
        return math.nan, math.nan
    return float(np.nanpercentile(ahead, 10)), float(np.nanpercentile(ahead, 90))


class _Piece(NamedTuple):
    """Part of a red blob: its (x, y, w, h) box, and its columns with each one's lowest pixel (its foot)."""

    box: tuple[int, int, int, int]
    cols: np.ndarray
    feet: np.ndarray


def _by_foot(labels: np.ndarray, k: int, box: tuple[int, ...], origin: tuple[int, int] = (0, 0)) -> list[_Piece]:
    """Component ``k`` split where its foot (its lowest row, column by column) jumps: a barrier behind another,
    seen over its end, touches it in the image but stands farther up on the ground. ``labels`` and ``box`` are of
    a box of the image whose top-left is ``origin``; the pieces are the image's."""
    x, y, bw, bh = box
    mask = labels[y:y + bh, x:x + bw] == k
    seen = mask.any(axis=0)
    foot = bh - 1 - np.argmax(mask[::-1], axis=0)
    head = np.argmax(mask, axis=0)
    out = []
    start = 0
    for c in range(1, bw + 1):
        if c < bw and seen[c] and seen[c - 1] and abs(int(foot[c]) - int(foot[c - 1])) <= max(3, 0.1 * bh):
            continue
        cols = np.flatnonzero(seen[start:c]) + start
        if len(cols):
            top, bottom = int(head[cols].min()), int(foot[cols].max())
            out.append(_Piece((origin[0] + x + int(cols[0]), origin[1] + y + top, int(cols[-1] - cols[0] + 1),
                               bottom - top + 1), origin[0] + x + cols, origin[1] + y + foot[cols]))
        start = c
    return out


def _join_stripes(pieces: list[_Piece]) -> list[_Piece]:
    """Pieces side by side joined: level with each other (overlapping over 70 % of the taller one's height: a
    barrier's stripes are as tall as each other, a farther barrier behind a near one is not) and apart by less
    than 0.6 of the taller one's height. A near barrier's red stripes lie farther apart than the fixed closing
    joins; a barrier's stripes are narrower than it is tall."""
    out = list(pieces)
    merged = True
    while merged:
        merged = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                (x0, y0, w0, h0), (x1, y1, w1, h1) = out[i].box, out[j].box
                level = min(y0 + h0, y1 + h1) - max(y0, y1) >= 0.7 * max(h0, h1)
                gap = max(x0, x1) - min(x0 + w0, x1 + w1)
                if level and gap <= 0.6 * max(h0, h1):
                    left, top = min(x0, x1), min(y0, y1)
                    box = (left, top, max(x0 + w0, x1 + w1) - left, max(y0 + h0, y1 + h1) - top)
                    out[i] = _Piece(box, np.r_[out[i].cols, out[j].cols], np.r_[out[i].feet, out[j].feet])
                    del out[j]
                    merged = True
                    break
            if merged:
                break
    return out


def find_parking_bay(barriers: list[Detection], camera: PinholeCamera | None, min_length_m: float = 2.0,
                     max_length_m: float = 15.0, max_bend_deg: float = 30.0) -> list[Detection]:
    """The bay between two barriers on the same side, the next one behind the other: a ``parking_bay`` whose
    state is its free length in metres (as text), from the near barrier's far end (its farthest foot) to the
    next one's near end, and whose distance is where it begins. Needs the barriers placed on the ground.

    The same side: the line from one to the next turns less than ``max_bend_deg`` from the kart's heading (the
    road may bend between them: by a kart's side offset, barriers on the same side 9 m apart in a bend differ by
    2 m or more; barriers across the road from each other lie square to it). A free length over
    ``max_length_m`` is road between two barriers, not a bay.

    The bay's line (its ``lateral_m``) is the middle of the two barriers' places, less any barrier whose box the
    image's side cuts (its place is then the visible part's: a near barrier beside the road leaving the view
    seemed to come 0.7 m nearer the kart's line as its outer part went out)."""
    if camera is None:
        return []
    width_px = camera.width_px

    def whole(d: Detection, edge_px: float = 1.0) -> bool:
        return d.box_px[0] > edge_px and d.box_px[2] < width_px - 1 - edge_px

    placed = [b for b in barriers if math.isfinite(b.distance_m)]
    slope = math.tan(math.radians(max_bend_deg))
    out = []
    for a in placed:
        start = a.far_m if math.isfinite(a.far_m) else a.distance_m
        beyond = [b for b in placed if b.distance_m > start
                  and abs(a.lateral_m - b.lateral_m) <= slope * (b.distance_m - a.distance_m)]
        if not beyond:
            continue
        b = min(beyond, key=lambda d: d.distance_m)
        free = b.distance_m - start
        if min_length_m <= free <= max_length_m:
            box = (min(a.box_px[0], b.box_px[0]), min(a.box_px[1], b.box_px[1]), max(a.box_px[2], b.box_px[2]),
                   max(a.box_px[3], b.box_px[3]))
            placed_whole = [d.lateral_m for d in (a, b) if whole(d)] or [a.lateral_m, b.lateral_m]
            out.append(Detection("parking_bay", box, min(a.confidence, b.confidence), f"{free:.1f}",
                                 distance_m=start, lateral_m=float(np.mean(placed_whole))))
    return out


def horizon_row(camera: PinholeCamera) -> float:
    """The row where the ground at a great distance ahead appears."""
    far = transform_points(invert_pose(camera.pose_body_cam_array), np.array([[1.0e4, 0.0, 0.0]]))
    return float(camera.project(far)[0, 1])


def ground_row(camera: PinholeCamera, ahead_m: float) -> float:
    """The image row of the ground ``ahead_m`` in front of the camera, on the kart's centre line; NaN where that
    ground is not in front of it."""
    x = float(camera.pose_body_cam_array[0, 3]) + ahead_m
    point = transform_points(invert_pose(camera.pose_body_cam_array), np.array([[x, 0.0, 0.0]]))
    return float(camera.project(point)[0, 1]) if point[0, 2] > 0 else math.nan


def _height_on_ground(camera: PinholeCamera, top: float, bottom: float) -> float:
    """The height in metres of a thing standing on the ground whose image runs from row ``top`` down to row
    ``bottom`` (its foot), at the distance its foot gives; NaN where the foot is above the horizon."""
    ahead = _ground_ahead(camera, camera.cx_px, bottom)
    depth = ahead - float(camera.pose_body_cam_array[0, 3])
    return (bottom - top) * depth / camera.fy_px if depth > 0 else math.nan


def _ground_ahead(camera: PinholeCamera, u: float, v: float) -> float:
    return float(ground_points(camera, np.array([[u, v]]))[0, 0])

"""Things standing on the track: people (OpenCV's HOG people detector), a car in the lane, barriers, a parking bay.

Each stands on the ground, so each is placed where its box's bottom meets the ground (the camera's mount), and each
is checked against that place: a thing that does not concern the kart is not reported.

- **People**: OpenCV's HOG people detector (Dalal and Triggs), shipped with OpenCV. A box counts only if a person
  standing where its bottom meets the ground would be that tall in the image (``person_height_m``, within
  ``height_tolerance``): a tall box on a near point is a lamp post, a short one a bag. People beyond
  ``max_lateral_m`` from the kart's line (behind a spectator fence) are not reported.
- **Car**: something upright in the kart's corridor (``corridor_half_width_m`` either side of its line, ahead
  to ``max_distance_m``): a blob that is not asphalt (its colour far from the road's own, measured in the
  image's lower middle) and not grass, standing on the ground in the corridor and reaching the horizon row (a
  thing taller than the camera; paint on the ground never does), at least ``min_car_width_m`` wide on the ground.
- **Barrier**: a strongly red blob standing on the ground (its bottom below the horizon) with white beside it in
  its box (the red-and-white stripes); a lit lamp is small and high, a sign's ring is high, so neither is one.
- **Parking bay**: two barriers on the same side, one behind the other: the bay is the ground between them, its
  free length the gap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from kartpilot.calibration.ground import ground_points
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import invert_pose, transform_points
from kartpilot.core.types import Image
from kartpilot.perception.objects import Detection, place_on_ground
from kartpilot.perception.road_marks import camera_for_image

__all__ = ["ObstacleConfig", "detect_barriers", "detect_car", "detect_people", "find_parking_bay", "horizon_row"]


@dataclass(frozen=True)
class ObstacleConfig:
    """Attributes:
        horizon: the horizon's row as a fraction of the height (used without a camera mount).
        person_height_m, height_tolerance: a standing person's height, and how far a box may be off it (a share).
        min_person_px: the least box height searched (fraction of the image's height; HOG's window is 128 px,
            so the image is scaled up to find smaller people, at a cost).
        hog_threshold: the least HOG score (the SVM's margin) a box needs.
        max_lateral_m: people and barriers farther than this from the kart's line are not reported.
        max_distance_m: nothing farther than this ahead is reported.
        corridor_half_width_m: the kart's corridor for a car: this far either side of its line.
        min_car_width_m, max_car_width_m: the width on the ground of an upright thing in the corridor that is a
            car (wider: the far end of the venue, its barriers, cars and fences run together at the horizon).
        colour_sigmas: a pixel is not asphalt when its colour is this many robust deviations from the road's.
        barrier_min_px: a barrier's least size (fraction of the image's height).
    """

    horizon: float = 0.34
    person_height_m: float = 1.75
    height_tolerance: float = 0.35
    min_person_px: float = 0.2
    hog_threshold: float = 0.3
    max_lateral_m: float = 6.0
    max_distance_m: float = 30.0
    corridor_half_width_m: float = 1.3
    min_car_width_m: float = 0.8
    max_car_width_m: float = 3.0
    colour_sigmas: float = 6.0
    barrier_min_px: float = 0.02

    def __post_init__(self) -> None:
        if not 0 < self.height_tolerance < 1 or min(self.person_height_m, self.max_lateral_m,
                                                    self.max_distance_m, self.corridor_half_width_m) <= 0:
            raise ConfigError("obstacles: height_tolerance must be in (0, 1) and the sizes positive")


_HOG: cv2.HOGDescriptor | None = None


def _hog() -> cv2.HOGDescriptor:
    global _HOG
    if _HOG is None:
        _HOG = cv2.HOGDescriptor()
        _HOG.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())
    return _HOG


def detect_people(image: Image, camera: PinholeCamera | None, config: ObstacleConfig = ObstacleConfig()
                  ) -> list[Detection]:
    """People standing on the ground, with their place; without a camera mount, every box HOG is sure of."""
    h, w = image.shape[:2]
    scale = max(1.0, 128.0 / (config.min_person_px * h))
    search = image if scale == 1.0 else cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
    boxes, weights = _hog().detectMultiScale(search, winStride=(8, 8), padding=(8, 8), scale=1.08)
    if len(boxes) == 0:
        return []
    kept = cv2.dnn.NMSBoxes([list(map(int, b)) for b in boxes], [float(s) for s in np.ravel(weights)],
                            config.hog_threshold, 0.4)
    out = []
    for k in np.ravel(kept):
        x, y, bw, bh = (float(v) / scale for v in boxes[int(k)])
        # HOG's window has a margin around the person: about an eighth of its height above and below
        box = (x + 0.1 * bw, y + 0.06 * bh, x + 0.9 * bw, y + 0.94 * bh)
        score = float(np.ravel(weights)[int(k)])
        out.append(Detection("person", box, float(1.0 - math.exp(-score)), source="classical"))
    return [d for d in place_on_ground(out, camera, (w, h)) if _plausible_person(d, camera, w, h, config)]


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


def _asphalt_model(lab: Image, h: int, w: int, top: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The road's colour (median) and spread (MAD per channel) from the image's lower middle (``lab``: the image
    from row ``top`` down)."""
    patch = lab[int(0.8 * h) - top:, int(0.35 * w):int(0.65 * w)].reshape(-1, 3).astype(np.float32)
    median = np.median(patch, axis=0)
    mad = np.median(np.abs(patch - median), axis=0)
    return median, np.maximum(1.4826 * mad, 2.0)


def detect_car(image: Image, camera: PinholeCamera | None, config: ObstacleConfig = ObstacleConfig()
               ) -> list[Detection]:
    """An upright thing in the kart's corridor (a stationary car): needs the camera's mount. Looked for at half
    the image's size (a car is large; a quarter of the pixels is a quarter of the cost), reported in the image's
    pixels."""
    if camera is None or image.ndim != 3:
        return []
    full_h, full_w = image.shape[:2]
    if min(full_h, full_w) >= 240:
        image = cv2.resize(image, (full_w // 2, full_h // 2), interpolation=cv2.INTER_AREA)
    h, w = image.shape[:2]
    sx, sy = full_w / w, full_h / h
    cam = camera_for_image(camera, w, h)
    horizon = horizon_row(cam)
    # only the image below the horizon is looked at: a car is found by its part there (above: sky and trees)
    top = min(max(int(horizon), 0), h - 8)
    band = image[max(top - 3, 0):]  # a few rows more, so the blur at the band's top sees what the full image's did
    lab = cv2.cvtColor(cv2.GaussianBlur(band, (5, 5), 0), cv2.COLOR_BGR2LAB).astype(np.float32)[top - max(
        top - 3, 0):]
    _, spread = _asphalt_model(lab, h, w, top)
    # the road's colour row by row (it pales with distance): each row's median, a car covering less than half
    # of it; smoothed over rows
    rows = cv2.blur(np.median(lab, axis=1)[:, None, :], (1, 15))[:, 0, :]
    distance = np.max(np.abs(lab - rows[:, None, :]) / spread, axis=2)
    hsv = cv2.cvtColor(image[top:], cv2.COLOR_BGR2HSV)
    grass = (hsv[..., 0] >= 30) & (hsv[..., 0] <= 90) & (hsv[..., 1] >= 50)
    thing = np.zeros((h, w), np.uint8)
    thing[top:] = (distance > config.colour_sigmas) & ~grass
    thing = cv2.morphologyEx(thing, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    count, _, stats, _ = cv2.connectedComponentsWithStats(thing, connectivity=8)
    out = []
    for k in range(1, count):
        x, y, bw, bh, _ = (int(v) for v in stats[k])
        if y > horizon + 1 or y + bh - 1 <= horizon + 2:
            continue  # it must reach the horizon (taller than the camera) and stand below it
        if bw > 0.6 * w or (x == 0 and x + bw >= w):
            continue  # the road's own change of shade across the image, not a thing on it
        det = place_on_ground([Detection("car", (x, y, x + bw, y + bh - 1), 0.0)], cam, (w, h))[0]
        if not (math.isfinite(det.distance_m) and 0 < det.distance_m <= config.max_distance_m):
            continue
        left, right = _ground_lateral(cam, x, y + bh - 1), _ground_lateral(cam, x + bw, y + bh - 1)
        width_m = abs(left - right)
        corridor = config.corridor_half_width_m
        if not config.min_car_width_m <= width_m <= config.max_car_width_m or min(left, right) > corridor or max(
                left, right) < -corridor:
            continue
        confidence = min(1.0, width_m / 1.6) * min(1.0, bh / max(0.15 * h, 1.0))
        left_px, top_px, right_px, bottom_px = det.box_px
        out.append(replace(det, confidence=float(confidence),
                           box_px=(left_px * sx, top_px * sy, right_px * sx, bottom_px * sy)))
    return out


def detect_barriers(image: Image, camera: PinholeCamera | None, config: ObstacleConfig = ObstacleConfig()
                    ) -> list[Detection]:
    """Red-and-white barriers standing on the ground."""
    if image.ndim != 3:
        return []
    h, w = image.shape[:2]
    cam = camera_for_image(camera, w, h) if camera is not None else None
    horizon = horizon_row(cam) if cam is not None else config.horizon * h
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    hue, sat, val = cv2.split(hsv)
    red = (((hue <= 10) | (hue >= 165)) & (sat >= 110) & (val >= 60)).astype(np.uint8)
    white = (sat < 60) & (val >= 150)
    red = cv2.morphologyEx(red, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    # a striped barrier's red blocks, joined across the white between them
    joined = cv2.morphologyEx(red, cv2.MORPH_CLOSE, np.ones((1, max(3, round(0.03 * w))), np.uint8))
    count, _, stats, _ = cv2.connectedComponentsWithStats(joined, connectivity=8)
    out = []
    for k in range(1, count):
        x, y, bw, bh, _ = (int(v) for v in stats[k])
        area = int(np.count_nonzero(red[y:y + bh, x:x + bw]))
        if max(bw, bh) < config.barrier_min_px * h or y + bh - 1 <= horizon:
            continue  # too small, or not standing on the ground seen below the horizon (a lamp, a sign's ring)
        if bw < 1.2 * bh or area < 0.25 * bw * bh:
            continue  # a barrier is longer than tall, and mostly red
        pad = max(2, bh // 3)
        around = white[max(y - pad, 0):y + bh + pad, max(x - pad, 0):x + bw + pad]
        stripes = float(np.mean(around)) if around.size else 0.0
        confidence = min(1.0, 0.5 + 2.0 * stripes)
        out.append(Detection("barrier", (float(x), float(y), float(x + bw), float(y + bh - 1)), confidence))
    placed = place_on_ground(out, cam, (w, h)) if cam is not None else out
    return [d for d in placed if cam is None or (math.isfinite(d.distance_m) and d.distance_m <= config.max_distance_m
                                                 and abs(d.lateral_m) <= config.max_lateral_m)]


def find_parking_bay(barriers: list[Detection], camera: PinholeCamera | None, image_size_wh: tuple[int, int],
                     min_length_m: float = 2.0, same_side_m: float = 1.0) -> list[Detection]:
    """The bay between two barriers on the same side, one behind the other: a ``parking_bay`` whose state is its
    free length in metres (as text) and whose distance is where it begins."""
    if camera is None:
        return []
    cam = camera_for_image(camera, *image_size_wh)
    placed = [b for b in barriers if math.isfinite(b.distance_m)]
    out = []
    for a in placed:
        for b in placed:
            if not a.distance_m < b.distance_m or abs(a.lateral_m - b.lateral_m) > same_side_m:
                continue
            near_end = _ground_ahead(cam, a.box_px[2] if a.lateral_m < 0 else a.box_px[0], a.box_px[3])
            free = b.distance_m - near_end
            if free >= min_length_m:
                box = (min(a.box_px[0], b.box_px[0]), min(a.box_px[1], b.box_px[1]), max(a.box_px[2], b.box_px[2]),
                       max(a.box_px[3], b.box_px[3]))
                out.append(Detection("parking_bay", box, min(a.confidence, b.confidence), f"{free:.1f}",
                                     distance_m=near_end, lateral_m=(a.lateral_m + b.lateral_m) / 2))
    return out


def horizon_row(camera: PinholeCamera) -> float:
    """The row where the ground at a great distance ahead appears."""
    far = transform_points(invert_pose(camera.pose_body_cam_array), np.array([[1.0e4, 0.0, 0.0]]))
    return float(camera.project(far)[0, 1])


def _ground_lateral(camera: PinholeCamera, u: float, v: float) -> float:
    return float(ground_points(camera, np.array([[u, v]]))[0, 1])


def _ground_ahead(camera: PinholeCamera, u: float, v: float) -> float:
    return float(ground_points(camera, np.array([[u, v]]))[0, 0])

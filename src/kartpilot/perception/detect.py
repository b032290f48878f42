"""The event's objects in one call: the classical detectors, a team's ONNX model, or both; placed and tracked.

``detector`` names what runs: ``classical`` (colour, shape and ground geometry, :mod:`signals`,
:mod:`road_marks`, :mod:`obstacles`), ``onnx:MODEL.onnx`` (a team's model in their place, with ``classes``
the YAML mapping its class ids, :mod:`onnx_detector`) or ``classical+onnx:MODEL.onnx`` (both). Every detection
is placed on the ground through the camera's mount where it stands on the ground (a person, a car, a barrier,
a road mark) and by its known size where it does not (a lamp, a sign); a person's state says whether they stand
on a zebra crossing the kart sees, or beside it. :class:`ObjectDetector` holds the model and the tracker that
gives each object an id over frames.

Costs on one core at 848x480 are measured by ``benchmarks/detect.py``. With the camera's mount, the HOG people
detector looks only around the upright things the car and the people's shapes are found from; without one it
searches the whole image at every scale and is most of the cost, which is why ``people`` can be turned off.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError, PerceptionError
from kartpilot.core.types import Image
from kartpilot.perception.colour import ColourPlanes
from kartpilot.perception.objects import (
    CROSSING_DEPTH_M,
    Detection,
    ObjectTracker,
    TrackerConfig,
    box_iou,
    place_on_ground,
)
from kartpilot.perception.obstacles import (
    ObstacleConfig,
    Upright,
    a_tree_trunk,
    detect_barriers,
    detect_car,
    detect_people,
    detect_standing_people,
    find_parking_bay,
    horizon_row,
    upright_things,
)
from kartpilot.perception.onnx_detector import OnnxDetector, load_class_map
from kartpilot.perception.road_marks import RoadMarkConfig, camera_for_image, detect_road_marks
from kartpilot.perception.signals import SignalConfig, detect_signals, place_by_size
from kartpilot.sensors.base import MIN_IMAGE_PX

__all__ = ["DetectorConfig", "GroundCar", "ObjectDetector", "crossing_states", "detect_classical", "merge_people",
           "part_of_barrier", "part_of_car"]


@dataclass(frozen=True)
class DetectorConfig:
    """Attributes:
        detector: ``classical``, ``onnx:MODEL.onnx`` or ``classical+onnx:MODEL.onnx``.
        classes: the YAML file mapping the ONNX model's class ids to kartpilot's classes.
        people: run the HOG people detector (the classical detectors' slowest part).
        beside_crossing_m: a person this close to a zebra's ends or sides (on the ground) is beside it.
        car_memory_frames: a car found in one of this many frames before is still where it was on the ground
            (moved back by the kart's travel, where the caller says it): a person's shape standing in its width and
            depth there is the car's edge (:func:`part_of_car`, :class:`GroundCar`; 0: this frame's cars only).
    """

    detector: str = "classical"
    classes: str = ""
    people: bool = True
    beside_crossing_m: float = 2.5
    car_memory_frames: int = 30
    signals: SignalConfig = field(default_factory=SignalConfig)
    road_marks: RoadMarkConfig = field(default_factory=RoadMarkConfig)
    obstacles: ObstacleConfig = field(default_factory=ObstacleConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)

    def __post_init__(self) -> None:
        classical, model = self.parts
        if not classical and not model:
            raise ConfigError(f"detector {self.detector!r}: use classical, onnx:MODEL.onnx or "
                              "classical+onnx:MODEL.onnx")
        if self.car_memory_frames < 0:
            raise ConfigError(f"detector: car_memory_frames must not be negative, got {self.car_memory_frames}")
        if model and not self.classes:
            raise ConfigError(f"detector {self.detector!r} needs the classes YAML that maps the model's class ids "
                              "(--classes)")

    @property
    def parts(self) -> tuple[bool, str]:
        """(whether the classical detectors run, the ONNX model's path or '')."""
        classical, model = False, ""
        for part in self.detector.split("+"):
            if part == "classical":
                classical = True
            elif part.startswith("onnx:") and len(part) > 5:
                model = part[5:]
            else:
                return False, ""
        return classical, model


@dataclass(frozen=True)
class GroundCar:
    """Where a car found in an earlier frame stands on the ground, in the body frame now: its back's distance
    ahead, its middle's offset to the left and half its width (metres)."""

    distance_m: float
    lateral_m: float
    half_width_m: float

    @classmethod
    def of(cls, car: Detection, camera: PinholeCamera) -> GroundCar | None:
        """A car detection on the ground (None where it is not placed); its width from its box at its distance."""
        if not (math.isfinite(car.distance_m) and math.isfinite(car.lateral_m)):
            return None
        depth = car.distance_m - float(camera.pose_body_cam_array[0, 3])  # from the camera, along its axis
        return cls(car.distance_m, car.lateral_m, 0.5 * car.width_px * max(depth, 0.0) / camera.fx_px)

    def holds(self, person: Detection) -> bool:
        """Whether a person's shape stands in the car: within its width (and a quarter metre) across, and from
        its back to 2.5 m beyond it along (a tenth of the distance nearer at most: a foot row's placement)."""
        along = person.distance_m - self.distance_m
        return (abs(person.lateral_m - self.lateral_m) <= self.half_width_m + 0.25
                and -max(0.5, 0.1 * self.distance_m) <= along <= 2.5)


def detect_classical(image: Image, camera: PinholeCamera | None, config: DetectorConfig = DetectorConfig(),
                     recent_cars: Sequence[GroundCar] = ()) -> list[Detection]:
    """Every classical detector on one image, placed on the ground where the camera's mount is known.
    ``recent_cars``: the cars found in the frames just before, where they stand now (:func:`part_of_car`)."""
    if image.ndim not in (2, 3) or min(image.shape[:2]) < MIN_IMAGE_PX:
        raise PerceptionError(f"an image of {image.shape} is too small to look for objects in (at least "
                              f"{MIN_IMAGE_PX} px a side)")
    signals = config.signals
    if camera is not None:
        # a camera of another shape is refused here, naming the image's own size (the detectors that work at a
        # reduced size would name theirs)
        camera_for_image(camera, image.shape[1], image.shape[0])
        # the horizon and the camera's height from its mount, not the defaults' kart
        signals = replace(signals, camera_height_m=float(camera.pose_body_cam_array[2, 3]),
                          horizon=min(max(horizon_row(camera) / camera.height_px, 0.0), 1.0))
    planes = ColourPlanes.of(image)  # converted once, read by several detectors
    out = detect_signals(image, signals, camera, planes)
    things = upright_things(image, camera, config.obstacles) if camera is not None and image.ndim == 3 else []
    barriers = detect_barriers(image, camera, config.obstacles, planes)
    # a barrier in the corridor stands upright too: it is not a car
    cars = [c for c in detect_car(image, camera, config.obstacles, things)
            if not any(_covered(c.box_px, b.box_px) for b in barriers)]
    people = [p for p in detect_standing_people(image, camera, config.obstacles, things)
              if not any(part_of_car(p.box_px, car.box_px) for car in cars)
              and not any(part_of_barrier(p.box_px, barrier.box_px) for barrier in barriers)
              and not any(car.holds(p) for car in recent_cars if math.isfinite(p.distance_m))]
    if config.people:  # HOG's people, and the upright shapes it did not find
        hog = detect_people(image, camera, config.obstacles, things)
        if camera is not None and image.ndim == 3:
            hog = [p for p in hog if _stands_under(p.box_px, things)]
        people = merge_people(hog, people)
    # red on a car (its plate, its lights) is not a barrier
    barriers = [b for b in barriers if not any(_inside(b.box_px, c.box_px) for c in cars)]
    people = [p for p in people if not any(_covered(p.box_px, b.box_px) for b in barriers)]
    # a signal head or a sign on its pole is as tall and as thin as a person, and so is its pole alone
    people = [p for p in people if not any(_inside(d.box_px, p.box_px) or _under(p.box_px, d.box_px) for d in out
                                            if d.label in ("traffic_light", "speed_sign"))]
    # and a tree's trunk under its crown is as tall, thin and still as a person waiting beside a crossing (the kart
    # waited for one for good): foliage above it, and one colour from its top to its foot
    if planes.hsv is not None:
        people = [p for p in people if not a_tree_trunk(image, planes.hsv, p.box_px, config.obstacles)]
    # what stands on the ground is not paint on it (seen from above, a barrier's white stripes would lie across
    # the road)
    out += detect_road_marks(image, camera, config.road_marks, [d.box_px for d in barriers + cars + people],
                             [t.box_px for t in things], planes)
    out += people + cars + barriers + find_parking_bay(barriers, camera)
    return out


def merge_people(hog: list[Detection], shaped: list[Detection]) -> list[Detection]:
    """HOG's people and the upright shapes it did not find: a shape is the same person as a HOG box that
    overlaps it by a third, or holds half of it (HOG's box has a margin round the person, so round a narrow
    shape the two overlap by less than a third: a rendered person, its frame compressed, was two people)."""
    return hog + [p for p in shaped if not any(box_iou(p.box_px, q.box_px) > 0.3 or _covered(p.box_px, q.box_px)
                                               for q in hog)]


def part_of_car(box: tuple[float, float, float, float], car: tuple[float, float, float, float]) -> bool:
    """Whether an upright shape's ``box`` is a car's edge: its foot on the car's bottom row (within 8 % of the
    car's height, 3 px at least) and within a quarter of the car's width of its sides. Where the middle of a car's
    back is not found upright (in the sun, a plain back), its two sides are each as tall and thin as a person:
    the kart yielded to two people at a car it was to overtake, and stood behind it for good (sweep events 10190,
    10214). A person before the car stands nearer, their foot lower in the image, and stays a person; so does one
    HOG finds (only the shapes it did not find are checked). In the frames after, where the car itself may not be
    found, the car as it stood on the ground says the same (:meth:`GroundCar.holds`)."""
    return _on_foot_row(box, car)


def part_of_barrier(box: tuple[float, float, float, float], barrier: tuple[float, float, float, float]) -> bool:
    """Whether an upright shape's ``box`` is a barrier's end with what stands behind it: its foot on the barrier's
    bottom row and its middle over the barrier (as :func:`part_of_car`). A barrier seen end on is an upright block
    of stripes, and a pole or a trunk behind it carries the shape up to a person's height: the kart yielded 4 s to
    the far barrier of a bay and the lamp post behind it (sweep event parking 10533). A person standing before the
    barrier has their foot lower in the image; one behind it has no foot to see; one HOG finds is not asked."""
    return _on_foot_row(box, barrier)


def _on_foot_row(box: tuple[float, float, float, float], of: tuple[float, float, float, float]) -> bool:
    """``box``'s foot on ``of``'s bottom row (within 8 % of its height, 3 px at least) and its middle within a
    quarter of ``of``'s width of its sides."""
    width, height = of[2] - of[0], of[3] - of[1]
    return (of[0] - width / 4 <= (box[0] + box[2]) / 2 <= of[2] + width / 4
            and abs(box[3] - of[3]) <= max(3.0, 0.08 * height))


def _stands_under(box: tuple[float, float, float, float], things: list[Upright]) -> bool:
    """Whether an upright thing stands under a person's box: under its middle half and reaching up to within a
    quarter of the box's height of its top. A person is taller than the camera, so :func:`upright_things` sees
    one; a box HOG puts round a lower thing (a barrier's stripes) or on bare ground has no such thing under its
    head. The thing may reach higher than the head (a person before a tree)."""
    left, top, right, bottom = box
    quarter_w, quarter_h = (right - left) / 4, (bottom - top) / 4
    return any(t.box_px[0] < right - quarter_w and t.box_px[2] > left + quarter_w
               and t.box_px[1] <= top + quarter_h for t in things)


def _covered(box: tuple[float, float, float, float], by: tuple[float, float, float, float]) -> bool:
    """Half or more of ``box`` lies inside ``by``."""
    w = max(0.0, min(box[2], by[2]) - max(box[0], by[0]))
    h = max(0.0, min(box[3], by[3]) - max(box[1], by[1]))
    return w * h >= 0.5 * max((box[2] - box[0]) * (box[3] - box[1]), 1e-9)


def _inside(inner: tuple[float, float, float, float], outer: tuple[float, float, float, float]) -> bool:
    cx, cy = (inner[0] + inner[2]) / 2, (inner[1] + inner[3]) / 2
    return outer[0] <= cx <= outer[2] and outer[1] <= cy <= outer[3]


def _under(box: tuple[float, float, float, float], signal: tuple[float, float, float, float]) -> bool:
    """``box`` stands under a light or a sign: its middle column within the signal's, its top below the signal's
    top and no more than two of the signal's heights below its bottom. It is the signal's pole: its thin middle
    breaks the column below the head, and the tripod's legs make the rest as wide and tall as a person (the
    venue's signal in scene 1, seen a fifth nearer, was a person 17 m ahead)."""
    middle, height = (box[0] + box[2]) / 2, signal[3] - signal[1]
    return signal[0] <= middle <= signal[2] and signal[1] < box[1] <= signal[3] + 2.0 * height


def crossing_states(detections: list[Detection], beside_m: float) -> list[Detection]:
    """Each person's state against the zebra crossings found with them: ``on_crossing`` where they stand on
    one (on the ground), ``beside_crossing`` within ``beside_m`` of it, else unchanged."""
    zebras = [d for d in detections if d.label == "crosswalk" and math.isfinite(d.distance_m)]
    if not zebras:
        return detections
    out = []
    for d in detections:
        if d.label == "person" and math.isfinite(d.distance_m):
            for z in zebras:
                along = z.distance_m - beside_m <= d.distance_m <= z.distance_m + CROSSING_DEPTH_M + beside_m
                if z.distance_m <= d.distance_m <= z.distance_m + CROSSING_DEPTH_M and abs(d.lateral_m) <= 2.5:
                    d = replace(d, state="on_crossing")
                    break
                if along and abs(d.lateral_m) <= 2.5 + beside_m:
                    d = replace(d, state="beside_crossing")
        out.append(d)
    return out


class ObjectDetector:
    """The configured detectors with their state between frames: the ONNX session and the tracker."""

    def __init__(self, config: DetectorConfig | None = None, camera: PinholeCamera | None = None) -> None:
        self.config = config = config or DetectorConfig()
        self.camera = camera
        classical, model = config.parts
        self.classical = classical
        self.model = OnnxDetector(Path(model), load_class_map(config.classes)) if model else None
        self.tracker = ObjectTracker(config.tracker)
        self._cars: deque[list[GroundCar]] = deque(maxlen=config.car_memory_frames)

    def reset(self) -> None:
        """A new scene: tracks do not carry over."""
        self.tracker.reset()
        self._cars.clear()

    def __call__(self, image: Image, moved_m: float = math.inf) -> list[Detection]:
        """The objects in the next frame; ``moved_m``: how far the kart went straight ahead since the frame before
        (unknown: infinite, and the cars of earlier frames are forgotten)."""
        if image is None or image.size == 0:
            raise ConfigError("the object detector was given an empty image")
        if not math.isfinite(moved_m):
            self._cars.clear()
        else:  # the cars seen before, where they stand now
            for cars in self._cars:
                cars[:] = [replace(c, distance_m=c.distance_m - moved_m) for c in cars]
        recent = [car for cars in self._cars for car in cars]
        found = detect_classical(image, self.camera, self.config, recent) if self.classical else []
        if self._cars.maxlen and self.camera is not None:
            camera = camera_for_image(self.camera, image.shape[1], image.shape[0])
            self._cars.append([g for d in found if d.label == "car" and (g := GroundCar.of(d, camera)) is not None])
        if self.model is not None:
            found += self._place(self.model(image), image)
        found = crossing_states(found, self.config.beside_crossing_m)
        return self.tracker.update(found)

    def _place(self, detections: list[Detection], image: Image) -> list[Detection]:
        """A model's boxes placed as the classical ones are: by size for lamps and signs, on the ground else."""
        size = {"traffic_light": self.config.signals.lamp_diameter_m * 2.5,
                "speed_sign": self.config.signals.sign_diameter_m}
        h, w = image.shape[:2]
        out = []
        for d in detections:
            if d.label in size:
                out.append(place_by_size(d, self.camera, w, size[d.label]))
            else:
                out.extend(place_on_ground([d], self.camera, (w, h)))
        return out

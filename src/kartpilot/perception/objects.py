"""What the event is scored on, as detections: a common result type, their place on the ground, and track ids.

Each detector (traffic lights, speed signs, stop lines, zebra crossings, people, a car in the lane, barriers and
a parking bay; or a team's own ONNX model) returns :class:`Detection` records in image pixels. Where the camera's
mount over the ground is known (the rig's pose from ``kartpilot calibrate ground``), :func:`place_on_ground`
adds where the object stands: the ground point under the middle of its box's bottom edge, in the body frame
(x ahead, y left, metres). :class:`ObjectTracker` gives each object an id that persists over frames.

The detectors are pure functions of an image and their config; the tracker is the only state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from kartpilot.calibration.ground import ground_points
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError

__all__ = ["ACROSS_ROAD", "CLASSES", "CROSSING_DEPTH_M", "Detection", "ObjectTracker", "TrackerConfig", "box_iou",
           "place_on_ground"]

CLASSES = ("traffic_light", "speed_sign", "stop_line", "crosswalk", "person", "car", "barrier", "parking_bay")
"""kartpilot's object classes; a team's model maps its own class ids onto these (``--classes``)."""


CROSSING_DEPTH_M = 3.0
"""A zebra crossing's length along the road: not reported by its detector, the usual crossing's."""
ACROSS_ROAD = ("crosswalk", "stop_line")
"""The classes of paint lying across the road, whose detections report how wide they reach (``width_m``)."""


@dataclass(frozen=True)
class Detection:
    """One object in one image.

    Attributes:
        label: one of :data:`CLASSES`.
        box_px: (left, top, right, bottom) in the image's pixels.
        confidence: 0 to 1, the detector's own.
        state: what the object says: a traffic light's ``red`` or ``green``, a speed sign's value
            (``20`` km/h, as text), a person's ``on_crossing`` or ``beside_crossing``; empty if nothing.
        distance_m: how far ahead it stands on the ground (body x), NaN where the mount or the ground point
            is unknown (the box's bottom above the horizon).
        lateral_m: how far left (+) or right (-) of the kart's centre line it stands (body y), NaN likewise.
        far_m: for a thing that reaches away along the ground (a barrier seen along its side), how far ahead its
            farthest foot stands; NaN where not measured.
        view_to_m: for a thing placed by its size (a signal head, a sign), the least distance ahead (body x) it can
            come to, the kart driving straight at it, with its top still in the camera's view; NaN where not
            measured.
        width_m: for paint across the road (a stop line, a zebra crossing), how far it reaches across on the ground
            from one end to the other, placed through the same mount as ``lateral_m`` (a camera pitched off its
            mount places both short or long by the same share); NaN where not measured.
        track_id: the same object's id over frames (0: not tracked).
        source: which detector found it (``classical`` or the ONNX model's file name).
    """

    label: str
    box_px: tuple[float, float, float, float]
    confidence: float
    state: str = ""
    distance_m: float = math.nan
    lateral_m: float = math.nan
    far_m: float = math.nan
    view_to_m: float = math.nan
    width_m: float = math.nan
    track_id: int = 0
    source: str = "classical"

    def __post_init__(self) -> None:
        if self.label not in CLASSES:
            raise ConfigError(f"unknown object class {self.label!r} (known: {', '.join(CLASSES)})")

    @property
    def bottom_centre_px(self) -> tuple[float, float]:
        left, _, right, bottom = self.box_px
        return (left + right) / 2.0, bottom

    @property
    def height_px(self) -> float:
        return self.box_px[3] - self.box_px[1]

    @property
    def width_px(self) -> float:
        return self.box_px[2] - self.box_px[0]


def place_on_ground(detections: list[Detection], camera: PinholeCamera | None, image_size_wh: tuple[int, int]
                    ) -> list[Detection]:
    """Each detection with ``distance_m`` and ``lateral_m`` from the camera's mount (the ground point under
    its box's bottom centre), and for paint across the road its ``width_m`` (between its box's bottom corners);
    unchanged where there is no camera. An image of another size than the calibration's is scaled to it (the same
    field of view)."""
    if camera is None or not detections:
        return detections
    sx, sy = camera.width_px / image_size_wh[0], camera.height_px / image_size_wh[1]
    pixels = np.array([[x * sx, d.box_px[3] * sy] for d in detections
                       for x in (d.bottom_centre_px[0], d.box_px[0], d.box_px[2])])
    ground = ground_points(camera, pixels).reshape(len(detections), 3, -1)
    return [replace(d, distance_m=float(g[0, 0]), lateral_m=float(g[0, 1]),
                    width_m=float(abs(g[2, 1] - g[1, 1])) if d.label in ACROSS_ROAD else d.width_m)
            for d, g in zip(detections, ground, strict=True)]


def box_iou(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> float:
    """Intersection over union of two (left, top, right, bottom) boxes."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


@dataclass(frozen=True)
class TrackerConfig:
    """Attributes:
        min_iou: a detection continues a track of its class when their boxes overlap at least this much.
        max_missed: frames a track is kept without a detection before it is dropped.
        rejoin_frames, rejoin_m: a detection that continues no track by its box takes up a track of its class
            that found nothing this frame, or was lost at most this many frames ago, where that track was last
            seen within this distance of it on the ground (nearest first). A person who merges with the barrier
            beside them for a second, or whose box jumps as they step out of it, keeps their id, and with it the
            history the rules read (whether they have crossed). 2 m: a walking person's second and the kart's
            creep toward them; two people closer than that may swap ids.
    """

    min_iou: float = 0.2
    max_missed: int = 5
    rejoin_frames: int = 30
    rejoin_m: float = 2.0

    def __post_init__(self) -> None:
        if not 0.0 < self.min_iou <= 1.0 or self.max_missed < 0:
            raise ConfigError("tracker: min_iou must be in (0, 1] and max_missed not negative")
        if self.rejoin_frames < 0 or self.rejoin_m < 0:
            raise ConfigError("tracker: rejoin_frames and rejoin_m must not be negative")


@dataclass
class _Track:
    track_id: int
    label: str
    box: tuple[float, float, float, float]
    ground_m: tuple[float, float] = (math.nan, math.nan)
    missed: int = 0


@dataclass
class ObjectTracker:
    """Ids that persist over frames: each detection continues the overlapping track of its class (greedy, best
    overlap first); one that overlaps none takes up the nearest track of its class on the ground that found
    nothing this frame (within ``rejoin_m``, lost at most ``rejoin_frames`` ago), or starts a new one. A track
    unseen for ``max_missed`` frames no longer continues by its box. Call :meth:`reset` where a frame does not
    follow from the one before (a new scene)."""

    config: TrackerConfig = field(default_factory=TrackerConfig)
    _tracks: list[_Track] = field(default_factory=list)
    _next_id: int = 1

    def reset(self) -> None:
        self._tracks = []

    def update(self, detections: list[Detection]) -> list[Detection]:
        pairs = sorted(((box_iou(d.box_px, t.box), i, k) for i, d in enumerate(detections)
                        for k, t in enumerate(self._tracks)
                        if d.label == t.label and t.missed <= self.config.max_missed), reverse=True)
        match: dict[int, int] = {}  # a detection's index: the index of the track it continues
        for iou, i, k in pairs:
            if iou >= self.config.min_iou and i not in match and k not in match.values():
                match[i] = k
        # the rest by where they stand: a box that jumped, or a thing lost for a moment
        gaps = ((math.hypot(d.distance_m - t.ground_m[0], d.lateral_m - t.ground_m[1]), i, k)
                for i, d in enumerate(detections) if i not in match
                for k, t in enumerate(self._tracks) if k not in match.values() and d.label == t.label)
        for _, i, k in sorted(g for g in gaps if g[0] <= self.config.rejoin_m):  # not where unplaced (NaN)
            if i not in match and k not in match.values():
                match[i] = k
        for track in self._tracks:
            track.missed += 1  # and back to 0 where continued
        for i, k in match.items():
            track, d = self._tracks[k], detections[i]
            track.box, track.ground_m, track.missed = d.box_px, (d.distance_m, d.lateral_m), 0
        ids = [self._tracks[match[i]].track_id if i in match else 0 for i in range(len(detections))]
        self._tracks = [t for t in self._tracks
                        if t.missed <= max(self.config.max_missed, self.config.rejoin_frames)]
        for i, d in enumerate(detections):
            if i not in match:
                self._tracks.append(_Track(self._next_id, d.label, d.box_px, (d.distance_m, d.lateral_m)))
                ids[i] = self._next_id
                self._next_id += 1
        return [replace(d, track_id=t) for d, t in zip(detections, ids, strict=True)]

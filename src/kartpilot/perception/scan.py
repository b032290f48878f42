"""Objects and free space from a planar LiDAR's sweep (issue 58): where things are, which the camera cannot
measure as well (a camera's distance comes from where a box's foot meets a flat road; a LiDAR's is measured).

A sweep's returns come in the order of their beams, so objects are found by breaking the ring of returns where
two neighbours lie farther apart than a beam's spread at that range allows (the adaptive breakpoint rule of
Borges and Aldon, 2004): one pass, no search, a few hundred microseconds for an 800-beam sweep. Each cluster gets
its extent on the ground (its points' rectangle along its own principal axis) and its nearest point.
:class:`ScanTracker` follows clusters from sweep to sweep in the odometry frame (the kart's own motion taken out)
and gives each its velocity. :func:`corridor_free_m` and :func:`side_clear` are the free-space questions the
manoeuvres ask: how far is the lane free ahead, and is the strip beside the kart clear. :func:`locate_detections`
gives the camera's detections the LiDAR's distance where a cluster lies along the same bearing: the camera says
what a thing is, the LiDAR where it is.

Points are in the kart's body frame (x ahead of the rear axle, y to the left), from the sensor's through its
:class:`~kartpilot.core.types.LidarMount`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from kartpilot.core.config import check_values
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import LaserScan, LidarMount
from kartpilot.perception.objects import Detection

__all__ = ["STANDING", "LidarAgreement", "LidarView", "ScanCluster", "ScanConfig", "ScanObject", "ScanTracker",
           "bay_between_barriers", "cluster_scan", "corridor_free_m", "lidar_view", "locate_detections",
           "scan_points_body", "side_clear"]


STANDING = ("car", "person", "barrier", "traffic_light", "speed_sign")
"""What stands tall enough for a planar LiDAR's beams to meet (a stop line, a crossing or a bay's paint does not;
a bay's ends are its barriers)."""


@dataclass(frozen=True)
class ScanConfig:
    """Attributes:
        gap_m: two neighbouring returns nearer than this belong to one object, whatever their range.
        gap_beams: ... or nearer than this many beams' spread at their range (a far object's returns lie farther
            apart; the adaptive part of the breakpoint rule).
        min_points: a cluster of fewer returns is noise (a single return off a post is dropped).
        track_gate_m: a cluster within this of a track's predicted place continues it.
        track_lost_s: a track not seen for this long is dropped.
        velocity_smoothing: the share of a new velocity measurement in a track's velocity (0 to 1).
        match_bearing_deg: a camera detection takes the LiDAR's distance from a cluster within this bearing.
        match_range_share: ... and whose range is within this share of the camera's own estimate.
    """

    gap_m: float = 0.3
    gap_beams: float = 4.0
    min_points: int = 3
    track_gate_m: float = 1.0
    track_lost_s: float = 0.5
    velocity_smoothing: float = 0.5
    match_bearing_deg: float = 4.0
    match_range_share: float = 0.5

    def __post_init__(self) -> None:
        check_values("scan", self, (("gap_m", self.gap_m > 0, "positive"),
                                    ("gap_beams", self.gap_beams >= 0, "0 or more"),
                                    ("min_points", self.min_points >= 1, "1 or more"),
                                    ("track_gate_m", self.track_gate_m > 0, "positive"),
                                    ("track_lost_s", self.track_lost_s > 0, "positive"),
                                    ("velocity_smoothing", 0 < self.velocity_smoothing <= 1, "above 0, at most 1"),
                                    ("match_bearing_deg", 0 < self.match_bearing_deg <= 45, "above 0, at most 45"),
                                    ("match_range_share", 0 < self.match_range_share <= 1, "above 0, at most 1")))


@dataclass(frozen=True)
class ScanCluster:
    """One object in a sweep, on the ground in the body frame.

    Attributes:
        centre_xy_m: the middle of its points' rectangle.
        nearest_xy_m: its point nearest the sensor.
        length_m, width_m: its rectangle's sides (along and across its principal axis): what the sensor sees of
            it (a car seen from behind is its width long and a few centimetres deep).
        heading_rad: the rectangle's long side's direction.
        points: how many returns.
        x_range_m, y_range_m: its points' least and greatest body x and y (where it begins and ends along the
            kart's heading, and beside it).
        bearings_rad: the bearings, seen from the sensor on the body frame, of its first and last returns (in the
            sweep's order: counter-clockwise), the angle it takes up.
    """

    centre_xy_m: tuple[float, float]
    nearest_xy_m: tuple[float, float]
    length_m: float
    width_m: float
    heading_rad: float
    points: int
    x_range_m: tuple[float, float] = (math.nan, math.nan)
    y_range_m: tuple[float, float] = (math.nan, math.nan)
    bearings_rad: tuple[float, float] = (math.nan, math.nan)


def scan_points_body(scan: LaserScan, mount: LidarMount) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(points (M, 2) in the body frame, their ranges (M,)) of the beams with a return, in beam order."""
    ranges = np.asarray(scan.ranges_m, np.float64)
    seen = np.isfinite(ranges) & (ranges >= scan.range_min_m) & (ranges <= scan.range_max_m)
    angles = scan.angles_rad()[seen]
    r = ranges[seen]
    return mount.to_body(np.column_stack([r * np.cos(angles), r * np.sin(angles)])), r


def cluster_scan(scan: LaserScan, mount: LidarMount, config: ScanConfig = ScanConfig()) -> list[ScanCluster]:
    """The sweep's objects: its returns broken into clusters where two neighbours (in beam order, the ring closed
    round) lie farther apart than ``gap_m`` and than ``gap_beams`` beams' spread at their range."""
    points, ranges = scan_points_body(scan, mount)
    n = len(points)
    if n < config.min_points:
        return []
    step = abs(scan.angle_increment_rad)
    gaps = np.hypot(*(np.roll(points, -1, axis=0) - points).T)  # from each point to the next, the last to the first
    allowed = np.maximum(config.gap_m, config.gap_beams * step * np.minimum(ranges, np.roll(ranges, -1)))
    breaks = np.flatnonzero(gaps > allowed)  # a break after these points
    if len(breaks) == 0:
        groups = [np.arange(n)]
    else:
        # start after the first break, so a cluster across the ring's seam (straight behind) stays whole
        order = np.roll(np.arange(n), -(int(breaks[0]) + 1))
        cut = np.flatnonzero(gaps[order] > allowed[order]) + 1
        groups = [g for g in np.split(order, cut) if len(g)]
    sensor = (mount.x_m, mount.y_m)
    return [_cluster(points[g], sensor) for g in groups if len(g) >= config.min_points]


def _cluster(points: NDArray[np.float64], sensor: tuple[float, float] = (0.0, 0.0)) -> ScanCluster:
    centre = points.mean(axis=0)
    spread = points - centre
    if len(points) >= 2 and np.ptp(points, axis=0).max() > 1e-6:
        _, _, axes = np.linalg.svd(spread, full_matrices=False)
        axis = axes[0]
    else:
        axis = np.array([1.0, 0.0])
    across = np.array([-axis[1], axis[0]])
    along_v, across_v = spread @ axis, spread @ across
    middle = centre + axis * (along_v.max() + along_v.min()) / 2 + across * (across_v.max() + across_v.min()) / 2
    nearest = points[int(np.argmin(np.hypot(points[:, 0], points[:, 1])))]
    return ScanCluster((float(middle[0]), float(middle[1])), (float(nearest[0]), float(nearest[1])),
                       float(np.ptp(along_v)), float(np.ptp(across_v)), float(math.atan2(axis[1], axis[0])),
                       len(points), (float(points[:, 0].min()), float(points[:, 0].max())),
                       (float(points[:, 1].min()), float(points[:, 1].max())),
                       (math.atan2(points[0, 1] - sensor[1], points[0, 0] - sensor[0]),
                        math.atan2(points[-1, 1] - sensor[1], points[-1, 0] - sensor[0])))


@dataclass(frozen=True)
class LidarView:
    """What the rules are given of a sweep: its returns and objects on the body frame, and how old it is.

    Attributes:
        stamp_ns: the sweep's time.
        points_m: (M, 2) its returns (body x, y).
        clusters: its objects (:func:`cluster_scan`).
    """

    stamp_ns: int
    points_m: NDArray[np.float64]
    clusters: tuple[ScanCluster, ...]


def lidar_view(scan: LaserScan, mount: LidarMount, config: ScanConfig = ScanConfig()) -> LidarView:
    """The rules' view of one sweep: its points and its clusters on the body frame."""
    points, _ = scan_points_body(scan, mount)
    return LidarView(scan.stamp_ns, points, tuple(cluster_scan(scan, mount, config)))


def bay_between_barriers(clusters: tuple[ScanCluster, ...] | list[ScanCluster], side: float, near_x_m: float,
                         lateral_m: float, search_m: float = 2.0, band_m: float = 1.5) -> tuple[float, float] | None:
    """(where the bay begins ahead of the rear axle, its free length) between the two barriers the scan sees on
    the bay's side (``side`` > 0: left), the nearer one's far end within ``search_m`` of where the camera put the
    bay's start (``near_x_m``), both within ``band_m`` of the bay's line (``lateral_m``); None where the scan does
    not show such a pair."""
    beside = sorted((k for k in clusters if math.isfinite(k.x_range_m[0]) and k.centre_xy_m[1] * side > 0
                     and abs(k.centre_xy_m[1] - lateral_m) <= band_m), key=lambda k: k.x_range_m[0])
    for near, far in itertools.pairwise(beside):
        start, end = near.x_range_m[1], far.x_range_m[0]
        if abs(start - near_x_m) <= search_m and end > start:
            return start, end - start
    return None


@dataclass(frozen=True)
class ScanObject:
    """A cluster followed over sweeps.

    Attributes:
        track_id: the same object's id over sweeps.
        cluster: its cluster in the latest sweep (body frame).
        velocity_mps: (vx, vy) over the ground, in the body frame of the latest sweep (the kart's own motion
            taken out: a car standing still is (0, 0) however the kart drives).
        age: the sweeps it has been seen in.
    """

    track_id: int
    cluster: ScanCluster
    velocity_mps: tuple[float, float]
    age: int

    @property
    def speed_mps(self) -> float:
        return math.hypot(*self.velocity_mps)


@dataclass
class _Track:
    track_id: int
    xy_m: NDArray[np.float64]  # odometry frame
    velocity: NDArray[np.float64]  # odometry frame
    stamp_ns: int
    age: int
    cluster: ScanCluster


class ScanTracker:
    """Clusters followed from sweep to sweep by their centres in the odometry frame (nearest first, within
    ``track_gate_m`` of where each track's velocity puts it), each track's velocity smoothed over sweeps."""

    def __init__(self, config: ScanConfig | None = None) -> None:
        self.config = config or ScanConfig()
        self._tracks: list[_Track] = []
        self._next_id = 1

    def update(self, stamp_ns: int, clusters: list[ScanCluster], body_pose: tuple[float, float, float] = (0, 0, 0)
               ) -> list[ScanObject]:
        """The objects of a sweep at ``stamp_ns``, with the kart's body at ``body_pose`` (x, y, yaw in the
        odometry frame; the body frame's origin when the kart's motion is unknown: velocities are then relative
        to the kart)."""
        c, s = math.cos(body_pose[2]), math.sin(body_pose[2])
        to_odom = np.array([[c, -s], [s, c]])
        origin = np.array(body_pose[:2], np.float64)
        alive = [t for t in self._tracks if (stamp_ns - t.stamp_ns) * 1e-9 <= self.config.track_lost_s]
        predicted = [t.xy_m + t.velocity * (stamp_ns - t.stamp_ns) * 1e-9 for t in alive]
        centres = [origin + to_odom @ np.asarray(k.centre_xy_m) for k in clusters]
        pairs = sorted((float(np.linalg.norm(p - q)), i, j) for i, p in enumerate(predicted)
                       for j, q in enumerate(centres))
        taken_tracks: set[int] = set()
        taken_clusters: set[int] = set()
        for distance, i, j in pairs:
            if distance > self.config.track_gate_m or i in taken_tracks or j in taken_clusters:
                continue
            track = alive[i]
            dt = (stamp_ns - track.stamp_ns) * 1e-9
            if dt > 0:
                measured = (centres[j] - track.xy_m) / dt
                a = self.config.velocity_smoothing if track.age > 1 else 1.0
                track.velocity = (1 - a) * track.velocity + a * measured
            track.xy_m, track.stamp_ns, track.age, track.cluster = centres[j], stamp_ns, track.age + 1, clusters[j]
            taken_tracks.add(i)
            taken_clusters.add(j)
        for j, cluster in enumerate(clusters):
            if j not in taken_clusters:
                alive.append(_Track(self._next_id, centres[j], np.zeros(2), stamp_ns, 1, cluster))
                self._next_id += 1
        self._tracks = alive
        objects = []
        for t in alive:
            if t.stamp_ns == stamp_ns:
                vx, vy = to_odom.T @ t.velocity
                objects.append(ScanObject(t.track_id, t.cluster, (float(vx), float(vy)), t.age))
        return objects


def corridor_free_m(points_body: NDArray[np.float64], y_min_m: float, y_max_m: float, x_from_m: float,
                    x_to_m: float = math.inf) -> float:
    """How far ahead of ``x_from_m`` the strip between ``y_min_m`` and ``y_max_m`` (body y) is free of returns,
    up to ``x_to_m`` (inf when nothing lies in it: as far as the sensor sees)."""
    points = np.asarray(points_body, np.float64).reshape(-1, 2)
    inside = (points[:, 1] >= y_min_m) & (points[:, 1] <= y_max_m) & (points[:, 0] >= x_from_m) & (
        points[:, 0] <= x_to_m)
    return float(points[inside, 0].min() - x_from_m) if inside.any() else math.inf


def side_clear(points_body: NDArray[np.float64], x_min_m: float, x_max_m: float, y_min_m: float, y_max_m: float,
               min_points: int = 2) -> bool:
    """Whether the box beside (or around) the kart holds fewer than ``min_points`` returns: clear."""
    points = np.asarray(points_body, np.float64).reshape(-1, 2)
    inside = (points[:, 0] >= x_min_m) & (points[:, 0] <= x_max_m) & (points[:, 1] >= y_min_m) & (
        points[:, 1] <= y_max_m)
    return int(np.count_nonzero(inside)) < min_points


def locate_detections(detections: list[Detection], clusters: list[ScanCluster], mount: LidarMount,
                      config: ScanConfig = ScanConfig()) -> list[Detection]:
    """The camera's detections of things that stand (:data:`STANDING`), each with the distance and side of the
    cluster along its bearing (seen from the LiDAR) where there is one within ``match_bearing_deg`` and within
    ``match_range_share`` of the camera's distance; such a detection's ``source`` gains ``+lidar``. The others (paint
    on the road, a bay, things the scan does not see) are returned as they came. Each cluster locates one
    detection at most (the nearest in bearing)."""
    if not clusters:
        return list(detections)
    sensor = np.array([mount.x_m, mount.y_m])
    # each cluster's bearings: its middle and half the angle it takes up (a wide barrier block's returns span more
    # than the gate; the camera's bearing to it may be to its middle or its near corner)
    firsts = np.array([k.bearings_rad[0] if math.isfinite(k.bearings_rad[0]) else
                       math.atan2(k.nearest_xy_m[1] - sensor[1], k.nearest_xy_m[0] - sensor[0]) for k in clusters])
    lasts = np.array([k.bearings_rad[1] if math.isfinite(k.bearings_rad[1]) else first
                      for k, first in zip(clusters, firsts, strict=True)])
    half = np.abs(np.remainder(lasts - firsts + math.pi, math.tau) - math.pi) / 2
    bearings = firsts + np.remainder(lasts - firsts + math.pi, math.tau) / 2 - math.pi / 2
    ranges = np.array([math.hypot(k.nearest_xy_m[0] - sensor[0], k.nearest_xy_m[1] - sensor[1]) for k in clusters])
    limit = math.radians(config.match_bearing_deg)
    candidates = []
    for i, d in enumerate(detections):
        if d.label not in STANDING or not (math.isfinite(d.distance_m) and math.isfinite(d.lateral_m)):
            continue
        bearing = math.atan2(d.lateral_m - sensor[1], d.distance_m - sensor[0])
        camera_range = math.hypot(d.distance_m - sensor[0], d.lateral_m - sensor[1])
        off = np.maximum(np.abs(np.remainder(bearings - bearing + math.pi, math.tau) - math.pi) - half, 0.0)
        fits = (off <= limit) & (np.abs(ranges - camera_range) <= config.match_range_share * camera_range)
        candidates += [(float(off[j]), i, int(j)) for j in np.flatnonzero(fits)]
    out = list(detections)
    used_d: set[int] = set()
    used_k: set[int] = set()
    for _, i, j in sorted(candidates):
        if i in used_d or j in used_k:
            continue
        used_d.add(i)
        used_k.add(j)
        x, y = clusters[j].nearest_xy_m
        out[i] = replace(detections[i], distance_m=x, lateral_m=y, source=f"{detections[i].source}+lidar")
    return out


class LidarAgreement:
    """Whether the LiDAR sees what the camera sees: of the last ``window`` things the camera found that a LiDAR's
    plane meets (a car, a person, a barrier) within ``reach_m``, how many :func:`locate_detections` found a cluster
    for. A share under ``min_share`` (once ``min_objects`` have been counted) is a LiDAR that disagrees with the
    cameras (a mount knocked so that its plane passes over or into the ground, a sensor blind on one side): the
    rules then go on with the cameras alone, and say why, until the share is back over ``recover_share``."""

    KINDS = ("car", "person", "barrier")

    def __init__(self, reach_m: float, window: int = 20, min_objects: int = 10, min_share: float = 0.2,
                 recover_share: float = 0.5) -> None:
        if not (reach_m > 0 and window >= min_objects >= 1 and 0 <= min_share < recover_share <= 1):
            raise ConfigError("lidar agreement: reach_m positive, window >= min_objects >= 1, "
                              "0 <= min_share < recover_share <= 1")
        self.reach_m, self.window, self.min_objects = reach_m, window, min_objects
        self.min_share, self.recover_share = min_share, recover_share
        self._seen: list[bool] = []
        self.problem = ""

    def update(self, located: list[Detection]) -> str:
        """Count this frame's detections (as :func:`locate_detections` returned them); the problem, or ""."""
        for d in located:
            if d.label in self.KINDS and math.isfinite(d.distance_m) and 0 < d.distance_m <= self.reach_m:
                self._seen.append(d.source.endswith("+lidar"))
        del self._seen[:-self.window]
        if len(self._seen) < self.min_objects:
            return self.problem
        share = sum(self._seen) / len(self._seen)
        if share < self.min_share:
            self.problem = (f"disagrees with the camera: {len(self._seen) - sum(self._seen)} of the last "
                            f"{len(self._seen)} objects it saw within {self.reach_m:g} m have no return along their "
                            "bearing")
        elif share >= self.recover_share:
            self.problem = ""
        return self.problem

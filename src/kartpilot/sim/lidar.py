"""The simulator's planar LiDAR (issue 58): a 360-degree scan, ray-cast against what stands on the track.

The 2026 Self Driving Challenge kart carries a front-mounted planar LiDAR (``../shared/docs/sdc-event.md``); the
teams of 2025 drove an RPLIDAR. This is its simulated counterpart, with what a real one does to a scan:

* the beams lie in one plane ``height_m`` above the road: a barrier block, a car, a person, a pole and a cone are
  hit where they stand taller than that plane; paint and the road are not;
* its angular step, range and rate (an RPLIDAR A2 at 10 Hz: 0.45 deg, 0.15 to 12 m), noise that grows with the
  range (``noise_m`` plus ``noise_share`` of it);
* returns that go missing on dark or shiny surfaces, a share of the beams per kind of object (``dropout``);
* the sweep's skew: each beam is taken at its own time while the kart moves (a 10 Hz sweep at 5 m/s spans 0.5 m),
  from the kart's speed and yaw rate (:func:`kartpilot.core.geometry.arc_2d`).

:func:`cast_rays` is the pure geometry (a test can call it with arrays); :func:`scene_segments` turns a track and
its props at a time into segments; :func:`simulate_scan` makes one :class:`~kartpilot.core.types.LaserScan`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kartpilot.core.config import check_values
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import LaserScan, LidarMount
from kartpilot.sim.track import PROP_SIZES_M, Track

__all__ = ["KINDS", "LidarConfig", "cast_rays", "near_segments", "scene_segments", "simulate_scan"]

KINDS = ("barrier", "car", "person", "traffic_light", "speed_sign", "cone")
"""What a beam can hit, in the order of :func:`scene_segments`' kind codes."""

CONE_BASE_M, CONE_HEIGHT_M = 0.18, 0.30


@dataclass(frozen=True)
class LidarConfig:
    """A planar LiDAR, the sensor itself (defaults: an RPLIDAR A2M8 at 10 Hz); where it sits on the kart is the
    vehicle's or the rig's :class:`~kartpilot.core.types.LidarMount`.

    Attributes:
        rate_hz: sweeps per second (an RPLIDAR spins at 5 to 15 Hz).
        step_deg: the angle between beams.
        range_min_m, range_max_m: what it measures; nearer or farther is no return.
        noise_m, noise_share: the range's standard deviation, ``noise_m + noise_share * range``.
        dropout: the share of beams that return nothing from each kind of object (dark clothes, a black car's
            paint): kind -> share.
        seed: the noise's and the dropouts' seed.
    """

    rate_hz: float = 10.0
    step_deg: float = 0.45
    range_min_m: float = 0.15
    range_max_m: float = 12.0
    noise_m: float = 0.005
    noise_share: float = 0.005
    dropout: dict[str, float] = field(default_factory=lambda: {"person": 0.10, "car": 0.05})
    seed: int = 0

    def __post_init__(self) -> None:
        check_values("lidar", self, (("rate_hz", 1.0 <= self.rate_hz <= 50.0, "1 to 50"),
                                     ("step_deg", 0.05 <= self.step_deg <= 5.0, "0.05 to 5"),
                                     ("range_min_m", 0.0 <= self.range_min_m < self.range_max_m, "0 up to range_max_m"),
                                     ("range_max_m", self.range_max_m <= 100.0, "at most 100"),
                                     ("noise_m", 0.0 <= self.noise_m <= 0.5, "0 to 0.5"),
                                     ("noise_share", 0.0 <= self.noise_share <= 0.2, "0 to 0.2")))
        for kind, share in self.dropout.items():
            if kind not in KINDS or not 0.0 <= share < 1.0:
                raise ConfigError(f"lidar.dropout.{kind} {share}: a kind of {', '.join(KINDS)} and a share in [0, 1)")

    @property
    def beams(self) -> int:
        return round(360.0 / self.step_deg)


def cast_rays(origins: NDArray[np.float64], directions: NDArray[np.float64],
              segments: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """(distance to the nearest segment along each ray, that segment's index), inf and -1 where a ray meets none.

    Args:
        origins: (N, 2) where each ray starts.
        directions: (N, 2) unit directions.
        segments: (M, 2, 2) each segment's two ends.
    """
    n = len(origins)
    if len(segments) == 0:
        return np.full(n, np.inf), np.full(n, -1, np.intp)
    a, b = segments[:, 0], segments[:, 1]
    edge = b - a  # (M, 2)
    # origin + t * direction = a + u * edge, for t >= 0 and 0 <= u <= 1 (2D cross products)
    cross = directions[:, None, 0] * edge[None, :, 1] - directions[:, None, 1] * edge[None, :, 0]  # (N, M)
    offset = a[None, :, :] - origins[:, None, :]  # (N, M, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (offset[..., 0] * edge[None, :, 1] - offset[..., 1] * edge[None, :, 0]) / cross
        u = (offset[..., 0] * directions[:, None, 1] - offset[..., 1] * directions[:, None, 0]) / cross
    hit = (np.abs(cross) > 1e-12) & (t >= 0.0) & (u >= 0.0) & (u <= 1.0)
    t = np.where(hit, t, np.inf)
    nearest = np.argmin(t, axis=1)
    distance = t[np.arange(n), nearest]
    return distance, np.where(np.isfinite(distance), nearest, -1)


def _outline(corners: NDArray[np.float64]) -> NDArray[np.float64]:
    """(4, 2, 2) the edges of a quadrilateral footprint (corners in any order around it or as a 2x2 grid)."""
    centre = corners.mean(axis=0)
    order = np.argsort(np.arctan2(corners[:, 1] - centre[1], corners[:, 0] - centre[0]))
    ring = corners[order]
    return np.stack([ring, np.roll(ring, -1, axis=0)], axis=1)


def scene_segments(track: Track, time_s: float, height_m: float) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """(segments (M, 2, 2), each one's kind as an index into :data:`KINDS`) of everything on the track that stands
    taller than the scan plane at ``height_m``, at ``time_s`` of the run (a walking person moves)."""
    segments: list[NDArray[np.float64]] = []
    kinds: list[int] = []

    def add(edges: NDArray[np.float64], kind: str) -> None:
        segments.append(edges)
        kinds.extend([KINDS.index(kind)] * len(edges))

    if track.spec.barrier_height_m > height_m:
        for line in track.barriers:
            xy = np.asarray(line, np.float64)[:, :2]
            add(np.stack([xy[:-1], xy[1:]], axis=1), "barrier")
        for block in track.barrier_blocks:
            add(_outline(np.asarray(block, np.float64)[:, :2]), "barrier")
    for prop in track.spec.props:
        if PROP_SIZES_M[prop.kind][2] > height_m:
            add(_outline(np.asarray(track.prop_corners(prop, time_s)[:4, :2], np.float64)), prop.kind)
    if height_m < CONE_HEIGHT_M:
        # a cone in the plane: a square as wide as the cone where the plane cuts it
        for cone in track.cones:
            half = CONE_BASE_M / 2 * (1.0 - height_m / CONE_HEIGHT_M)
            x, y = cone.xy_m
            add(_outline(np.array([[x - half, y - half], [x + half, y - half], [x + half, y + half],
                                   [x - half, y + half]])), "cone")
    if not segments:
        return np.zeros((0, 2, 2)), np.zeros(0, np.intp)
    return np.concatenate(segments), np.array(kinds, np.intp)


def near_segments(segments: NDArray[np.float64], centre_xy: tuple[float, float], reach_m: float) -> NDArray[np.bool_]:
    """Which segments come within ``reach_m`` of a point (a segment's nearest point to it, not its ends): a scan
    casts its beams against these only (a whole track's barriers are thousands of segments, and a beam meets
    none farther than the sensor's range)."""
    if len(segments) == 0:
        return np.zeros(0, bool)
    a, b = segments[:, 0], segments[:, 1]
    edge = b - a
    p = np.asarray(centre_xy, np.float64)[None, :]
    length2 = np.maximum(np.sum(edge * edge, axis=1), 1e-12)
    u = np.clip(np.sum((p - a) * edge, axis=1) / length2, 0.0, 1.0)
    nearest = a + u[:, None] * edge
    return np.asarray(np.hypot(*(nearest - p).T) <= reach_m)


def _sensor_path(body_xy_yaw: tuple[float, float, float], speed_mps: float, yaw_rate_radps: float,
                 times_s: NDArray[np.float64], mount: LidarMount) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where the sensor is ((N, 2) x, y) and which way it faces ((N,) yaw) at each of ``times_s`` after the body was
    at ``body_xy_yaw``, moving along an arc (:func:`kartpilot.core.geometry.arc_2d`, for every beam at once)."""
    turn = yaw_rate_radps * times_s
    if abs(yaw_rate_radps) < 1e-9:
        dx, dy = speed_mps * times_s, np.zeros_like(times_s)
    else:
        radius = speed_mps / yaw_rate_radps
        dx, dy = radius * np.sin(turn), radius * (1.0 - np.cos(turn))
    x0, y0, yaw0 = body_xy_yaw
    c0, s0 = math.cos(yaw0), math.sin(yaw0)
    bx, by, byaw = x0 + c0 * dx - s0 * dy, y0 + s0 * dx + c0 * dy, yaw0 + turn
    cb, sb = np.cos(byaw), np.sin(byaw)
    return (np.column_stack([bx + cb * mount.x_m - sb * mount.y_m, by + sb * mount.x_m + cb * mount.y_m]),
            byaw + mount.yaw_rad)


def simulate_scan(track: Track, body_xy_yaw: tuple[float, float, float], speed_mps: float, yaw_rate_radps: float,
                  time_s: float, config: LidarConfig, mount: LidarMount, rng: np.random.Generator) -> LaserScan:
    """One sweep starting at ``time_s`` by the sensor at ``mount`` on the body (rear axle) at ``body_xy_yaw``,
    moving at ``speed_mps`` and ``yaw_rate_radps``: each beam from where the sensor is at its own time, its range
    with the sensor's noise, a share of those on dark surfaces lost, and what lies outside the sensor's range
    NaN."""
    beams = config.beams
    scan_time = 1.0 / config.rate_hz
    step = math.radians(config.step_deg)
    angles = -math.pi + step * np.arange(beams)
    dt = scan_time / beams
    origins, yaws = _sensor_path(body_xy_yaw, speed_mps, yaw_rate_radps, np.arange(beams, dtype=np.float64) * dt, mount)
    headings = yaws + angles
    directions = np.column_stack([np.cos(headings), np.sin(headings)])
    segments, kinds = scene_segments(track, time_s, mount.z_m)
    reach = config.range_max_m + abs(speed_mps) * scan_time + 1.0
    near = near_segments(segments, (float(origins[0, 0]), float(origins[0, 1])), reach)
    segments, kinds = segments[near], kinds[near]
    distance, hit = cast_rays(origins, directions, segments)
    ranges = distance + rng.normal(0.0, 1.0, beams) * (config.noise_m + config.noise_share * np.minimum(
        distance, config.range_max_m))
    lost = np.zeros(beams, bool)
    for kind, share in config.dropout.items() if len(kinds) else ():
        lost |= (hit >= 0) & (kinds[np.maximum(hit, 0)] == KINDS.index(kind)) & (rng.random(beams) < share)
    valid = np.isfinite(ranges) & ~lost & (ranges >= config.range_min_m) & (ranges <= config.range_max_m)
    intensity = np.where(valid, 1.0 / (1.0 + 0.1 * np.where(valid, ranges, 0.0)), 0.0)
    return LaserScan(round(time_s * 1e9), float(angles[0]), step, dt, scan_time, config.range_min_m,
                     config.range_max_m, np.where(valid, ranges, np.nan).astype(np.float32),
                     intensity.astype(np.float32))

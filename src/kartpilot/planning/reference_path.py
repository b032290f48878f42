"""Reference paths: a recorded trajectory turned into waypoints a controller can follow.

A path lives in the plane of the road, in the frame of the kart's rear axle at the
start of the drive it came from (x forward, y left, metres; yaw positive to the left).
:func:`build_reference_path` resamples the trajectory at even spacing, smooths it
(a Gaussian along arc length, so the heading no longer jumps from one VO frame to the
next, the thesis's oscillation), and derives heading, curvature and a speed profile
that slows down in bends (lateral acceleration bound) and brakes to a stop at the end.

Progress along the path only moves forward: :func:`advance_progress` searches for the
nearest waypoint in a window ahead of the last one, so a path that passes near itself
(the end of a lap next to its start) never makes the follower jump across.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from scipy.ndimage import gaussian_filter1d

from kartpilot.core.errors import ConfigError, DataError, PlanningError
from kartpilot.core.files import parse_csv, parse_yaml, read_text_file, write_csv_atomic, write_text_atomic
from kartpilot.core.geometry import Array

__all__ = [
    "PathConfig",
    "ReferencePath",
    "advance_progress",
    "build_reference_path",
    "index_ahead",
    "lateral_offset",
    "load_reference_path",
    "save_reference_path",
]

COLUMNS = ("s_m", "x_m", "y_m", "heading_rad", "curvature_per_m", "speed_mps")


@dataclass(frozen=True)
class PathConfig:
    """How a trajectory becomes a reference path.

    Attributes:
        spacing_m: distance between waypoints (at most; the path is divided evenly so it keeps its end).
        smoothing_m: standard deviation of the Gaussian smoothing along the path (0: none).
        cruise_speed_mps: the speed on straights.
        max_lateral_accel_mps2: bends are taken at ``sqrt(a / |curvature|)`` at most.
        max_accel_mps2, max_decel_mps2: bounds on the profile's speed changes along the path.
        min_speed_mps: the profile never asks for less, except at the end, where it stops.
        stop_at_end: brake to a standstill at the last waypoint.
    """

    spacing_m: float = 0.1
    smoothing_m: float = 0.5
    cruise_speed_mps: float = 1.0
    max_lateral_accel_mps2: float = 1.5
    max_accel_mps2: float = 1.0
    max_decel_mps2: float = 1.0
    min_speed_mps: float = 0.3
    stop_at_end: bool = True

    def __post_init__(self) -> None:
        for name in ("spacing_m", "cruise_speed_mps", "max_lateral_accel_mps2", "max_accel_mps2", "max_decel_mps2"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"path.{name} must be positive")
        if self.smoothing_m < 0 or self.min_speed_mps < 0:
            raise ConfigError("path.smoothing_m and path.min_speed_mps must not be negative")


@dataclass(frozen=True)
class ReferencePath:
    """Evenly spaced waypoints with heading, curvature and target speed (arrays of equal length)."""

    s_m: Array
    x_m: Array
    y_m: Array
    heading_rad: Array
    curvature_per_m: Array
    speed_mps: Array

    def __post_init__(self) -> None:
        n = len(self.s_m)
        if n < 2:
            raise PlanningError("a reference path needs at least two waypoints")
        for name in COLUMNS:
            if len(getattr(self, name)) != n:
                raise PlanningError(f"the path's {name} has {len(getattr(self, name))} values, s_m has {n}")
        if np.any(np.diff(self.s_m) <= 0):
            raise PlanningError("the path's s_m must increase strictly")

    def __len__(self) -> int:
        return len(self.s_m)

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1] - self.s_m[0])

    @property
    def xy_m(self) -> Array:
        return np.column_stack([self.x_m, self.y_m])


def build_reference_path(xy_m: Array, config: PathConfig | None = None) -> ReferencePath:
    """A reference path through the points ``(N, 2)`` of a trajectory, in their order.

    Points closer together than a millimetre (the kart standing still) are dropped first.
    """
    config = config or PathConfig()
    xy = np.asarray(xy_m, float)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ConfigError(f"a path needs (N, 2) points, got shape {xy.shape}")
    if not np.all(np.isfinite(xy)):
        raise ConfigError("the trajectory has non-finite points")
    keep = np.concatenate([[True], np.linalg.norm(np.diff(xy, axis=0), axis=1) > 1e-3])
    xy = xy[keep]
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    s_raw = np.concatenate([[0.0], np.cumsum(steps)])
    if len(xy) < 2 or s_raw[-1] < 2 * config.spacing_m:
        raise ConfigError(f"the trajectory is {s_raw[-1]:.2f} m long: too short for a path")
    s = _even_stations(s_raw[-1], config.spacing_m)
    x = np.interp(s, s_raw, xy[:, 0])
    y = np.interp(s, s_raw, xy[:, 1])
    sigma = config.smoothing_m / config.spacing_m
    if sigma > 0:
        x, y = _smooth_keeping_ends(x, sigma), _smooth_keeping_ends(y, sigma)
        # smoothing shortens bends a little: resample again to even spacing
        steps = np.hypot(np.diff(x), np.diff(y))
        s_smooth = np.concatenate([[0.0], np.cumsum(steps)])
        s = _even_stations(s_smooth[-1], config.spacing_m)
        x, y = np.interp(s, s_smooth, x), np.interp(s, s_smooth, y)
    heading = np.unwrap(np.arctan2(np.gradient(y), np.gradient(x)))
    curvature = np.gradient(heading, s)
    if sigma > 0:
        curvature = gaussian_filter1d(curvature, max(sigma / 2, 1.0), mode="nearest")
    speed = speed_profile(s, curvature, config)
    return ReferencePath(s, x, y, heading, curvature, speed)


def _even_stations(length_m: float, spacing_m: float) -> Array:
    """Stations from 0 to ``length_m`` inclusive, evenly spaced at most ``spacing_m`` apart (the path keeps its end)."""
    return np.linspace(0.0, length_m, max(math.ceil(length_m / spacing_m - 1e-9), 1) + 1)


def _smooth_keeping_ends(values: Array, sigma: float) -> Array:
    """Gaussian smoothing after a point reflection at both ends, which keeps the end points and
    any straight run through them exactly where they are."""
    pad = min(int(4 * sigma) + 1, len(values) - 1)
    head = 2 * values[0] - values[pad:0:-1]
    tail = 2 * values[-1] - values[-2:-pad - 2:-1]
    smoothed = gaussian_filter1d(np.concatenate([head, values, tail]), sigma, mode="nearest")
    return smoothed[pad:pad + len(values)]


def speed_profile(s_m: Array, curvature_per_m: Array, config: PathConfig) -> Array:
    """Cruise speed, capped in bends by lateral acceleration, then bounded in acceleration forward
    and deceleration backward along the path (the usual two passes)."""
    with np.errstate(divide="ignore"):
        bend = np.sqrt(config.max_lateral_accel_mps2 / np.abs(curvature_per_m))
    v = np.clip(np.minimum(config.cruise_speed_mps, bend), min(config.min_speed_mps, config.cruise_speed_mps), None)
    ds = np.diff(s_m)
    if config.stop_at_end:
        v[-1] = 0.0
    for i in range(1, len(v)):
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * config.max_accel_mps2 * ds[i - 1]))
    v[0] = min(config.cruise_speed_mps, max(v[0], config.min_speed_mps))  # a path must start moving
    for i in range(len(v) - 2, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * config.max_decel_mps2 * ds[i]))
    return v


def advance_progress(path: ReferencePath, x_m: float, y_m: float, index: int, search_ahead_m: float) -> int:
    """The waypoint nearest ``(x, y)`` among ``index`` and the waypoints up to ``search_ahead_m`` ahead.

    Never returns less than ``index``: progress only moves forward.
    """
    index = min(max(index, 0), len(path) - 1)
    end = int(np.searchsorted(path.s_m, path.s_m[index] + search_ahead_m, side="right"))
    end = max(end, index + 1)
    d2 = (path.x_m[index:end] - x_m) ** 2 + (path.y_m[index:end] - y_m) ** 2
    return index + int(np.argmin(d2))


def lateral_offset(path: ReferencePath, index: int, x_m: float, y_m: float) -> tuple[float, float]:
    """``(s, offset)`` of the point projected onto the path's segment next to waypoint ``index``.

    The offset is positive when the point lies left of the path. Past either end the end segment
    is extended, so ``s`` may leave ``[s_0, s_end]``.
    """
    i = min(max(index, 0), len(path) - 2)
    if index > 0:
        # the segment before the waypoint if the point projects behind it
        hx, hy = path.x_m[index] - path.x_m[index - 1], path.y_m[index] - path.y_m[index - 1]
        if (x_m - path.x_m[index]) * hx + (y_m - path.y_m[index]) * hy < 0:
            i = index - 1
    x0, y0 = path.x_m[i], path.y_m[i]
    dx, dy = path.x_m[i + 1] - x0, path.y_m[i + 1] - y0
    length = math.hypot(dx, dy)
    ux, uy = dx / length, dy / length
    along = (x_m - x0) * ux + (y_m - y0) * uy
    return float(path.s_m[i] + along), float(-(x_m - x0) * uy + (y_m - y0) * ux)


def index_ahead(path: ReferencePath, index: int, distance_m: float) -> int:
    """The waypoint ``distance_m`` along the path from ``index`` (the last one at most)."""
    target = path.s_m[min(max(index, 0), len(path) - 1)] + max(distance_m, 0.0)
    return min(int(np.searchsorted(path.s_m, target, side="left")), len(path) - 1)


def save_reference_path(path: ReferencePath, target: str | Path) -> Path:
    """Write ``.csv`` (a header of unit-named columns) or ``.yaml``/``.yml`` (columns under ``waypoints``)."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    rows = np.column_stack([getattr(path, name) for name in COLUMNS])
    if target.suffix.lower() == ".csv":
        write_csv_atomic(target, COLUMNS, [[f"{v:.6f}" for v in row] for row in rows])
    elif target.suffix.lower() in (".yaml", ".yml"):
        data = {
            "frame": "rear axle at the start of the recorded drive: x forward, y left",
            "columns": list(COLUMNS),
            "waypoints": [[round(float(v), 6) for v in row] for row in rows],
        }
        write_text_atomic(target, yaml.safe_dump(data, sort_keys=False, default_flow_style=None))
    else:
        raise PlanningError(f"{target}: a reference path is saved as .csv or .yaml")
    return target


def load_reference_path(source: str | Path) -> ReferencePath:
    """Read a path written by :func:`save_reference_path` (or by hand, with the same columns)."""
    source = Path(source)
    if not source.is_file():
        raise PlanningError(f"{source}: no such reference path")
    try:
        if source.suffix.lower() == ".csv":
            records = parse_csv(read_text_file(source), source)
            header = tuple(records[0]) if records else COLUMNS
            rows = [[record[c] for c in header] for record in records]
        elif source.suffix.lower() in (".yaml", ".yml"):
            data = parse_yaml(read_text_file(source), source)
            if not isinstance(data, dict):
                raise PlanningError(f"{source}: expected a mapping with 'columns' and 'waypoints'")
            header = tuple(data.get("columns", ()))
            rows = data.get("waypoints") or []
        else:
            raise PlanningError(f"{source}: a reference path is read from .csv or .yaml")
        missing = [c for c in COLUMNS if c not in header]
        if missing:
            raise PlanningError(f"{source}: missing column(s) {', '.join(missing)}")
        table = np.array([[float(row[header.index(c)]) for c in COLUMNS] for row in rows], float).reshape(-1, 6)
    except DataError as exc:
        raise PlanningError(str(exc)) from None
    except (ValueError, IndexError, TypeError, yaml.YAMLError) as exc:
        raise PlanningError(f"{source}: unreadable reference path ({exc})") from exc
    if not np.all(np.isfinite(table)):
        raise PlanningError(f"{source}: the path has non-finite values")
    return ReferencePath(*(table[:, k].copy() for k in range(6)))

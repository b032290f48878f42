"""Tracks as data: a YAML description turned into dense, queryable geometry.

A track file describes the *route* (the centre line the kart must follow) as
straights and arcs or as spline control points, its width along the way, each
boundary's marking (painted line, cones at a gap, or nothing), curbs, tyre
walls, tyre marks, a cross-slope, the start and (for open tracks) the finish,
and *branches*: alternative roads that leave the route at a split and rejoin it
later. Taking a branch is a wrong route. Crossings need no description: a
route that passes over itself crosses, and the painted markings are left out
wherever they would lie on another part of the road.

World frame: x and y on the ground, z up, metres. ``s`` is the distance along
a centre line; a lateral offset is positive to the left of the direction of
travel.

Example (``straight20``)::

    name: straight20
    centerline:
      closed: false
      segments: [{straight_m: 26.0}]
    width_m: 1.5
    left: {kind: cones, cone_gap_m: 1.0}
    right: {kind: cones, cone_gap_m: 1.0}
    start_s_m: 2.0
    finish_s_m: 22.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, is_dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from kartpilot.core.config import load_yaml_mapping, merge_config
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array

__all__ = [
    "PROP_SIZES_M",
    "BarrierBlock",
    "Branch",
    "CenterlineSpec",
    "Curb",
    "Dashed",
    "Marking",
    "Projection",
    "Prop",
    "RoadMark",
    "RoadPiece",
    "Segment",
    "Track",
    "TrackSpec",
    "build_track",
    "bundled_tracks",
    "load_track",
    "load_track_spec",
    "project_onto",
    "roadside_trees",
    "scenery_boxes",
]

SAMPLE_SPACING_M = 0.05
Side = Literal["left", "right"]


@dataclass(frozen=True)
class Segment:
    """A straight (``straight_m``) or an arc (``radius_m`` turning ``angle_deg``, positive to the left)."""

    straight_m: float = 0.0
    radius_m: float = 0.0
    angle_deg: float = 0.0


@dataclass(frozen=True)
class CenterlineSpec:
    """The route's centre line, from segments or from spline control points (not both)."""

    closed: bool = True
    start_xy_m: tuple[float, float] = (0.0, 0.0)
    start_heading_deg: float = 0.0
    segments: tuple[Segment, ...] = ()
    points_m: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True)
class Marking:
    """How one boundary is marked. Cones stand on the boundary, lines are centred on it."""

    kind: Literal["line", "cones", "none"] = "line"
    line_width_m: float = 0.08
    cone_gap_m: float = 1.0
    cone_base_m: float = 0.18
    cone_height_m: float = 0.30

    def __post_init__(self) -> None:
        if not min(self.line_width_m, self.cone_gap_m, self.cone_base_m, self.cone_height_m) > 0:
            raise ConfigError("track marking: line_width_m, cone_gap_m, cone_base_m and cone_height_m must be "
                              "positive")


@dataclass(frozen=True)
class Curb:
    """Red and white curb stones just outside a boundary, from ``from_s_m`` to ``to_s_m``."""

    side: Side = "left"
    from_s_m: float = 0.0
    to_s_m: float = 0.0
    width_m: float = 0.3

    def __post_init__(self) -> None:
        if not self.width_m > 0 or not self.from_s_m <= self.to_s_m:
            raise ConfigError("track curb: width_m must be positive and from_s_m at most to_s_m")


@dataclass(frozen=True)
class Branch:
    """A split: a road that leaves the route toward ``side`` and rejoins it; taking it is a wrong route."""

    side: Side = "left"
    from_s_m: float = 0.0
    to_s_m: float = 0.0
    offset_m: float = 8.0
    ramp_m: float = 15.0


@dataclass(frozen=True)
class Dashed:
    """A stretch of a boundary's line painted dashed (the centre line of a two-lane road), ``dash_m`` of paint
    then ``gap_m`` of none. The boundary still bounds the lane: the referee counts crossing it."""

    side: Side = "left"
    from_s_m: float = 0.0
    to_s_m: float = 0.0
    dash_m: float = 3.0
    gap_m: float = 3.0

    def __post_init__(self) -> None:
        if not (self.dash_m > 0 and self.gap_m > 0 and self.from_s_m <= self.to_s_m):
            raise ConfigError("track dashed: dash_m and gap_m must be positive and from_s_m at most to_s_m")


@dataclass(frozen=True)
class RoadMark:
    """Paint across the lane at ``s_m``: a ``stop_line`` (a bar ``length_m`` deep along the road) or a ``zebra``
    crossing (stripes ``stripe_m`` wide along the road, as deep as ``length_m``, across the surface)."""

    kind: Literal["stop_line", "zebra"] = "stop_line"
    s_m: float = 0.0
    length_m: float = 0.3
    stripe_m: float = 0.5

    def __post_init__(self) -> None:
        if not (self.length_m > 0 and self.stripe_m > 0):
            raise ConfigError("track road mark: length_m and stripe_m must be positive")


@dataclass(frozen=True)
class BarrierBlock:
    """A red-and-white barrier standing beside the road: ``length_m`` long along it from ``s_m``, ``offset_m``
    beyond the boundary on ``side`` (negative: inside the lane), ``height_m`` tall and ``depth_m`` thick."""

    side: Side = "right"
    s_m: float = 0.0
    offset_m: float = 0.5
    length_m: float = 2.0
    height_m: float = 1.0
    depth_m: float = 0.4

    def __post_init__(self) -> None:
        if not min(self.length_m, self.height_m, self.depth_m) > 0:
            raise ConfigError("track barrier block: length_m, height_m and depth_m must be positive")


@dataclass(frozen=True)
class Prop:
    """A scenario's object at ``s_m`` along the route, ``offset_m`` left (+) or right (-) of its centre line,
    facing the kart as it comes.

    Kinds: ``traffic_light`` (a signal head on a tripod; ``phases`` are (colour, seconds) in turn from the start
    of the run, the last one held), ``speed_sign`` (a round sign of ``value_kmh`` on a pole), ``person`` (standing;
    from ``walk_start_s`` seconds on, walking across the road at ``walk_speed_mps`` to ``walk_to_offset_m``; with
    ``walk_pause_s``, back and forth for good, standing that long at each side) and ``car`` (the event's inflatable
    car, stationary)."""

    kind: Literal["traffic_light", "speed_sign", "person", "car"] = "car"
    s_m: float = 0.0
    offset_m: float = 0.0
    value_kmh: int = 20
    phases: tuple[tuple[Literal["red", "green"], float], ...] = (("red", 10.0), ("green", 1.0))
    walk_to_offset_m: float = 0.0
    walk_start_s: float = 0.0
    walk_speed_mps: float = 0.0
    walk_pause_s: float = 0.0

    def __post_init__(self) -> None:
        if self.walk_pause_s < 0:
            raise ConfigError("track prop: walk_pause_s must not be negative")
        if self.walk_speed_mps < 0 or not self.phases or any(d <= 0 for _, d in self.phases):
            raise ConfigError("track prop: walk_speed_mps must not be negative and each phase must last a while")
        if not 0 < self.value_kmh <= 130:
            raise ConfigError("track prop: value_kmh must be a speed limit in km/h")

    def light_at(self, time_s: float) -> str:
        """A traffic light's colour at a time of the run."""
        elapsed = 0.0
        for colour, seconds in self.phases:
            elapsed += seconds
            if time_s < elapsed:
                return colour
        return self.phases[-1][0]

    def offset_at(self, time_s: float) -> float:
        """A person's lateral offset at a time of the run (walking once started, then standing at the end)."""
        if self.walk_speed_mps <= 0 or time_s <= self.walk_start_s:
            return self.offset_m
        elapsed = time_s - self.walk_start_s
        span = self.walk_to_offset_m - self.offset_m
        crossing_s = abs(span) / self.walk_speed_mps
        start, end = self.offset_m, self.walk_to_offset_m
        if self.walk_pause_s > 0:  # back and forth: cross, stand, cross back, stand
            cycle = crossing_s + self.walk_pause_s
            if (elapsed // cycle) % 2 == 1:
                start, end = end, start
            elapsed %= cycle
        travelled = elapsed * self.walk_speed_mps
        return end if travelled >= abs(span) else start + math.copysign(travelled, end - start)


PROP_SIZES_M = {"traffic_light": (0.3, 0.25, 2.1), "speed_sign": (0.6, 0.05, 2.2), "person": (0.5, 0.3, 1.75),
                "car": (1.7, 3.8, 1.45)}
"""(width across the road, depth along it, height) of each kind of prop, metres; a sign's disc is 0.6 m across and
its top 2.2 m up, a signal head's lamps are 0.2 m across."""


@dataclass(frozen=True)
class TrackSpec:
    """Everything a track file can say. Defaults describe a plain lined asphalt road.

    ``lane_preset`` names the lane pipeline's preset a simulated drive uses on this track unless told otherwise
    (``--preset``): ``kart``, the real kart's, where the track is drawn as the real venue looks; ``kart-sim`` on
    sdc-assen, whose wide track and its split the thesis's Hough lines were developed on."""

    name: str = "track"
    description: str = ""
    centerline: CenterlineSpec = field(default_factory=CenterlineSpec)
    width_m: float = 3.0
    width_profile: tuple[tuple[float, float], ...] = ()
    left: Marking = field(default_factory=Marking)
    right: Marking = field(default_factory=Marking)
    surface: Literal["asphalt", "worn_asphalt", "tartan"] = "asphalt"
    surface_margin_m: tuple[float, float] = (0.6, 0.6)
    ground: Literal["grass", "asphalt"] = "grass"
    decor_lines_m: tuple[float, ...] = ()
    curbs: tuple[Curb, ...] = ()
    barrier_offset_m: float = 0.0
    barrier_height_m: float = 0.6
    tyre_marks: int = 0
    cross_slope_deg: float = 0.0
    start_s_m: float = 0.0
    finish_s_m: float | None = None
    branches: tuple[Branch, ...] = ()
    dashed: tuple[Dashed, ...] = ()
    road_marks: tuple[RoadMark, ...] = ()
    barrier_blocks: tuple[BarrierBlock, ...] = ()
    props: tuple[Prop, ...] = ()
    sky: Literal["clear", "overcast"] = "clear"
    lane_preset: str = "kart"
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.width_m > 0 or any(not w > 0 for _, w in self.width_profile):
            raise ConfigError(f"track {self.name!r}: width_m and every width in width_profile must be positive")
        if min(*self.surface_margin_m, self.barrier_offset_m, self.barrier_height_m, self.tyre_marks) < 0:
            raise ConfigError(f"track {self.name!r}: surface_margin_m, barrier_offset_m, barrier_height_m and "
                              "tyre_marks must not be negative")
        if not -45.0 <= self.cross_slope_deg <= 45.0:
            raise ConfigError(f"track {self.name!r}: cross_slope_deg must lie within 45 degrees")


@dataclass(frozen=True)
class RoadPiece:
    """A densely sampled centre line (route or branch) with its width."""

    name: str
    xy_m: Array
    s_m: Array
    heading_rad: Array
    curvature_1pm: Array
    half_width_m: Array
    closed: bool

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1] + (SAMPLE_SPACING_M if self.closed else 0.0))

    def normal(self) -> Array:
        """Unit normals pointing to the left of the direction of travel."""
        return np.stack([-np.sin(self.heading_rad), np.cos(self.heading_rad)], axis=1)

    def boundary(self, side: Side, extra_m: float = 0.0) -> Array:
        sign = 1.0 if side == "left" else -1.0
        return self.xy_m + sign * (self.half_width_m + extra_m)[:, None] * self.normal()

    def index_at(self, s_m: float) -> int:
        if self.closed:
            s_m %= self.length_m
        return int(np.clip(round(s_m / SAMPLE_SPACING_M), 0, len(self.s_m) - 1))


@dataclass(frozen=True)
class Cone:
    xy_m: tuple[float, float]
    side: Side
    s_m: float


@dataclass(frozen=True)
class Track:
    """A built track: the route, its branches, and the markings as they appear on the ground."""

    spec: TrackSpec
    route: RoadPiece
    branches: tuple[RoadPiece, ...]
    cones: tuple[Cone, ...]
    lines: tuple[Array, ...]
    line_widths_m: tuple[float, ...]
    curbs: tuple[tuple[Array, Array], ...]
    barriers: tuple[Array, ...]
    route_marked_left: NDArray[np.bool_]
    route_marked_right: NDArray[np.bool_]
    road_marks: tuple[Array, ...] = ()
    """Polygons (N x 2, world) of the paint across the lane: stop lines and zebra stripes."""
    barrier_blocks: tuple[Array, ...] = ()
    """Footprints (4 x 2, world, counter-clockwise) of the barrier blocks, as ``spec.barrier_blocks``."""
    road_mark_of: tuple[int, ...] = ()
    """For each of ``road_marks``, the index of the ``spec.road_marks`` entry it belongs to (a zebra's stripes)."""

    def prop_frame(self, prop: Prop, time_s: float = 0.0) -> tuple[Array, float]:
        """((x, y) of a prop's foot on the ground, its facing: the yaw of the direction it faces, toward the
        kart coming along the route) at a time of the run."""
        i = self.route.index_at(prop.s_m)
        heading = float(self.route.heading_rad[i])
        offset = prop.offset_at(time_s) if prop.kind == "person" else prop.offset_m
        return self.route.xy_m[i] + offset * self.route.normal()[i], heading + math.pi

    def prop_corners(self, prop: Prop, time_s: float = 0.0) -> Array:
        """The 8 corners (world, metres) of a prop's box at a time of the run."""
        foot, facing = self.prop_frame(prop, time_s)
        width, depth, height = PROP_SIZES_M[prop.kind]
        c, s = math.cos(facing), math.sin(facing)
        along, across = np.array([c, s]), np.array([-s, c])
        corners = [foot + a * depth / 2 * along + b * width / 2 * across for a in (-1, 1) for b in (-1, 1)]
        return np.array([[x, y, z] for z in (0.0, height) for x, y in corners])

    def dashed_at(self, side: Side, s_m: float) -> bool:
        """Whether the boundary on ``side`` is painted dashed at ``s_m`` along the route (a two-lane road's
        centre line, which a kart may cross to overtake)."""
        return any(d.side == side and d.from_s_m <= s_m <= d.to_s_m for d in self.spec.dashed)

    def marked(self, side: Side, index: int) -> bool:
        """Whether the route's boundary on ``side`` is marked at a sample (not at a crossing or split)."""
        mask = self.route_marked_left if side == "left" else self.route_marked_right
        return bool(mask[index])

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def closed(self) -> bool:
        return self.route.closed

    @property
    def start_index(self) -> int:
        return self.route.index_at(self.spec.start_s_m)

    @property
    def finish_s_m(self) -> float:
        """Where a run ends on an open track (closed tracks count laps from the start)."""
        if self.spec.finish_s_m is not None:
            return self.spec.finish_s_m
        return self.route.length_m - 2.0

    def start_pose(self) -> tuple[float, float, float]:
        """(x, y, yaw) of the start on the route's centre line."""
        i = self.start_index
        return float(self.route.xy_m[i, 0]), float(self.route.xy_m[i, 1]), float(self.route.heading_rad[i])

    def bounds_m(self, margin_m: float = 0.0) -> tuple[float, float, float, float]:
        xy = np.vstack([self.route.xy_m, *(b.xy_m for b in self.branches)])
        lo, hi = xy.min(axis=0) - margin_m, xy.max(axis=0) + margin_m
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


@dataclass(frozen=True)
class Projection:
    """Where a point lies relative to a road piece."""

    index: int
    s_m: float
    offset_m: float
    heading_rad: float
    half_width_m: float


def bundled_tracks() -> list[str]:
    """Names of the tracks shipped with kartpilot."""
    folder = resources.files("kartpilot.sim") / "tracks"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def load_track(name_or_path: str | Path) -> Track:
    """A bundled track by name (``utrack``) or a track YAML file by path."""
    return build_track(load_track_spec(name_or_path))


def load_track_spec(name_or_path: str | Path) -> TrackSpec:
    """A track's description, checked but not built (building samples the whole track)."""
    path = Path(name_or_path)
    if not path.suffix:
        if str(name_or_path) not in bundled_tracks():
            raise ConfigError(f"unknown track {name_or_path!r}; bundled tracks: {', '.join(bundled_tracks())}")
        resource = resources.files("kartpilot.sim") / "tracks" / f"{name_or_path}.yaml"
        with resources.as_file(resource) as file:
            mapping = load_yaml_mapping(file)
    else:
        mapping = load_yaml_mapping(path)
    return merge_config(TrackSpec(), mapping, "track")


@lru_cache(maxsize=16)
def build_track(spec: TrackSpec) -> Track:
    """Sample the route and its branches and lay out the markings. Built once per description in a process (a
    simulator, its referee, a scenario's checks and the CLI each asked for the same track: sdc-assen took a second
    each time) and shared: every array of the track is read-only, so no user can change it for the next."""
    return _read_only(_build_track(spec))


def _read_only(value: Any) -> Any:
    """``value`` with every NumPy array in it (through dataclasses and tuples) made read-only; the same object."""
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif isinstance(value, tuple):
        for item in value:
            _read_only(item)
    elif is_dataclass(value) and not isinstance(value, type):
        for f in fields(value):
            _read_only(getattr(value, f.name))
    return value


def _build_track(spec: TrackSpec) -> Track:
    xy = _centerline_points(spec.centerline)
    route = _piece("route", _resample(xy, spec.centerline.closed), spec, spec.centerline.closed)
    if not spec.centerline.closed and not 0.0 <= spec.start_s_m < route.length_m:
        raise ConfigError(f"track {spec.name!r}: start_s_m {spec.start_s_m} is off the route")
    finish = spec.finish_s_m
    if finish is not None and (spec.centerline.closed or not spec.start_s_m < finish <= route.length_m):
        raise ConfigError(f"track {spec.name!r}: finish_s_m needs an open route and must lie after the start")
    branches = tuple(_branch(route, b, i) for i, b in enumerate(spec.branches))
    pieces = (route, *branches)
    road = _RoadIndex(pieces)

    lines: list[Array] = []
    widths: list[float] = []
    cones: list[Cone] = []
    marked = {side: ~road.inside(route.boundary(side), -0.02) for side in ("left", "right")}
    for piece in pieces:
        for side, marking in (("left", spec.left), ("right", spec.right)):
            boundary = piece.boundary(side)  # type: ignore[arg-type]
            if marking.kind == "line":
                keep = ~road.inside(boundary, -0.02)
                if piece is route:
                    keep &= ~_dash_gaps(route.s_m, [d for d in spec.dashed if d.side == side])
                for run in _runs(boundary, keep, piece.closed):
                    lines.append(run)
                    widths.append(marking.line_width_m)
            elif marking.kind == "cones":
                step = max(1, round(marking.cone_gap_m / SAMPLE_SPACING_M))
                idx = np.arange(0, len(boundary), step)
                keep = ~road.inside(boundary[idx], -marking.cone_base_m)
                cones += [Cone((float(boundary[i, 0]), float(boundary[i, 1])), side, float(piece.s_m[i]))  # type: ignore[arg-type]
                          for i in idx[keep]]
        for offset in spec.decor_lines_m:
            decor = piece.xy_m + offset * piece.normal()
            keep = ~road.inside(decor, -0.02) if abs(offset) < piece.half_width_m.min() else np.ones(len(decor), bool)
            for run in _runs(decor, keep, piece.closed):
                lines.append(run)
                widths.append(0.05)

    curbs: list[tuple[Array, Array]] = []
    for curb in spec.curbs:
        i0, i1 = route.index_at(curb.from_s_m), route.index_at(curb.to_s_m)
        idx = np.arange(i0, i1 + 1) if i1 >= i0 else np.r_[np.arange(i0, len(route.s_m)), np.arange(0, i1 + 1)]
        line_w = (spec.left if curb.side == "left" else spec.right).line_width_m / 2
        inner = route.boundary(curb.side, line_w)[idx]
        outer = route.boundary(curb.side, line_w + curb.width_m)[idx]
        curbs.append((inner, outer))

    barriers: list[Array] = []
    if spec.barrier_offset_m > 0:
        for piece in pieces:
            for side in ("left", "right"):
                wall = piece.boundary(side, spec.barrier_offset_m)  # type: ignore[arg-type]
                keep = ~road.inside(wall, 0.8 * spec.barrier_offset_m)
                barriers += [run for run in _runs(wall, keep, piece.closed) if len(run) > 10]
    return Track(spec, route, branches, tuple(cones), tuple(lines), tuple(widths), tuple(curbs), tuple(barriers),
                 marked["left"], marked["right"], tuple(p for m in spec.road_marks for p in _road_mark(route, m)),
                 tuple(_barrier_block(route, spec, b) for b in spec.barrier_blocks),
                 tuple(k for k, m in enumerate(spec.road_marks) for _ in _road_mark(route, m)))


def _dash_gaps(s_m: Array, stretches: list[Dashed]) -> NDArray[np.bool_]:
    """Where a dashed stretch leaves a gap in its line."""
    gaps = np.zeros(len(s_m), bool)
    for d in stretches:
        inside = (s_m >= d.from_s_m) & (s_m <= d.to_s_m)
        gaps |= inside & (np.mod(s_m - d.from_s_m, d.dash_m + d.gap_m) >= d.dash_m)
    return gaps


def _frame_at(route: RoadPiece, s_m: float) -> tuple[Array, Array, Array, float]:
    """(point, unit tangent, unit left normal, half width) of the route at ``s_m``."""
    i = route.index_at(s_m)
    h = float(route.heading_rad[i])
    return route.xy_m[i], np.array([math.cos(h), math.sin(h)]), np.array([-math.sin(h), math.cos(h)]), float(
        route.half_width_m[i])


def _road_mark(route: RoadPiece, mark: RoadMark) -> list[Array]:
    """The polygons of a stop line (one bar across the lane, its near edge at ``s_m``) or of a zebra's
    stripes (bars along the road, from ``s_m`` on, spaced across the lane)."""
    centre, along, left, half = _frame_at(route, mark.s_m)
    if mark.kind == "stop_line":
        return [np.array([centre - half * left, centre - half * left + mark.length_m * along,
                          centre + half * left + mark.length_m * along, centre + half * left])]
    stripes = []
    pitch = 2 * mark.stripe_m
    count = max(1, int((2 * half) // pitch))
    first = -0.5 * (count - 1) * pitch
    for k in range(count):
        c = centre + (first + k * pitch) * left
        w = 0.5 * mark.stripe_m * left
        stripes.append(np.array([c - w, c - w + mark.length_m * along, c + w + mark.length_m * along, c + w]))
    return stripes


def _barrier_block(route: RoadPiece, spec: TrackSpec, block: BarrierBlock) -> Array:
    centre, along, left, half = _frame_at(route, block.s_m)
    sign = 1.0 if block.side == "left" else -1.0
    inner = centre + sign * (half + block.offset_m) * left
    outer = inner + sign * block.depth_m * left
    corners = np.array([inner, inner + block.length_m * along, outer + block.length_m * along, outer])
    return corners if sign > 0 else corners[::-1].copy()


def project_onto(piece: RoadPiece, xy: Array, hint: int | None = None,
                 back_m: float = 1.0, ahead_m: float = 5.0) -> Projection:
    """Project a point onto a centre line; with ``hint``, search only a window around it.

    The window keeps the projection on the right part of the road where the
    route passes near itself (a crossing, a hairpin): progress can only move by
    about as far as the kart can drive between two calls.
    """
    n = len(piece.s_m)
    if hint is None:
        candidates = np.arange(n)
    else:
        lo, hi = hint - int(back_m / SAMPLE_SPACING_M), hint + int(ahead_m / SAMPLE_SPACING_M)
        candidates = np.arange(lo, hi + 1) % n if piece.closed else np.arange(max(lo, 0), min(hi, n - 1) + 1)
    d2 = np.sum((piece.xy_m[candidates] - xy) ** 2, axis=1)
    i = int(candidates[int(np.argmin(d2))])
    heading = float(piece.heading_rad[i])
    delta = np.asarray(xy, float) - piece.xy_m[i]
    along = delta[0] * math.cos(heading) + delta[1] * math.sin(heading)
    offset = -delta[0] * math.sin(heading) + delta[1] * math.cos(heading)
    s = float(piece.s_m[i] + along)
    if piece.closed:
        s %= piece.length_m
    return Projection(i, s, float(offset), heading, float(piece.half_width_m[i]))


# --- construction helpers ---------------------------------------------------------------------

MAX_TRACK_M = 20_000.0
"""The longest track kartpilot builds: 20 km (the venue's course is 0.3 km, sdc-assen 1 km); a longer one, a typo of
a few zeros, would be sampled into billions of points before anything else could say so."""

MAX_CONTROL_POINTS = 5_000
"""The most control points a spline centre line may have (each becomes 2,000 samples)."""


def _centerline_points(spec: CenterlineSpec) -> Array:
    if bool(spec.segments) == bool(spec.points_m):
        raise ConfigError("track.centerline needs either 'segments' or 'points_m' (exactly one)")
    if spec.points_m:
        pts = np.asarray(spec.points_m, float)
        if len(pts) < 4:
            raise ConfigError("track.centerline.points_m needs at least 4 control points")
        if not np.all(np.isfinite(pts)) or pts.ndim != 2 or pts.shape[1] != 2:
            raise ConfigError("track.centerline.points_m must be finite (x, y) pairs")
        if len(pts) > MAX_CONTROL_POINTS or np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)) > MAX_TRACK_M:
            raise ConfigError(f"track.centerline.points_m: at most {MAX_CONTROL_POINTS} points and "
                              f"{MAX_TRACK_M / 1000:.0f} km of track")
        if spec.closed and len(pts) > 4 and np.linalg.norm(pts[-1] - pts[0]) < 1e-6:
            pts = pts[:-1]  # a loop written with its first point again at the end: the same loop
        repeats = np.flatnonzero(np.linalg.norm(np.diff(pts, axis=0), axis=1) < 1e-6)
        if len(repeats):  # a spline through a point twice has no direction there (a track of zero length)
            raise ConfigError(f"track.centerline.points_m[{int(repeats[0]) + 1}] repeats the point before it; "
                              "control points must differ from their neighbours")
        if spec.closed:
            pts = np.vstack([pts, pts[:1]])
        from scipy.interpolate import splev, splprep  # here: scipy.interpolate costs every command 0.1 s

        tck, _ = splprep(pts.T, s=0.0, per=1 if spec.closed else 0, k=3)
        u = np.linspace(0.0, 1.0, 40 * len(pts) * 50)
        return np.stack(splev(u, tck), axis=1)
    planned = sum(seg.straight_m + abs(math.radians(seg.angle_deg)) * seg.radius_m for seg in spec.segments)
    if not (math.isfinite(planned) and planned <= MAX_TRACK_M):
        raise ConfigError(f"track.centerline: its segments are {planned:.0f} m long; a track is at most "
                          f"{MAX_TRACK_M / 1000:.0f} km (it is sampled every centimetre)")
    x, y = spec.start_xy_m
    heading = math.radians(spec.start_heading_deg)
    out = [(x, y)]
    for i, seg in enumerate(spec.segments):
        if seg.straight_m > 0 and seg.radius_m == 0 and seg.angle_deg == 0:
            n = max(2, int(seg.straight_m / 0.01))
            t = np.linspace(0, seg.straight_m, n)[1:]
            out += list(zip(x + t * math.cos(heading), y + t * math.sin(heading), strict=True))
            x, y = out[-1]
        elif seg.radius_m > 0 and seg.angle_deg != 0 and seg.straight_m == 0:
            sign = math.copysign(1.0, seg.angle_deg)
            cx, cy = x - sign * seg.radius_m * math.sin(heading), y + sign * seg.radius_m * math.cos(heading)
            sweep = math.radians(seg.angle_deg)
            n = max(2, int(abs(sweep) * seg.radius_m / 0.01))
            a = heading - sign * math.pi / 2 + np.linspace(0, sweep, n)[1:]
            out += list(zip(cx + seg.radius_m * np.cos(a), cy + seg.radius_m * np.sin(a), strict=True))
            x, y = out[-1]
            heading += sweep
        else:
            raise ConfigError(f"track.centerline.segments[{i}] must be a straight (straight_m) "
                              "or an arc (radius_m and angle_deg), not both")
    pts = np.asarray(out)
    if spec.closed and np.hypot(*(pts[-1] - pts[0])) > 0.05:
        raise ConfigError(f"track.centerline is closed but its segments end {np.hypot(*(pts[-1] - pts[0])):.2f} m "
                          "from the start")
    if spec.closed:
        pts = pts[:-1]
    return pts


def _resample(xy: Array, closed: bool) -> Array:
    pts = np.vstack([xy, xy[:1]]) if closed else xy
    seg = np.hypot(*np.diff(pts, axis=0).T)
    s = np.r_[0.0, np.cumsum(seg)]
    total = s[-1]
    n = round(total / SAMPLE_SPACING_M)
    targets = np.arange(n) * (total / n) if closed else np.linspace(0.0, total, n + 1)
    return np.stack([np.interp(targets, s, pts[:, 0]), np.interp(targets, s, pts[:, 1])], axis=1)


def _piece(name: str, xy: Array, spec: TrackSpec, closed: bool) -> RoadPiece:
    if closed:
        ahead, behind = np.roll(xy, -1, axis=0), np.roll(xy, 1, axis=0)
    else:
        ahead, behind = np.vstack([xy[1:], 2 * xy[-1] - xy[-2]]), np.vstack([2 * xy[0] - xy[1], xy[:-1]])
    heading = np.arctan2(ahead[:, 1] - behind[:, 1], ahead[:, 0] - behind[:, 0])
    steps = np.hypot(*np.diff(xy, axis=0).T)
    s = np.r_[0.0, np.cumsum(steps)]
    dh = np.diff(np.unwrap(heading))
    curvature = np.r_[dh, dh[-1:]] / np.maximum(np.r_[steps, steps[-1:]], 1e-9)
    length = s[-1] + (float(np.hypot(*(xy[0] - xy[-1]))) if closed else 0.0)
    half = 0.5 * _width_along(spec, s, length if closed else None)
    return RoadPiece(name, xy, s, heading, curvature, half, closed)


def _width_along(spec: TrackSpec, s: Array, period: float | None) -> Array:
    if not spec.width_profile:
        return np.full(len(s), spec.width_m)
    prof = np.asarray(sorted(spec.width_profile), float)
    if np.any(prof[:, 1] <= 0):
        raise ConfigError("track.width_profile widths must be positive")
    if period is not None:
        return np.interp(s % period, prof[:, 0], prof[:, 1], period=period)
    return np.interp(s, prof[:, 0], prof[:, 1])


def _branch(route: RoadPiece, branch: Branch, number: int) -> RoadPiece:
    i0, i1 = route.index_at(branch.from_s_m), route.index_at(branch.to_s_m)
    if i1 <= i0 or (i1 - i0) * SAMPLE_SPACING_M < 2 * branch.ramp_m:
        raise ConfigError(f"track.branches[{number}] must span more than twice its ramp_m along the route")
    idx = np.arange(i0, i1 + 1)
    s = route.s_m[idx] - route.s_m[i0]
    span = s[-1]
    ramp = np.clip(np.minimum(s, span - s) / branch.ramp_m, 0.0, 1.0)
    smooth = ramp * ramp * (3 - 2 * ramp)
    sign = 1.0 if branch.side == "left" else -1.0
    xy = route.xy_m[idx] + (sign * branch.offset_m * smooth)[:, None] * route.normal()[idx]
    xy = _resample(xy, closed=False)
    half = np.interp(np.linspace(0, 1, len(xy)), np.linspace(0, 1, len(idx)), route.half_width_m[idx])
    piece = _piece(f"branch{number}", xy, TrackSpec(), closed=False)
    return RoadPiece(piece.name, piece.xy_m, piece.s_m, piece.heading_rad, piece.curvature_1pm, half, False)


class _RoadIndex:
    """Answers "is this point on the road surface?" for all pieces at once."""

    def __init__(self, pieces: tuple[RoadPiece, ...]) -> None:
        self.xy = np.vstack([p.xy_m for p in pieces])
        self.half = np.concatenate([p.half_width_m for p in pieces])
        self.tree = cKDTree(self.xy)
        self.max_half = float(self.half.max())

    def inside(self, points: Array, margin_m: float) -> NDArray[np.bool_]:
        """True where a point lies closer than half the width plus ``margin_m`` to some centre line."""
        radius = self.max_half + max(margin_m, 0.0)
        out = np.zeros(len(points), bool)
        if len(points) == 0:
            return out
        # every (point, centre sample) pair within the widest half width at once, where a loop over the points
        # asked the tree one point at a time (two seconds of each simulator's start on sdc-assen)
        pairs = cKDTree(points).sparse_distance_matrix(self.tree, radius, output_type="ndarray")
        near = pairs["v"] < self.half[pairs["j"]] + margin_m
        out[pairs["i"][near]] = True
        return out


def _runs(points: Array, keep: NDArray[np.bool_], closed: bool) -> list[Array]:
    """Split a polyline into the runs where ``keep`` holds (joining across the seam when closed)."""
    if keep.all():
        return [np.vstack([points, points[:1]]) if closed else points]
    runs: list[Array] = []
    idx = np.flatnonzero(keep)
    if len(idx) == 0:
        return runs
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts, ends = np.r_[idx[0], idx[breaks + 1]], np.r_[idx[breaks], idx[-1]]
    pieces = [points[a:b + 1] for a, b in zip(starts, ends, strict=True)]
    if closed and keep[0] and keep[-1] and len(pieces) > 1:
        pieces[0] = np.vstack([pieces.pop(), pieces[0]])
    return [p for p in pieces if len(p) >= 2]


def scenery_boxes(track: Track, spacing_m: float, seed: int, min_offset_m: float = 3.0,
                  max_offset_m: float = 14.0) -> Array:
    """Roadside buildings and boards as ``(N, 6)`` rows ``x, y, yaw, width, depth, height`` (metres, radians).

    One every ``spacing_m`` along the route (jittered), on a random side, ``min_offset_m`` to
    ``max_offset_m`` beyond the road's edge (beyond a barrier when there is one), facing the road;
    a box whose footprint would come near any road piece is left out. Real circuits have
    grandstands, pit buildings and signs; without them the scene has nothing that fixes a place.
    """
    if spacing_m <= 0:
        return np.zeros((0, 6))
    rng = np.random.default_rng(seed)
    road = _RoadIndex((track.route, *track.branches))
    route = track.route
    near = max(min_offset_m, track.spec.barrier_offset_m + 1.0)
    boxes: list[list[float]] = []
    s = float(rng.uniform(0, spacing_m))
    while s < route.length_m - 1.0:
        i = route.index_at(s)
        side = 1.0 if rng.random() < 0.5 else -1.0
        width, depth, height = rng.uniform(2.0, 7.0), rng.uniform(0.6, 3.0), rng.uniform(1.5, 5.0)
        offset = route.half_width_m[i] + rng.uniform(near, max(near, max_offset_m)) + depth / 2
        centre = route.xy_m[i] + side * offset * route.normal()[i]
        yaw = float(route.heading_rad[i] + rng.normal(0, 0.15))
        c, si = np.cos(yaw), np.sin(yaw)
        corners = centre + np.array([[dx * c - dy * si, dx * si + dy * c]
                                     for dx in (-width / 2, width / 2) for dy in (-depth / 2, depth / 2)])
        if not road.inside(np.vstack([corners, centre]), near - 0.5).any():
            boxes.append([centre[0], centre[1], yaw, width, depth, height])
        s += spacing_m * float(rng.uniform(0.6, 1.4))
    return np.array(boxes).reshape(-1, 6)


def roadside_trees(track: Track, spacing_m: float, seed: int, min_offset_m: float = 1.0,
                   max_offset_m: float = 4.0) -> Array:
    """Trees and lamp poles beside the road, near enough to throw their shadows across it when the sun is low, as
    ``(N, 5)`` rows ``x, y, trunk_m, height_m, crown_m``: a trunk ``trunk_m`` thick and ``height_m`` tall, and a
    crown ``crown_m`` wide on top of it (0: a pole). One every ``spacing_m`` along the route (jittered), on a random
    side, ``min_offset_m`` to ``max_offset_m`` beyond the road's edge; one that would stand on any road piece is
    left out."""
    if spacing_m <= 0:
        return np.zeros((0, 5))
    rng = np.random.default_rng(seed)
    road = _RoadIndex((track.route, *track.branches))
    route = track.route
    rows: list[list[float]] = []
    s = float(rng.uniform(0, spacing_m))
    while s < route.length_m - 1.0:
        i = route.index_at(s)
        side = 1.0 if rng.random() < 0.5 else -1.0
        pole = rng.random() < 0.3
        trunk, height = (0.12, rng.uniform(4.0, 6.0)) if pole else (rng.uniform(0.2, 0.4), rng.uniform(1.8, 3.0))
        crown = 0.0 if pole else rng.uniform(2.0, 4.0)
        offset = route.half_width_m[i] + rng.uniform(min_offset_m, max_offset_m) + max(crown, trunk) / 2
        centre = route.xy_m[i] + side * offset * route.normal()[i]
        if not road.inside(centre[None], max(crown, trunk) / 2 + 0.3).any():
            rows.append([float(centre[0]), float(centre[1]), trunk, height, crown])
        s += spacing_m * float(rng.uniform(0.6, 1.4))
    return np.array(rows).reshape(-1, 5)

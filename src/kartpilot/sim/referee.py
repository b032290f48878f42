"""The Self Driving Challenge referee.

A trial is disqualified when a tyre touches a boundary marker (a painted line
or a cone), when the kart leaves the track between markers, or when it takes
the wrong route at a split or a crossing. The referee also measures what a
team wants to know afterwards: metres driven, lap time, cones hit, and how far
the kart stayed from the lane centre.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import cKDTree

from kartpilot.core.errors import ConfigError
from kartpilot.core.vehicle import VehicleParams
from kartpilot.sim.dynamics import VehicleState
from kartpilot.sim.track import Track, project_onto

__all__ = ["Referee", "RefereeConfig", "RunResult"]


@dataclass(frozen=True)
class RefereeConfig:
    """Attributes:
        laps: laps to drive on a closed track (open tracks end at their finish).
        stop_on_disqualification: end the run at the first disqualification (the rules do).
        run_on_m: after the finish the run goes on for this distance before it ends (``inf``: the
            driver ends it, for a kart that stops by itself at the end of its reference path).
        may_cross_dashed: a dashed boundary (a two-lane road's centre line) may be crossed into the next lane,
            one lane's width beyond it, as an overtake does; a solid line still may not.
    """

    laps: int = 1
    stop_on_disqualification: bool = True
    run_on_m: float = 0.0
    may_cross_dashed: bool = False


@dataclass(frozen=True)
class RunResult:
    """The referee's verdict on one run. ``to_json`` gives the documented keys."""

    disqualified: bool
    reason: str
    distance_m: float
    lap_time_s: float | None
    laps_completed: int
    finished: bool
    cones_hit: int
    mean_center_offset_m: float
    max_center_offset_m: float
    sim_time_s: float
    wall_time_s: float
    disqualified_at_s_m: float | None
    disqualified_at_xy_m: tuple[float, float] | None

    def to_json(self) -> dict[str, object]:
        data = asdict(self)
        data["real_time_factor"] = self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else None
        return data


class Referee:
    """Watches the kart's ground-truth state, step by step."""

    def __init__(self, track: Track, vehicle: VehicleParams, config: RefereeConfig | None = None,
                 cones: bool = True) -> None:
        self.track = track
        self.vehicle = vehicle
        self.config = config or RefereeConfig()
        if self.config.laps < 1:
            raise ConfigError("referee.laps must be at least 1")
        if not self.config.run_on_m >= 0:
            raise ConfigError("referee.run_on_m must not be negative")
        self._cones = np.array([c.xy_m for c in track.cones]) if cones and track.cones else np.zeros((0, 2))
        self._cone_tree = cKDTree(self._cones) if len(self._cones) else None
        marking = track.spec.left if track.spec.left.kind == "cones" else track.spec.right
        self._cone_radius = marking.cone_base_m / 2
        self._hint = track.start_index
        self._progress_m = 0.0
        self._last_s = float(track.route.s_m[self._hint])
        self._hit: set[int] = set()
        self._offsets: list[float] = []
        self.time_s = 0.0
        self.distance_m = 0.0
        self.lap_time_s: float | None = None
        self.laps_completed = 0
        self.finished = False
        self._finished_at_m = 0.0
        self.reason = ""
        self.disqualified = False
        self.dq_s: float | None = None
        self.dq_xy: tuple[float, float] | None = None

    @property
    def done(self) -> bool:
        ran_on = self.finished and self._progress_m - self._finished_at_m >= self.config.run_on_m
        return ran_on or (self.disqualified and self.config.stop_on_disqualification)

    @property
    def progress_m(self) -> float:
        """Distance made good along the route since the start (laps included)."""
        return self._progress_m

    @property
    def route_index(self) -> int:
        """The route sample nearest the kart at the last update."""
        return self._hint

    def update(self, time_s: float, state: VehicleState) -> None:
        """Judge the kart at ``time_s``; call once per simulation step, in order."""
        if self.done:
            return
        self.time_s = time_s
        self.distance_m = state.odometer_m
        route = self.track.route
        c, s = math.cos(state.yaw_rad), math.sin(state.yaw_rad)
        centre = np.array([state.x_m + c * self.vehicle.wheelbase_m / 2, state.y_m + s * self.vehicle.wheelbase_m / 2])
        here = project_onto(route, centre, self._hint)
        self._advance(here.s_m, here.index)
        self._offsets.append(abs(here.offset_m))

        self._check_cones(centre, state, c, s, here.s_m)
        if not self.disqualified:
            self._check_boundaries(state, c, s, here.offset_m, here.half_width_m, centre)
        if self.finished or self.disqualified:
            return
        if self.track.closed:
            laps = int(self._progress_m // route.length_m)
            if laps > self.laps_completed:
                self.laps_completed = laps
                if laps >= self.config.laps:
                    self._finish(time_s)
        elif here.s_m >= self.track.finish_s_m:
            self.laps_completed = 1
            self._finish(time_s)

    def _finish(self, time_s: float) -> None:
        self.lap_time_s = time_s
        self.finished = True
        self._finished_at_m = self._progress_m

    def result(self, wall_time_s: float) -> RunResult:
        offsets = np.asarray(self._offsets) if self._offsets else np.zeros(1)
        reason = self.reason or ("finished" if self.finished else "stopped before the finish")
        return RunResult(
            disqualified=self.disqualified, reason=reason, distance_m=round(self.distance_m, 4),
            lap_time_s=None if self.lap_time_s is None else round(self.lap_time_s, 4),
            laps_completed=self.laps_completed, finished=self.finished, cones_hit=len(self._hit),
            mean_center_offset_m=round(float(offsets.mean()), 4), max_center_offset_m=round(float(offsets.max()), 4),
            sim_time_s=round(self.time_s, 4), wall_time_s=round(wall_time_s, 3),
            disqualified_at_s_m=None if self.dq_s is None else round(self.dq_s, 3),
            disqualified_at_xy_m=self.dq_xy,
        )

    # --- checks ------------------------------------------------------------------------------

    def _advance(self, s_m: float, index: int) -> None:
        route = self.track.route
        step = s_m - self._last_s
        if route.closed:
            step = (step + route.length_m / 2) % route.length_m - route.length_m / 2
        self._progress_m += step
        self._last_s = s_m
        self._hint = index

    def _disqualify(self, reason: str, s_m: float, xy: np.ndarray) -> None:
        if not self.disqualified:
            self.disqualified = True
            self.reason = reason
            self.dq_s = float(s_m)
            self.dq_xy = (round(float(xy[0]), 3), round(float(xy[1]), 3))

    def _check_cones(self, centre: np.ndarray, state: VehicleState, c: float, s: float, s_m: float) -> None:
        if self._cone_tree is None:
            return
        x0, x1, y0, y1 = self.vehicle.footprint_body()
        reach = math.hypot(max(abs(x0), abs(x1)) + self.vehicle.wheelbase_m, max(abs(y0), abs(y1))) + 0.5
        for i in self._cone_tree.query_ball_point(centre, reach):
            if i in self._hit:
                continue
            dx, dy = self._cones[i, 0] - state.x_m, self._cones[i, 1] - state.y_m
            bx, by = c * dx + s * dy, -s * dx + c * dy  # the cone in the body frame
            gap = math.hypot(max(x0 - bx, 0.0, bx - x1), max(y0 - by, 0.0, by - y1))
            if gap < self._cone_radius:
                self._hit.add(i)
                self._disqualify(f"hit a cone at s={s_m:.1f} m", s_m, self._cones[i])

    def _check_boundaries(self, state: VehicleState, c: float, s: float, centre_offset: float,
                          centre_half_width: float, centre: np.ndarray) -> None:
        track, route = self.track, self.track.route
        if abs(centre_offset) > centre_half_width and track.branches:
            for branch in track.branches:
                on_branch = project_onto(branch, centre)
                if abs(on_branch.offset_m) < on_branch.half_width_m and 0 < on_branch.index < len(branch.s_m) - 1:
                    self._disqualify(f"wrong route at the split (s={self._last_s:.1f} m)", self._last_s, centre)
                    return
        for bx, by in self.vehicle.tyre_points_body():
            tyre = np.array([state.x_m + c * bx - s * by, state.y_m + s * bx + c * by])
            p = project_onto(route, tyre, self._hint, back_m=2.0, ahead_m=3.0)
            side = "left" if p.offset_m > 0 else "right"
            marking = track.spec.left if side == "left" else track.spec.right
            limit = p.half_width_m - (marking.line_width_m / 2 if marking.kind == "line" else 0.0)
            if self.config.may_cross_dashed and track.dashed_at(side, p.s_m):  # type: ignore[arg-type]
                limit = 3 * p.half_width_m - marking.line_width_m / 2  # the next lane, to its far edge
                if abs(p.offset_m) <= limit:
                    continue
            if abs(p.offset_m) <= limit:
                continue
            if track.marked(side, p.index):  # type: ignore[arg-type]
                what = f"touched the {side} line" if marking.kind == "line" else f"left the track on the {side}"
                self._disqualify(f"{what} at s={p.s_m:.1f} m", p.s_m, tyre)
                return
            if abs(centre_offset) > centre_half_width and not (self.config.may_cross_dashed
                                                               and abs(centre_offset) <= 3 * centre_half_width):
                self._disqualify(f"left the route at s={p.s_m:.1f} m (no marking there)", p.s_m, centre)
                return

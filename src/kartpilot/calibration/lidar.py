"""The LiDAR's mount on the kart from a calibration board held upright, seen by the centre camera and the LiDAR.

The target is the board the cameras are calibrated with (a ChArUco board or a chessboard), stood upright on the
ground or held so that it crosses the LiDAR's scan plane, at a few places around the front of the kart, turned a
different way at each (a board seen only face on leaves the LiDAR's turn along it unmeasured). At each place:

* the centre camera, whose intrinsics and mount are calibrated, finds the board and its pose
  (:func:`kartpilot.calibration.ground.board_pose`); the board's plane cut by the scan plane is a segment on the
  kart's body frame (:func:`board_segment_body`);
* the LiDAR sees the same board as a line of returns in its own frame.

:func:`fit_lidar_mount` finds the mount (``x_m``, ``y_m``, ``yaw_rad``) that puts the LiDAR's returns on the
camera's segments: least squares on each return's distance to its segment's line, starting from the mount as
measured by hand (the rig file's), each return taken if it lies within a gate of its segment (the gate narrows as
the fit improves, so the floor or a person holding the board are left out). The scan plane's height (``z_m``) is not
measured by a planar sweep of an upright board: it stays the hand-measured one, which only has to put the plane
across the board. The residual (the returns' RMS distance to their lines) and each place's share say how well it
went; a fit that cannot tell the mount (fewer than two places, all facing the same way) is refused.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from kartpilot.calibration.board import BoardConfig
from kartpilot.core.errors import CalibrationError
from kartpilot.core.geometry import Array, transform_points_2d
from kartpilot.core.types import LidarMount

__all__ = ["BoardSighting", "LidarFit", "board_extent_m", "board_segment_body", "fit_lidar_mount"]

GATES_M = (0.5, 0.25, 0.1, 0.05)
"""The gates a return must lie within of its segment, one round of the fit each, widest first."""
MIN_TURN_DEG = 20.0
"""The least angle between two places' boards for the LiDAR's turn and its position along a board to be told."""


def board_extent_m(board: BoardConfig) -> tuple[tuple[float, float], tuple[float, float]]:
    """The board's printed area in its own frame ((u0, u1), (v0, v1)): a ChArUco board's squares from its corner, a
    chessboard's from a square before its first inner corner to a square after its last."""
    if board.kind == "charuco":
        return (0.0, board.columns * board.square_m), (0.0, board.rows * board.square_m)
    s = board.square_m
    return (-s, board.columns * s), (-s, board.rows * s)


def board_segment_body(board_in_body: Array, board: BoardConfig, plane_z_m: float) -> Array | None:
    """(2, 2) the two ends, on the body's ground plane, of where the board's printed area crosses the horizontal
    plane ``plane_z_m`` up; None where it does not (a board lying flat, or wholly above or below the plane)."""
    rotation, origin = board_in_body[:3, :3], board_in_body[:3, 3]
    (u0, u1), (v0, v1) = board_extent_m(board)
    du, dv = rotation[2, 0], rotation[2, 1]  # how the height changes along the board's u and v
    if abs(dv) < 1e-6:
        return None  # its rows run level: a board lying flat, or turned on its side
    ends = []
    for u in (u0, u1):
        v = (plane_z_m - origin[2] - du * u) / dv
        ends.append((u, v))
    (ua, va), (ub, vb) = ends
    # keep the part of the line u -> v(u) inside the board's v range
    lo, hi = sorted(((v0 - va) / (vb - va), (v1 - va) / (vb - va))) if abs(vb - va) > 1e-12 else (0.0, 1.0)
    if abs(vb - va) <= 1e-12 and not v0 <= va <= v1:
        return None
    t0, t1 = max(lo, 0.0), min(hi, 1.0)
    if t1 - t0 < 1e-6:
        return None
    points = []
    for t in (t0, t1):
        u, v = ua + t * (ub - ua), va + t * (vb - va)
        p = origin + rotation @ np.array([u, v, 0.0])
        points.append(p[:2])
    return np.array(points)


@dataclass(frozen=True)
class BoardSighting:
    """One place of the board: its segment on the body frame from the camera, and the sweep's returns (x, y in the
    LiDAR's own frame) taken at that moment."""

    name: str
    segment_body_m: Array
    points_lidar_m: Array


@dataclass(frozen=True)
class LidarFit:
    """The mount found, the returns' RMS distance to their boards' lines, and per place how many returns fitted
    and their RMS (NaN where none did)."""

    mount: LidarMount
    rms_m: float
    per_place: tuple[tuple[str, int, float], ...]

    def lines(self) -> list[str]:
        m = self.mount
        out = [f"LiDAR mount: x {m.x_m:.3f} m, y {m.y_m:.3f} m, turned {math.degrees(m.yaw_rad):.2f} deg "
               f"(z {m.z_m:.3f} m as measured); the returns' RMS distance to the boards {self.rms_m * 1000:.1f} mm"]
        out += [f"  {name}: {count} returns, {rms * 1000:.1f} mm" for name, count, rms in self.per_place]
        return out


def _near_segment(points: Array, segment: Array, gate_m: float) -> Array:
    a, b = segment
    edge = b - a
    u = np.clip(((points - a) @ edge) / max(float(edge @ edge), 1e-12), 0.0, 1.0)
    return np.asarray(np.hypot(*(points - (a + u[:, None] * edge)).T) <= gate_m)


def _normal(segment: Array) -> Array:
    edge = segment[1] - segment[0]
    return np.array([-edge[1], edge[0]]) / max(float(np.hypot(*edge)), 1e-12)


def _residuals(params: Array, taken: list[tuple[Array, Array]]) -> Array:
    """Each return's signed distance, on the body frame, to its board's line, the LiDAR at ``params``."""
    return np.concatenate([(transform_points_2d(points, *params) - segment[0]) @ _normal(segment)
                           for points, segment in taken])


def _widest_turn_deg(headings_deg: Sequence[float]) -> float:
    """The largest angle between two of the boards' lines (headings in degrees, a line's modulo 180)."""
    return max((min(abs(a - b), 180.0 - abs(a - b)) for a in headings_deg for b in headings_deg), default=0.0)


def fit_lidar_mount(sightings: Sequence[BoardSighting], initial: LidarMount, min_points: int = 5) -> LidarFit:
    """The LiDAR's mount that puts its returns on the camera's boards (module docstring). ``initial``: the mount
    measured by hand (its height is kept)."""
    if len(sightings) < 2:
        raise CalibrationError(f"the board was found at {len(sightings)} place(s); two or more are needed, turned "
                               f"at least {MIN_TURN_DEG:g} deg from each other")
    headings = [math.degrees(math.atan2(*(s.segment_body_m[1] - s.segment_body_m[0])[::-1])) % 180.0
                for s in sightings]
    turn = _widest_turn_deg(headings)
    if turn < MIN_TURN_DEG:
        raise CalibrationError(f"the board faced the same way at every place (its turns differ by {turn:.1f} deg at "
                               f"most): turn it by {MIN_TURN_DEG:g} deg or more between places, or the LiDAR's turn "
                               "cannot be told from its position along the board")
    x = np.array([initial.x_m, initial.y_m, initial.yaw_rad])
    chosen: list[Array] = []
    for gate in GATES_M:
        chosen = [_near_segment(transform_points_2d(s.points_lidar_m, *x), s.segment_body_m, gate) for s in sightings]
        used = [k for k, keep in enumerate(chosen) if int(keep.sum()) >= min_points]
        if len(used) < 2 or _widest_turn_deg([headings[k] for k in used]) < MIN_TURN_DEG:
            raise CalibrationError(f"the LiDAR's returns lie on the camera's boards at {len(used)} place(s) within "
                                   f"{gate * 100:.0f} cm of the hand-measured mount; is the rig's lidar mount within "
                                   "a few decimetres and a few degrees, and does the scan plane cross the board?")

        taken = [(sightings[k].points_lidar_m[chosen[k]], sightings[k].segment_body_m) for k in used]
        x = least_squares(_residuals, x, args=(taken,), loss="soft_l1", f_scale=0.02).x
    per_place = []
    everything = []
    for k, sighting in enumerate(sightings):
        keep = chosen[k]
        points = transform_points_2d(sighting.points_lidar_m[keep], *x)
        distance = (points - sighting.segment_body_m[0]) @ _normal(sighting.segment_body_m)
        everything.append(distance)
        rms = float(np.sqrt(np.mean(distance ** 2))) if len(distance) else math.nan
        per_place.append((sighting.name, int(keep.sum()), rms))
    all_distance = np.concatenate(everything)
    mount = LidarMount(float(x[0]), float(x[1]), initial.z_m, float(math.remainder(x[2], math.tau)))
    return LidarFit(mount, float(np.sqrt(np.mean(all_distance ** 2))), tuple(per_place))

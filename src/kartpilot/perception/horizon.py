"""The camera's pitch on the kart, measured while driving from the lane's boundaries.

A camera knocked a degree down from where the rig says puts the ground 10 m ahead at 7 m, and a foot 25 m ahead
metres off: every distance the detectors place on the ground (a stop line, a bay's far barrier, a person) goes
with it. The two boundaries of a lane are parallel on the ground, so their tangents at one row (one distance
ahead) meet on the horizon, in a bend as on a straight; where they meet above or below the horizon the rig's
mount draws is the pitch the mount is off by (the classic vanishing-point self-calibration of road cameras; the
thesis steered toward the same meeting point). The median of the last frames' pitches is robust to a frame whose
boundary is a shadow, a curb or a barrier's base.

Only the pitch: the height cannot be told from a vanishing point, and the roll (which tilts the horizon) needs
meeting points spread across the image, which a kart on its lane does not give.

The tangents are taken near the kart (``ahead_m``, where both boundaries must have been seen): the
paint finder's curves bend toward the horizon the rig says, so a far tangent leans with the error it should
measure (simulated, 1 s of driving: the pitch off by 0.70, 0.47 and -0.22 deg read 0.69, 0.51 and -0.30 at 5 m;
0.35, 0.27 and -0.66 at 8 m).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.config import check_values
from kartpilot.core.geometry import invert_pose, pitched_mount, transform_points
from kartpilot.perception.lanes import LaneObservation
from kartpilot.perception.obstacles import ground_row
from kartpilot.perception.paint import LaneCurve

__all__ = ["HorizonConfig", "HorizonEstimator", "bend_deg", "horizon_row_at", "meeting_point", "pitch_off_deg"]


@dataclass(frozen=True)
class HorizonConfig:
    """Attributes:
        enabled: measure the pitch while driving and place what the detectors find with it.
        ahead_m: the tangents are taken where the ground this far ahead of the camera is seen.
        window: the last this many frames with both boundaries are kept.
        spacing_m: a frame counts once the kart has moved this far since the last one that did (a kart standing at
            a start line sees one view over and over: it would agree with itself whatever it read).
        min_frames, max_spread_deg: a correction is used once this many frames are kept (2 m of driving at
            least) and the middle half of them lies within ``max_spread_deg`` (a lane that agrees with itself;
            until then the rig's mount, or the last correction used). The parking bay comes 20 m after the start:
            with 15 frames the pitch came after the kart had passed it.
        seen_to_m, max_bend_deg: a frame counts where both boundaries are seen from ``ahead_m`` to ``seen_to_m``
            ahead at least (a boundary seen over a metre or two gives no direction to trust), and neither one's
            direction in the image turns more than ``max_bend_deg`` between its nearest row and there (a
            straight line's image is straight; in a tight bend or at a junction the curves' tangents lean: of the
            real venue clip, taken in bends, a few frames pass).
        max_pitch_deg: a frame's pitch farther off than this is not a lane's (a boundary taken for another line).
    """

    enabled: bool = True
    ahead_m: float = 5.0
    window: int = 90
    spacing_m: float = 0.25
    min_frames: int = 8
    max_spread_deg: float = 0.5
    seen_to_m: float = 6.0
    max_bend_deg: float = 10.0
    max_pitch_deg: float = 3.0

    def __post_init__(self) -> None:
        check_values("horizon", self, (
            ("ahead_m", self.ahead_m > 0, "positive"),
            ("window", self.window >= 1, "at least 1"),
            ("spacing_m", self.spacing_m >= 0, "0 or more"),
            ("min_frames", 1 <= self.min_frames <= self.window, "between 1 and window"),
            ("max_spread_deg", self.max_spread_deg > 0, "positive"),
            ("seen_to_m", self.seen_to_m > self.ahead_m, "more than ahead_m"),
            ("max_bend_deg", 0 < self.max_bend_deg <= 90, "in (0, 90]"),
            ("max_pitch_deg", 0 < self.max_pitch_deg <= 15, "in (0, 15]")))


def _tangent(curve: LaneCurve, row: float) -> tuple[float, float]:
    """The curve's column at ``row`` and its slope there (columns per row)."""
    dy = max(row - curve.horizon_y, 1e-3)
    return float(curve.x_at(row)), curve.b - curve.c / dy ** 2


def bend_deg(curve: LaneCurve, far_row: float | None = None) -> float:
    """How far the curve's direction in the image turns between its nearest row seen and ``far_row`` (its
    farthest seen where not given, or where it was not seen that far)."""
    far_row = curve.y_far if far_row is None else min(max(far_row, curve.y_far), curve.y_near)
    far, near = (math.degrees(math.atan(_tangent(curve, row)[1])) for row in (far_row, curve.y_near))
    return abs(near - far)


def meeting_point(left: LaneCurve, right: LaneCurve, row: float) -> tuple[float, float] | None:
    """Where the two boundaries' tangents at ``row`` meet (column, row), or None where they do not meet above it
    with the left one on the left."""
    xl, sl = _tangent(left, row)
    xr, sr = _tangent(right, row)
    if not xl < xr or abs(sl - sr) < 1e-9:
        return None
    t = (xr - xl) / (sl - sr)
    if t >= 0:
        return None  # they part upward: not two sides of a lane ahead
    return xl + sl * t, row + t


def horizon_row_at(camera: PinholeCamera, column: float) -> float:
    """The row of the horizon the camera's mount draws, at ``column`` (the ground at a great distance)."""
    to_camera = invert_pose(camera.pose_body_cam_array)
    far = transform_points(to_camera, np.array([[1.0e4, -1.0e3, 0.0], [1.0e4, 1.0e3, 0.0]]))
    (u0, v0), (u1, v1) = camera.project(far)
    return float(v0 + (v1 - v0) * (column - u0) / (u1 - u0)) if abs(u1 - u0) > 1e-9 else float(v0)


def pitch_off_deg(camera: PinholeCamera, point: tuple[float, float]) -> float:
    """How far further down than its mount says the camera looks, from where the lane's boundaries meet: above the
    drawn horizon, the view is lower."""
    column, row = point

    def elevation(v: float) -> float:  # of the ray through that row, in the camera's vertical plane
        return math.atan2(camera.cy_px - v, camera.fy_px)

    return math.degrees(elevation(row) - elevation(horizon_row_at(camera, column)))


class HorizonEstimator:
    """The pitch the camera's mount is off by, from the last frames' boundaries; the camera as it is mounted."""

    def __init__(self, camera: PinholeCamera, config: HorizonConfig = HorizonConfig()) -> None:
        self.config = config
        self.rig_camera = camera
        self.camera = camera  # as it is mounted, once measured: the rig's until then
        self.pitch_deg = 0.0
        self.frames: deque[float] = deque(maxlen=config.window)
        self._moved_m = 0.0  # since the last frame kept
        self._row, self._far_row = ground_row(camera, config.ahead_m), ground_row(camera, config.seen_to_m)

    def update(self, observation: LaneObservation | None, moved_m: float = math.inf) -> PinholeCamera:
        """One frame's boundaries, and how far the kart moved since the frame before (unknown: infinite, every
        frame counts); the camera as it is mounted, as far as measured."""
        self._moved_m += moved_m if math.isfinite(moved_m) else self.config.spacing_m
        if not self.config.enabled or observation is None or not math.isfinite(self._row):
            return self.camera
        left, right = observation.left_curve, observation.right_curve
        if left is None or right is None or self._moved_m < self.config.spacing_m:
            return self.camera
        if max(left.y_far, right.y_far) > self._far_row or not self._row <= min(left.y_near, right.y_near):
            return self.camera  # both boundaries seen from ahead_m to seen_to_m ahead at least
        if max(bend_deg(left, self._far_row), bend_deg(right, self._far_row)) > self.config.max_bend_deg:
            return self.camera
        point = meeting_point(left, right, self._row)
        if point is None:
            return self.camera
        pitch = pitch_off_deg(self.rig_camera, point)
        if abs(pitch) <= self.config.max_pitch_deg:
            self.frames.append(pitch)
            self._moved_m = 0.0
        if len(self.frames) >= self.config.min_frames:
            low, measured, high = np.percentile(self.frames, (25, 50, 75))
            if high - low <= self.config.max_spread_deg and abs(measured - self.pitch_deg) >= 0.01:
                self.pitch_deg = float(measured)
                self.camera = self.rig_camera.on_body(pitched_mount(self.rig_camera.pose_body_cam_array, measured))
        return self.camera

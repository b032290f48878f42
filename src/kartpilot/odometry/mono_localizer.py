"""One camera, localised in metres on a reference: monocular VO fused with place fixes.

Monocular VO (:mod:`kartpilot.odometry.mono_vo`) gives the motion from frame to frame with
its scale from the ground plane; it drifts. Place recognition against the reference drive's
database (:mod:`kartpilot.odometry.places`) gives absolute but coarse positions. An extended
Kalman filter on the rear axle's planar pose ``x, y, yaw`` and VO's scale error ``k`` joins them:

- predict with VO's step times ``k`` (the uncertainty grows with the distance driven);
- update with each accepted place fix, every ``place_every_m`` driven: the fix's position, with
  ``sigma_m`` along the track, and its heading. Across the track and in heading a fix registered on
  the place's road (a top view, :mod:`kartpilot.perception.birdseye`) is good to centimetres and a
  fraction of a degree; an unregistered one gets at least ``cross_track_sigma_m`` across the track (it
  is where the reference drive was, and the kart may be on another line) and the check's heading,
  if any. A fix outside the 99.9 % gate is rejected and counted.
- ``k`` starts at 1 with ``scale_sigma`` (the ground plane's scale is biased where the road's texture
  is weak) and is learnt from the fixes: when VO keeps falling short of them, ``k`` grows, so a
  biased scale does not keep pulling the estimate off between fixes.
- where the kart measures its own speed (the RDW kart's 0x440, :meth:`PoseTracker.observe_speed`), each
  VO step's length is compared with the distance the wheels drove in the same time, which teaches
  ``k`` between fixes too (``wheel_sigma_mps``; a kart standing still teaches nothing).

The frame is the reference's: the rear axle at the database's first place, x forward, y left
(:func:`place_ground_poses`), so a reference path built from the same drive lines up. The first
accepted fix places the kart, wherever it starts on the reference; until then the pose is
bridged, and ``lost`` after ``max_bridge_s``, which stops the kart.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError, OdometryError, PerceptionError
from kartpilot.core.geometry import Array, Pose2D, between_2d, compose_2d, invert_pose, vo_ground_pose
from kartpilot.core.types import FrameSet, VehiclePose
from kartpilot.core.vehicle import VehicleParams
from kartpilot.odometry.localizer import PoseTracker
from kartpilot.odometry.mono_vo import MonoVO, MonoVOConfig
from kartpilot.odometry.places import PlaceDatabase, PlaceFix
from kartpilot.sensors.health import HealthConfig, frame_problem

__all__ = ["FixFilter", "MonoLocalizer", "MonoLocalizerConfig", "along_arc", "place_ground_poses"]

log = logging.getLogger(__name__)

GATE_CHI2 = 16.27  # 99.9 % of a chi-square with 3 degrees of freedom


@dataclass(frozen=True)
class MonoLocalizerConfig:
    """Attributes:
        camera: the camera's name in the frame sets.
        health: when a frame counts as black, blank or frozen (bridged, not used).
        max_bridge_s: how long the motion model may stand in before the pose is ``lost``.
        speed_time_constant_s: low-pass time constant of the speed and yaw-rate estimates.
        place_every_m: query the place database after driving this far (and on every frame until the first fix).
        settle_at_start, settled_sigma_m: query on every frame at the start, until the position's standard
            deviation first comes below ``settled_sigma_m``: after a start on ambiguous fixes, the first
            unambiguous one comes sooner. Off by default: each query costs about 60 ms, and in the closed-loop
            simulator test the kart's line varied by up to half a metre with it, depending on what ran before
            (not understood yet). A replay, which is not bound to the loop's period, can afford it.
        cross_track_sigma_m: an unregistered fix's least standard deviation across the track.
        vo_sigma_per_m: VO's position error per metre driven (standard deviation); ``vo_yaw_sigma_per_m`` likewise.
        scale_sigma: the initial standard deviation of VO's scale error (relative).
        scale_sigma_per_m: how fast the scale error may change, per metre driven.
        wheel_sigma_mps: the measured speed's standard deviation (resolution, wheel slip), for the scale.
    """

    camera: str = "center"
    health: HealthConfig = field(default_factory=HealthConfig)
    max_bridge_s: float = 0.5
    speed_time_constant_s: float = 0.15
    place_every_m: float = 1.0
    settle_at_start: bool = False
    settled_sigma_m: float = 0.3
    cross_track_sigma_m: float = 1.0
    vo_sigma_per_m: float = 0.05
    vo_yaw_sigma_per_m: float = 0.02
    scale_sigma: float = 0.3
    scale_sigma_per_m: float = 0.01
    wheel_sigma_mps: float = 0.15

    def __post_init__(self) -> None:
        if not (self.place_every_m > 0 and self.cross_track_sigma_m > 0 and self.settled_sigma_m > 0):
            raise ConfigError("mono_localizer.place_every_m, cross_track_sigma_m and settled_sigma_m must be positive")
        if not all(v > 0 for v in (self.vo_sigma_per_m, self.vo_yaw_sigma_per_m, self.scale_sigma,
                                   self.scale_sigma_per_m, self.wheel_sigma_mps)):  # NaN too
            raise ConfigError("mono_localizer.vo_sigma_per_m, vo_yaw_sigma_per_m, scale_sigma, scale_sigma_per_m and "
                              "wheel_sigma_mps must be positive")


def along_arc(step: Pose2D) -> Pose2D:
    """A planar step as a kart can make it: its length along a circular arc with its change of heading.

    A kart does not move sideways (Ackermann steering, no slip at these speeds), so the sideways
    part of a step is VO's error: the direction of a monocular translation is its least certain
    part, and at half a metre per frame a few degrees off give decimetres sideways.
    """
    forward, sideways, turn = step
    length = math.copysign(math.hypot(forward, sideways), forward)
    return length * math.cos(turn / 2), length * math.sin(turn / 2), turn


def place_ground_poses(poses_world_cam: Array, pose_body_cam: Array, origin_world_cam: Array) -> Array:
    """``(N, 3)`` rear-axle ``x, y, yaw`` of camera poses, in the frame of the body at ``origin_world_cam``."""
    body_cam_inv = invert_pose(np.asarray(pose_body_cam, float))
    origin = invert_pose(np.asarray(origin_world_cam, float) @ body_cam_inv)
    body = origin @ np.asarray(poses_world_cam, float).reshape(-1, 4, 4) @ body_cam_inv
    return np.column_stack([body[:, 0, 3], body[:, 1, 3], np.arctan2(body[:, 1, 0], body[:, 0, 0])])


class FixFilter:
    """The extended Kalman filter on ``x, y, yaw`` and VO's scale factor ``k`` (see the module's description).
    Holds only the state and its covariance; empty until :meth:`place` sets the first fix."""

    def __init__(self, config: MonoLocalizerConfig) -> None:
        self.config = config
        self.state: Array | None = None
        self.covariance = np.zeros((4, 4))

    @property
    def scale(self) -> float:
        return 1.0 if self.state is None else float(self.state[3])

    @property
    def position_sigma_m(self) -> float:
        """The position's standard deviation along its least certain direction (inf before the first fix)."""
        if self.state is None:
            return math.inf
        return math.sqrt(max(float(np.linalg.eigvalsh(self.covariance[:2, :2])[-1]), 0.0))

    def place(self, measured: Array, noise: Array) -> None:
        """Start at a fix (``x, y, yaw`` and its 3x3 covariance), with the scale factor 1 and ``scale_sigma``."""
        self.state = np.r_[np.asarray(measured, float), 1.0]
        self.covariance = np.zeros((4, 4))
        self.covariance[:3, :3] = noise
        self.covariance[3, 3] = self.config.scale_sigma ** 2

    def predict(self, vo_step: Pose2D) -> None:
        """Move by VO's step (in VO's units) times the scale factor; the uncertainty grows with the distance."""
        assert self.state is not None
        x, y, yaw, scale = self.state
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = scale * vo_step[0], scale * vo_step[1]
        jacobian = np.eye(4)
        jacobian[0, 2], jacobian[1, 2] = -s * dx - c * dy, c * dx - s * dy
        jacobian[0, 3], jacobian[1, 3] = c * vo_step[0] - s * vo_step[1], s * vo_step[0] + c * vo_step[1]
        self.state = np.array([*compose_2d((x, y, yaw), (dx, dy, vo_step[2])), scale])
        cfg, distance = self.config, math.hypot(dx, dy)
        noise = np.diag([(cfg.vo_sigma_per_m * distance) ** 2] * 2 + [(cfg.vo_yaw_sigma_per_m * distance) ** 2,
                                                                      (cfg.scale_sigma_per_m * distance) ** 2])
        self.covariance = jacobian @ self.covariance @ jacobian.T + noise

    def correct(self, measured: Array, noise: Array) -> bool:
        """Fold in a fix (``x, y, yaw`` and its covariance); False when the 99.9 % gate rejects it. A heading
        beyond three sigma is dropped and the position still used: the check's rotation is its least
        reliable part in bends (two views of a turn a metre apart)."""
        assert self.state is not None
        noise = np.array(noise, float)
        innovation = np.asarray(measured, float) - self.state[:3]
        innovation[2] = math.remainder(float(innovation[2]), math.tau)
        if innovation[2] ** 2 > 9.0 * (self.covariance[2, 2] + noise[2, 2]):
            innovation[2], noise[2, 2] = 0.0, math.pi ** 2
        covariance = self.covariance[:3, :3] + noise
        if float(innovation @ np.linalg.solve(covariance, innovation)) > GATE_CHI2:
            return False
        gain = self.covariance[:, :3] @ np.linalg.inv(covariance)
        self.state = self.state + gain @ innovation
        self.state[2] = math.remainder(float(self.state[2]), math.tau)
        self.state[3] = float(np.clip(self.state[3], 0.5, 2.0))
        self.covariance = self.covariance - gain @ self.covariance[:3, :]
        return True

    def correct_distance(self, vo_length: float, driven_m: float, sigma_m: float) -> None:
        """Fold in the distance the wheels measured for VO's last step (``vo_length`` in VO's units): it
        observes the scale factor, ``driven_m = k * vo_length``."""
        assert self.state is not None
        if vo_length <= 0 or sigma_m <= 0:
            return
        h = np.zeros(4)
        h[3] = vo_length
        variance = float(h @ self.covariance @ h) + sigma_m ** 2
        gain = self.covariance @ h / variance
        self.state = self.state + gain * (driven_m - self.state[3] * vo_length)
        self.state[3] = float(np.clip(self.state[3], 0.5, 2.0))
        self.covariance = self.covariance - np.outer(gain, h @ self.covariance)


class MonoLocalizer(PoseTracker):
    """Holds the VO, the filter's state and covariance, and the recent fixes for the scale."""

    def __init__(self, camera: PinholeCamera, places: PlaceDatabase, vo_config: MonoVOConfig | None = None,
                 config: MonoLocalizerConfig | None = None, *,
                 wrap_vo: Callable[[MonoVO], MonoVO] | None = None, vehicle: VehicleParams | None = None) -> None:
        """``wrap_vo`` is the seam fault injection wraps the VO at (``vo-failure``); ``vehicle``, the kart, whose
        tyres' slip the VO's arc steps take into account."""
        self.config = config or MonoLocalizerConfig()
        super().__init__(self.config.max_bridge_s, self.config.speed_time_constant_s)
        if camera.size_wh != places.camera.size_wh:
            raise ConfigError(f"the place database is of a {places.camera.size_wh} camera, the kart's "
                              f"{self.config.camera!r} camera is {camera.size_wh}")
        if not np.allclose(camera.matrix, places.camera.matrix, rtol=1e-3) or any(camera.distortion):
            raise ConfigError(f"the place database's camera matrix is not the {self.config.camera!r} camera's "
                              "pinhole one: build the database from this camera's drive")
        vo_config = vo_config or MonoVOConfig()
        height = float(camera.pose_body_cam_array[2, 3])
        if height > 0:  # the mount knows the camera's height above the road better than a default
            vo_config = replace(vo_config, ground=replace(vo_config.ground, camera_height_m=height))
        vo = MonoVO(camera, vo_config, self.config.camera, vehicle)
        self.vo = wrap_vo(vo) if wrap_vo is not None else vo
        self._camera = camera
        self.places = places
        self.body_cam = camera.pose_body_cam_array
        self._origin = places.poses_world_cam[0]
        self.filter = FixFilter(self.config)
        self._raw: Pose2D | None = None
        self._raw_stamp_ns = 0
        self._since_query_m = math.inf
        self._settled = not self.config.settle_at_start  # the position's sigma has come below settled_sigma_m
        self._previous_image: np.ndarray | None = None
        self.relocalisations = 0  # accepted place fixes
        self.rejected_fixes = 0
        self.timing_ms: dict[str, float] = {}

    @property
    def camera_name(self) -> str:
        return self.config.camera

    @property
    def camera(self) -> PinholeCamera:
        return self._camera

    @property
    def scale_correction(self) -> float:
        """The factor VO's steps are multiplied by (learnt from the place fixes)."""
        return self.filter.scale

    def close(self) -> None:
        pass

    def update(self, frames: FrameSet) -> VehiclePose:
        """The pose at ``frames.stamp_ns``."""
        image = frames.images.get(self.config.camera)
        if image is None:
            return self._bridge(frames.stamp_ns, f"the {self.config.camera} camera delivered nothing")
        problem = frame_problem(image, self._previous_image, self.config.health)
        self._previous_image = image
        if problem:
            return self._bridge(frames.stamp_ns, f"the {self.config.camera} camera's frame is {problem}")
        t0 = time.perf_counter()
        try:
            estimate = self.vo.process(frames)
        except (PerceptionError, OdometryError) as exc:
            return self._bridge(frames.stamp_ns, str(exc))
        t1 = time.perf_counter()
        raw = vo_ground_pose(estimate.pose_world_cam, self.body_cam)
        vo_step = (0.0, 0.0, 0.0) if self._raw is None else along_arc(between_2d(self._raw, raw))
        scale = self.scale_correction
        dt = 0.0 if self._raw is None else (frames.stamp_ns - self._raw_stamp_ns) * 1e-9
        if estimate.status == "bridged" and self._last is not None:
            # VO skipped this frame's motion (it is lost for good: the next frame is matched to this one), so
            # the motion model stands in for it, in VO's units
            vo_step = along_arc((self._last.speed_mps * dt / scale, 0.0, self._last.yaw_rate_radps * dt))
        step = (vo_step[0] * scale, vo_step[1] * scale, vo_step[2])
        self._raw, self._raw_stamp_ns = raw, frames.stamp_ns
        distance = math.hypot(step[0], step[1])
        self._since_query_m += distance
        if self.filter.state is not None:
            self.filter.predict(vo_step)
            wheel = self._measured_speed(frames.stamp_ns)
            if wheel is not None and estimate.status != "bridged" and dt > 0:
                vo_length = math.hypot(vo_step[0], vo_step[1])
                # the comparison is as uncertain as the wheels' distance and VO's step length together
                sigma = math.hypot(self.config.wheel_sigma_mps * dt, self.config.vo_sigma_per_m * vo_length * scale)
                self.filter.correct_distance(vo_length, abs(wheel) * dt, sigma)
        fixed = False
        if self._since_query_m >= self.config.place_every_m or self.filter.state is None or not self._settled:
            fixed = self._fix(self.places.locate(image, frames.stamp_ns))
            self._settled = self._settled or self.filter.position_sigma_m <= self.config.settled_sigma_m
        t2 = time.perf_counter()
        self.timing_ms["vo"] = self.timing_ms.get("vo", 0.0) + (t1 - t0) * 1e3
        self.timing_ms["places"] = self.timing_ms.get("places", 0.0) + (t2 - t1) * 1e3
        if self.filter.state is None:
            return self._bridge(frames.stamp_ns, "not placed on the reference yet")
        if estimate.status == "bridged" and not fixed:
            return self._bridge(frames.stamp_ns, estimate.reason)
        self._last_ok_ns = frames.stamp_ns
        x, y, yaw, _ = self.filter.state
        pose = (float(x), float(y), float(yaw))
        return self._remember(self._with_motion(frames.stamp_ns, pose, step, dt, "ok", ""))

    def _fix(self, fix: PlaceFix) -> bool:
        """Fold a place fix into the filter; True when it was used."""
        self._since_query_m = 0.0
        if not fix.accepted:
            return False
        measured = place_ground_poses(fix.pose_world_cam, self.body_cam, self._origin)[0]
        place_yaw = float(place_ground_poses(self.places.poses_world_cam[fix.place], self.body_cam, self._origin)[0, 2])
        c, s = math.cos(place_yaw), math.sin(place_yaw)
        turn = np.array([[c, -s], [s, c]])
        noise = np.zeros((3, 3))
        across = fix.cross_track_sigma_m if fix.registered else max(fix.sigma_m, self.config.cross_track_sigma_m)
        noise[:2, :2] = turn @ np.diag([fix.sigma_m, across]) ** 2 @ turn.T
        noise[2, 2] = min(fix.heading_sigma_rad, math.pi) ** 2
        if self.filter.state is None:  # the first fix places the kart
            self.filter.place(measured, noise)
            self.relocalisations += 1
            log.info("placed on the reference at x %.1f m, y %.1f m (place %d)", measured[0], measured[1], fix.place)
            return True
        if not self.filter.correct(measured, noise):
            self.rejected_fixes += 1
            log.info("place fix %d rejected: %.1f m from the estimate", fix.place,
                     math.hypot(*(measured[:2] - self.filter.state[:2])))
            return False
        self.relocalisations += 1
        return True

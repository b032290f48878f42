"""The stereo-VO pipeline as a policy: frames -> VO pose -> progress on the reference -> command.

It fails closed: once the localizer reports ``lost`` (VO bridged for longer than it
may), the end of the reference is reached, or the kart has driven clearly further than
the whole reference (whatever the pose says), the command is a stop, and it stays a
stop. Every step is logged as a :class:`DriveSample` for plots and CSV, and the time
spent in each stage is accumulated for the profile.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import astuple, dataclass, field, fields, replace
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from kartpilot.control.path_follow import PathFollowConfig, PathFollowState, path_follow_step
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.files import write_csv_atomic
from kartpilot.core.geometry import Array, invert_pose, transform_points
from kartpilot.core.types import ActuatorCommand, FrameSet, Image, VehicleFeedback, VehiclePose
from kartpilot.odometry.localizer import LocalizerConfig
from kartpilot.odometry.mono_localizer import MonoLocalizerConfig, place_ground_poses
from kartpilot.odometry.places import PlaceDatabase
from kartpilot.odometry.stereo_vo import VO_STAGES
from kartpilot.odometry.visual_map import MapConfig
from kartpilot.planning.reference_path import PathConfig, ReferencePath, build_reference_path

__all__ = ["DriveConfig", "DriveSample", "Localizer", "PathFollowPolicy", "places_reference", "write_drive_log"]

OVERRUN_FACTOR, OVERRUN_M = 1.1, 2.0  # stop after driving 10 % + 2 m more than the reference is long

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DriveConfig:
    """The ``drive`` pipeline's settings: localisation (stereo VO, or one camera with place fixes), reference and
    map building, path following."""

    localizer: LocalizerConfig = field(default_factory=LocalizerConfig)
    mono: MonoLocalizerConfig = field(default_factory=MonoLocalizerConfig)
    path: PathConfig = field(default_factory=PathConfig)
    map: MapConfig = field(default_factory=MapConfig)
    follow: PathFollowConfig = field(default_factory=PathFollowConfig)


@dataclass(frozen=True)
class DriveSample:
    """One step of a drive, as the pipeline saw it (odometry frame, rear axle)."""

    stamp_ns: int
    x_m: float
    y_m: float
    yaw_rad: float
    speed_mps: float
    pose_status: str
    cross_track_m: float
    heading_error_rad: float
    target_speed_mps: float
    path_index: int
    steer_rad: float
    throttle: float
    brake: float


class Localizer(Protocol):
    """What the path follower needs of a localiser (stereo VO with its map, or one camera with place fixes)."""

    body_cam: Array
    relocalisations: int

    @property
    def timing_ms(self) -> dict[str, float]:
        """Milliseconds per stage, summed over every frame."""

    @property
    def camera_name(self) -> str: ...

    @property
    def camera(self) -> PinholeCamera: ...

    def update(self, frames: FrameSet) -> VehiclePose: ...

    def observe_speed(self, stamp_ns: int, speed_mps: float) -> None: ...

    def close(self) -> None: ...


class PathFollowPolicy:
    """Callable policy for :func:`kartpilot.runtime.loop.run_loop`. Holds the localizer and the controller state."""

    def __init__(self, localizer: Localizer, path: ReferencePath, config: PathFollowConfig,
                 wheelbase_m: float, max_steer_rad: float, rate_hz: float) -> None:
        self.localizer = localizer
        self.path = path
        self.config = config
        self.wheelbase_m = wheelbase_m
        self.max_steer_rad = max_steer_rad
        self.period_s = 1.0 / rate_hz
        self.state = PathFollowState.start(config)
        self.samples: list[DriveSample] = []
        self.stop_reason = ""
        self.stopped_at_ns: int | None = None
        self.stage_s: dict[str, float] = {"localize": 0.0, "control": 0.0}
        self._last_stamp_ns: int | None = None
        self.odometer_m = 0.0
        self.measured_speed_mps: float | None = None  # the kart's own, where it reports one (the RDW kart's 0x440)

    def observe_vehicle(self, feedback: VehicleFeedback) -> None:
        """The kart's measurements before a step: a fresh measured speed drives the speed control and the
        Stanley gains instead of odometry's estimate (closed-loop speed on the kart's own sensor), and the
        localiser's bridging and, for one camera, VO's scale."""
        self.measured_speed_mps = feedback.speed_mps
        if feedback.speed_mps is not None:
            self.localizer.observe_speed(feedback.stamp_ns, feedback.speed_mps)

    @property
    def stopped(self) -> bool:
        """True once the policy has decided to stop for good (end of the path, or lost)."""
        return self.stopped_at_ns is not None

    def stopped_for_s(self, stamp_ns: int) -> float:
        return 0.0 if self.stopped_at_ns is None else (stamp_ns - self.stopped_at_ns) * 1e-9

    def __call__(self, frames: FrameSet) -> ActuatorCommand:
        t0 = time.perf_counter()
        pose = self.localizer.update(frames)
        t1 = time.perf_counter()
        dt = self.period_s if self._last_stamp_ns is None else max((frames.stamp_ns - self._last_stamp_ns) * 1e-9,
                                                                    1e-3)
        self._last_stamp_ns = frames.stamp_ns
        control_pose = pose if self.measured_speed_mps is None else replace(pose, speed_mps=self.measured_speed_mps)
        out, self.state = path_follow_step(self.config, self.state, self.path, control_pose, dt, self.wheelbase_m,
                                           self.max_steer_rad)
        self.odometer_m += abs(pose.speed_mps) * dt
        overrun = self.odometer_m > OVERRUN_FACTOR * self.path.length_m + OVERRUN_M
        if not self.stopped and (out.done or pose.status == "lost" or overrun):
            if out.done:
                self.stop_reason = "reached the end of the reference"
            elif overrun:  # whatever the pose says, the kart has driven further than the whole reference
                self.stop_reason = f"drove {self.odometer_m:.1f} m on a {self.path.length_m:.1f} m reference"
            else:
                self.stop_reason = f"localisation lost: {pose.reason}"
            self.stopped_at_ns = frames.stamp_ns
            (log.info if out.done else log.error)("stopping: %s", self.stop_reason)
        command = (ActuatorCommand.stop(frames.stamp_ns) if self.stopped
                   else ActuatorCommand(frames.stamp_ns, out.steer_rad, out.throttle, out.brake))
        t2 = time.perf_counter()
        self.stage_s["localize"] += t1 - t0
        self.stage_s["control"] += t2 - t1
        self.samples.append(DriveSample(frames.stamp_ns, pose.x_m, pose.y_m, pose.yaw_rad, pose.speed_mps,
                                        pose.status, out.cross_track_m, out.heading_error_rad, out.target_speed_mps,
                                        out.index, command.steer_rad, command.throttle, command.brake))
        return command

    def close(self) -> None:
        self.localizer.close()

    def summary(self, steps: int) -> tuple[dict[str, float], dict[str, object]]:
        """The mean milliseconds per step of each stage (the localiser's own inside ``localize``), and how the
        drive went, for a session's result."""
        per_step = 1.0 / max(steps, 1)
        stages = {k: 1e3 * v * per_step for k, v in self.stage_s.items()}
        stages.update({f"localize.{k}": v * per_step for k, v in self.localizer.timing_ms.items()})
        statuses = [sample.pose_status for sample in self.samples]
        return stages, {"stop_reason": self.stop_reason, "bridged_frames": statuses.count("bridged"),
                        "lost_frames": statuses.count("lost"), "relocalised_frames": self.localizer.relocalisations}

    def fault(self) -> str:
        """What is wrong with the pipeline, for the supervisor: localisation lost, or an overrun. The end of
        the reference is not a fault: the pipeline stops the kart there itself."""
        if self.stopped and self.stop_reason != "reached the end of the reference":
            return self.stop_reason
        return ""

    def outputs(self) -> dict[str, dict[str, float | int | str]]:
        """The last step as the recording's ``pose`` and ``follow`` topics."""
        if not self.samples:
            return {}
        last = self.samples[-1]
        return {
            "pose": {"x_m": last.x_m, "y_m": last.y_m, "yaw_rad": last.yaw_rad, "speed_mps": last.speed_mps,
                     "status": last.pose_status, "relocalisations": self.localizer.relocalisations},
            "follow": {"path_index": last.path_index, "cross_track_m": last.cross_track_m,
                       "heading_error_rad": last.heading_error_rad, "target_speed_mps": last.target_speed_mps,
                       "stopped": int(self.stopped)},
            **self._vo_outputs(),
        }

    def _vo_outputs(self) -> dict[str, dict[str, float | int | str]]:
        """Stereo VO's ``vo`` topic: what each filter stage kept in the last frame (0 where VO did not run)."""
        if not hasattr(self.localizer, "last_diagnostics"):
            return {}
        diagnostics = self.localizer.last_diagnostics
        return {"vo": {name: int(getattr(diagnostics, name)) if diagnostics is not None else 0 for name in VO_STAGES}}

    def overlay(self, frames: FrameSet) -> Image | None:
        """The pipeline's view: the left image with the reference path ahead drawn where the pipeline
        believes it lies on the road, and its state."""
        image = frames.images.get(self.localizer.camera_name)
        if image is None or not self.samples:
            return None
        canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
        last = self.samples[-1]
        path = self.path
        ahead = slice(last.path_index, int(np.searchsorted(path.s_m, path.s_m[last.path_index] + 8.0)))
        c, s = math.cos(last.yaw_rad), math.sin(last.yaw_rad)
        dx, dy = path.x_m[ahead] - last.x_m, path.y_m[ahead] - last.y_m
        body = np.column_stack([c * dx + s * dy, -s * dx + c * dy, np.zeros_like(dx)])
        in_camera = transform_points(invert_pose(self.localizer.body_cam), body)
        in_camera = in_camera[in_camera[:, 2] > 0.2]
        if len(in_camera) >= 2:
            pixels = self.localizer.camera.project(in_camera)
            cv2.polylines(canvas, [np.round(pixels).astype(np.int32).reshape(-1, 1, 2)], False, (0, 220, 0), 3,
                          cv2.LINE_AA)
        status = "STOPPED: " + self.stop_reason if self.stopped else f"pose {last.pose_status}"
        text = (f"{status} | cross-track {last.cross_track_m * 100:+.1f} cm | v {last.speed_mps:.2f} / "
                f"{last.target_speed_mps:.2f} m/s | relocalised {self.localizer.relocalisations}")
        y = canvas.shape[0] - 14
        cv2.putText(canvas, text, (12, y), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(canvas, text, (12, y), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
        return canvas


def places_reference(places: PlaceDatabase, pose_body_cam: Array, config: PathConfig) -> ReferencePath:
    """The reference drive of a place database as a path to follow, in the mono localiser's frame."""
    ground = place_ground_poses(places.poses_world_cam, pose_body_cam, places.poses_world_cam[0])
    return build_reference_path(ground[:, :2], config)


def write_drive_log(samples: list[DriveSample], target: str | Path) -> Path:
    """The drive's samples as CSV, one row per step, columns named with units."""
    rows = ([f"{v:.6f}" if isinstance(v, float) else v for v in astuple(sample)] for sample in samples)
    return write_csv_atomic(target, [f.name for f in fields(DriveSample)], rows)

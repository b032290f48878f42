"""Frozen messages exchanged between stages. Field names carry their units."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array, planar_pose, transform_points_2d

__all__ = [
    "ActuatorCommand",
    "CommandSink",
    "FrameSet",
    "FrameSink",
    "FrameSource",
    "Image",
    "LaserScan",
    "LidarMount",
    "OperatorInput",
    "StereoFrame",
    "VehicleFeedback",
    "VehiclePose",
]

Image = NDArray[Any]
"""An 8-bit image (grayscale HxW or BGR HxWx3), as OpenCV returns it."""


@dataclass(frozen=True)
class StereoFrame:
    """A synchronised, rectified stereo pair.

    Attributes:
        index: position of the frame in its source (0-based).
        stamp_ns: capture time in nanoseconds (monotonic within a source).
        left, right: 8-bit grayscale images of equal size, rectified.
    """

    index: int
    stamp_ns: int
    left: Image
    right: Image

    @property
    def stamp_s(self) -> float:
        return self.stamp_ns * 1e-9

    def as_frame_set(self, left: str = "left", right: str = "right") -> FrameSet:
        """The pair as a frame set of two cameras with these names."""
        return FrameSet(self.index, self.stamp_ns, {left: self.left, right: self.right})


@dataclass(frozen=True)
class FrameSet:
    """One synchronised set of camera images (BGR or grayscale), keyed by camera name.

    Attributes:
        index: position of the set in its source (0-based).
        stamp_ns: capture time of the set in nanoseconds.
        images: camera name -> image. A camera missing from the mapping delivered nothing.
        capture_ns: camera name -> when that camera's image was captured, where it differs from
            ``stamp_ns`` (live cameras are grouped by time; their own stamps show the skew).
        name: where the set came from when it is one file (an image's file name), so a result can be matched
            to it; empty otherwise.
        scans: LiDAR name -> the sweep that ended since the set before (none where no sweep ended: a LiDAR at
            10 Hz beside cameras at 15 Hz delivers to two sets of three).
    """

    index: int
    stamp_ns: int
    images: Mapping[str, Image]
    capture_ns: Mapping[str, int] = field(default_factory=dict)
    name: str = ""
    scans: Mapping[str, LaserScan] = field(default_factory=dict)


@dataclass(frozen=True)
class ActuatorCommand:
    """One command to the actuators.

    Attributes:
        stamp_ns: when the command was issued.
        steer_rad: road-wheel steering angle, positive to the left.
        throttle: 0 (none) to 1 (full).
        brake: 0 (released) to 1 (full).
    """

    stamp_ns: int
    steer_rad: float
    throttle: float
    brake: float

    @classmethod
    def stop(cls, stamp_ns: int) -> ActuatorCommand:
        """The safe command: straight wheels, no throttle, full brake."""
        return cls(stamp_ns, 0.0, 0.0, 1.0)

    @property
    def is_stop(self) -> bool:
        """Full brake and no throttle (wherever the wheels point)."""
        return self.brake >= 1.0 and self.throttle == 0.0


@dataclass(frozen=True)
class LaserScan:
    """One sweep of a planar LiDAR, as ROS 2's ``sensor_msgs/LaserScan`` holds it (angles counter-clockwise from
    the sensor's x axis, forward; its frame on the kart is the rig's).

    Attributes:
        stamp_ns: the time of the sweep's first beam.
        angle_min_rad, angle_increment_rad: the first beam's angle and the step between beams.
        time_increment_s: the time between beams (a sweep of ``scan_time_s`` is not one instant: the kart moves).
        scan_time_s: the time from one sweep to the next.
        range_min_m, range_max_m: what the sensor measures; a beam without a return is NaN.
        ranges_m: (N,) the distance along each beam.
        intensities: (N,) each return's strength (0 where there was none).
    """

    stamp_ns: int
    angle_min_rad: float
    angle_increment_rad: float
    time_increment_s: float
    scan_time_s: float
    range_min_m: float
    range_max_m: float
    ranges_m: NDArray[np.float32]
    intensities: NDArray[np.float32]

    def __post_init__(self) -> None:
        """A sweep every reader can trust, whoever made it (a file, a bag, a driver): one range and one intensity
        per beam, finite angles and times, a range window that is one; a range outside the window or not finite
        stays, as no return (NaN), as ROS's convention has it."""
        ranges, strengths = np.asarray(self.ranges_m), np.asarray(self.intensities)
        scalars = (self.angle_min_rad, self.angle_increment_rad, self.time_increment_s, self.scan_time_s,
                   self.range_min_m, self.range_max_m)
        if ranges.ndim != 1 or strengths.shape != ranges.shape:
            raise ConfigError(f"a LiDAR sweep needs one range and one intensity per beam, got {ranges.shape} and "
                              f"{strengths.shape}")
        if not all(np.isfinite(scalars)) or (self.angle_increment_rad == 0 and len(ranges) > 1):
            raise ConfigError(f"a LiDAR sweep's angles and times must be finite, its angle step not 0: {scalars}")
        if not (0.0 <= self.range_min_m < self.range_max_m) or self.time_increment_s < 0 or self.scan_time_s < 0:
            raise ConfigError(f"a LiDAR sweep's range window [{self.range_min_m}, {self.range_max_m}] m and times "
                              f"({self.time_increment_s}, {self.scan_time_s} s) are not a sensor's")
        if abs(self.angle_increment_rad) * max(len(ranges) - 1, 0) > 2 * np.pi + 1e-6:
            raise ConfigError(f"a LiDAR sweep of {len(ranges)} beams {self.angle_increment_rad} rad apart turns more "
                              "than once")

    def angles_rad(self) -> NDArray[np.float64]:
        """Each beam's angle."""
        return np.asarray(self.angle_min_rad + self.angle_increment_rad * np.arange(len(self.ranges_m)), np.float64)

    def points_m(self) -> NDArray[np.float64]:
        """(M, 2) x, y in the sensor's frame of the beams with a return."""
        angles, ranges = self.angles_rad(), np.asarray(self.ranges_m, np.float64)
        seen = np.isfinite(ranges)
        return np.column_stack([ranges[seen] * np.cos(angles[seen]), ranges[seen] * np.sin(angles[seen])])


@dataclass(frozen=True)
class LidarMount:
    """Where a planar LiDAR sits on the kart: its centre ``x_m`` ahead of the rear axle, ``y_m`` to the left,
    its scan plane ``z_m`` above the road, turned ``yaw_rad`` to the left (its 0-degree beam along the kart's
    x axis when 0). The scan plane is level: a planar LiDAR mounted tilted sees the road."""

    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float = 0.0

    def __post_init__(self) -> None:
        values = (self.x_m, self.y_m, self.z_m, self.yaw_rad)
        if not all(np.isfinite(values)) or not 0.0 < self.z_m <= 3.0 or abs(self.x_m) > 10 or abs(self.y_m) > 10:
            raise ConfigError(f"a LiDAR mount at x {self.x_m}, y {self.y_m}, z {self.z_m} m, yaw {self.yaw_rad} rad: "
                             "finite, within 10 m of the rear axle, its plane above the road and at most 3 m up")

    def pose_body_lidar(self) -> Array:
        """The sensor's 4x4 pose on the body (its frame as ROS's laser frames are: x ahead, y left, z up)."""
        pose = planar_pose(self.x_m, self.y_m, self.yaw_rad)
        pose[2, 3] = self.z_m
        return pose

    def to_body(self, points_m: NDArray[np.float64]) -> NDArray[np.float64]:
        """(M, 2) points in the sensor's frame as x, y on the kart's body."""
        return transform_points_2d(points_m, self.x_m, self.y_m, self.yaw_rad)


@dataclass(frozen=True)
class VehiclePose:
    """Where the kart is on the road plane, from odometry.

    Attributes:
        stamp_ns: the frame time the pose belongs to.
        x_m, y_m, yaw_rad: the rear axle's position and heading in the odometry frame (the rear axle at
            the start of the drive: x forward, y left, yaw positive to the left).
        speed_mps, yaw_rate_radps: filtered motion along the heading and about the vertical.
        status: ``ok`` (measured), ``bridged`` (predicted by the motion model for a short gap) or
            ``lost`` (predicted for too long: stop).
        reason: why the pose was not measured, if it was not.
    """

    stamp_ns: int
    x_m: float
    y_m: float
    yaw_rad: float
    speed_mps: float
    yaw_rate_radps: float
    status: Literal["ok", "bridged", "lost"]
    reason: str = ""


@dataclass(frozen=True)
class VehicleFeedback:
    """What the kart itself measures, from its CAN bus (None where it says nothing, or nothing fresh).

    Attributes:
        stamp_ns: when this was read.
        speed_mps: the measured speed (the RDW kart's 0x440), forward positive.
        steer_rad: the measured road-wheel angle, positive left (the steering sensor through the calibration).
    """

    stamp_ns: int
    speed_mps: float | None = None
    steer_rad: float | None = None


@dataclass(frozen=True)
class OperatorInput:
    """What the person in charge asks for now: from a gamepad, the web page, or a script in the simulator.

    Attributes:
        connected: the input device (or page) is connected and alive.
        estop: the emergency stop is pressed.
        hold: the dead-man button for autonomy is held.
        request: ``manual``, ``autonomous``, ``disarm`` or ``rearm`` (after a fault), or empty.
        manual: the person's own steer, throttle and brake, when driving by hand.
        source: where this came from (``gamepad``, ``web``, ``script``).
    """

    connected: bool = True
    estop: bool = False
    hold: bool = False
    request: str = ""
    manual: ActuatorCommand | None = None
    source: str = ""


class FrameSource(Protocol):
    """Anything that delivers camera images: a live rig, a recording, the simulator."""

    def read(self) -> FrameSet | None:
        """The next frame set, or None when the source has ended."""


class CommandSink(Protocol):
    """Anything that takes actuator commands: the CAN bus, the simulator, a recorder."""

    def send(self, command: ActuatorCommand) -> None: ...


class FrameSink(Protocol):
    """Anything that takes frame sets, such as a recorder."""

    def write_frames(self, frames: FrameSet) -> None: ...

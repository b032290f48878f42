"""Whether a frame-to-frame step is one the vehicle can have made.

A VO step is bounded by the vehicle's speed and rotation rate, and by how much its velocity and rotation
rate can have changed since the last accepted step (the vehicle's acceleration). Steps that fail are not
accepted silently: the estimator tries again or bridges the frame and counts it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array, invert_pose, rotvec_from_pose

__all__ = ["MotionLimits", "StepVelocity", "check_motion"]


@dataclass(frozen=True)
class StepVelocity:
    """A frame-to-frame step as velocities in the earlier camera's frame.

    Attributes:
        linear_mps: (3,) the camera's translation over the step divided by its duration.
        angular_radps: (3,) the rotation vector over the step divided by its duration.
        mid_ns: the middle of the step (the time the velocities belong to).
    """

    linear_mps: Array
    angular_radps: Array
    mid_ns: int

    @staticmethod
    def of_motion(motion: Array, start_ns: int, end_ns: int) -> StepVelocity:
        """The velocities of the camera's motion ``motion`` (its pose at ``end_ns`` in its frame at ``start_ns``)."""
        dt_s = max((end_ns - start_ns) * 1e-9, 1e-3)
        return StepVelocity(motion[:3, 3] / dt_s, rotvec_from_pose(motion) / dt_s, (start_ns + end_ns) // 2)

    @staticmethod
    def of_step(pose_cur_prev: Array, start_ns: int, end_ns: int) -> StepVelocity:
        """The velocities of a step given as the transform of points from the earlier camera to the later."""
        return StepVelocity.of_motion(invert_pose(pose_cur_prev), start_ns, end_ns)


@dataclass(frozen=True)
class MotionLimits:
    """What the vehicle can do, to reject steps it cannot have made.

    Attributes:
        max_speed_mps, max_yaw_rate_dps: the largest speed and rotation rate.
        max_accel_mps2: the largest change of the velocity vector per second (braking, accelerating,
            cornering); 10 m/s^2 is 1 g, more than a car or kart brakes.
        max_angular_accel_dps2: the largest change of the rotation rate per second.
        speed_tolerance_mps, rate_tolerance_dps: the noise of a good step's velocity, added to the
            allowed change.
    """

    max_speed_mps: float = 40.0
    max_yaw_rate_dps: float = 180.0
    max_accel_mps2: float = 10.0
    max_angular_accel_dps2: float = 720.0
    speed_tolerance_mps: float = 0.3
    rate_tolerance_dps: float = 5.0

    def __post_init__(self) -> None:
        for name in ("max_speed_mps", "max_yaw_rate_dps", "max_accel_mps2", "max_angular_accel_dps2"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"motion_limits.{name} must be positive, got {getattr(self, name)}")
        for name in ("speed_tolerance_mps", "rate_tolerance_dps"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"motion_limits.{name} must not be negative, got {getattr(self, name)}")


def check_motion(step: StepVelocity, limits: MotionLimits, recent: StepVelocity | None = None) -> str:
    """Empty when the step is plausible for the vehicle, else the reason it is not.

    The step is bounded by the vehicle's speed and rotation rate, and, given the last accepted step
    ``recent``, by how much its velocity and rotation rate can have changed since then.
    """
    speed = float(np.linalg.norm(step.linear_mps))
    rate = float(np.degrees(np.linalg.norm(step.angular_radps)))
    if not np.isfinite(speed) or speed > limits.max_speed_mps:
        return f"implausible speed {speed:.1f} m/s (limit {limits.max_speed_mps:.1f})"
    if not np.isfinite(rate) or rate > limits.max_yaw_rate_dps:
        return f"implausible rotation rate {rate:.0f} deg/s (limit {limits.max_yaw_rate_dps:.0f})"
    if recent is None:
        return ""
    elapsed_s = max((step.mid_ns - recent.mid_ns) * 1e-9, 0.0)
    change = float(np.linalg.norm(step.linear_mps - recent.linear_mps))
    allowed = limits.max_accel_mps2 * elapsed_s + limits.speed_tolerance_mps
    if change > allowed:
        return (f"velocity changed by {change:.2f} m/s in {elapsed_s:.2f} s "
                f"(limit {allowed:.2f}: {limits.max_accel_mps2:g} m/s^2)")
    rate_change = float(np.degrees(np.linalg.norm(step.angular_radps - recent.angular_radps)))
    allowed_rate = limits.max_angular_accel_dps2 * elapsed_s + limits.rate_tolerance_dps
    if rate_change > allowed_rate:
        return (f"rotation rate changed by {rate_change:.0f} deg/s in {elapsed_s:.2f} s "
                f"(limit {allowed_rate:.0f}: {limits.max_angular_accel_dps2:g} deg/s^2)")
    return ""

"""Following a reference path: one pure step from a pose to a command.

``path_follow_step(config, state, path, pose, dt, wheelbase, max_steer)`` returns the command
and the next state, with nothing hidden: the progress index, the steering-bias estimate,
the last steering angle and the speed controller's integral are all in the state.

* Lateral: Stanley at the front axle (the thesis's law, with softening, look-ahead
  heading and curvature feed-forward) or pure pursuit from the rear axle.
* Bias: a slow integral of the cross-track error estimates a steady steering offset
  (a kart that drags to one side, a sloped track) and cancels it.
* Limits: steering range and rate.
* Longitudinal: PI on the path's speed profile, from the odometry's speed, or the
  thesis's constant throttle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from kartpilot.control.longitudinal import SpeedPIConfig, SpeedPIState, speed_pi
from kartpilot.control.pure_pursuit import pure_pursuit_steer
from kartpilot.control.stanley import StanleyConfig, heading_lookahead_m, stanley_steer
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array
from kartpilot.core.types import VehiclePose
from kartpilot.planning.reference_path import ReferencePath, advance_progress, index_ahead, lateral_offset

__all__ = [
    "BiasConfig",
    "PathFollowConfig",
    "PathFollowOutput",
    "PathFollowState",
    "PurePursuitConfig",
    "estimate_steer_bias",
    "path_follow_step",
    "steer_bias_of_drive",
]


CREEP_SPEED_MPS = 0.15


@dataclass(frozen=True)
class PurePursuitConfig:
    """Look-ahead distance ``lookahead_m + lookahead_time_s * speed`` from the rear axle."""

    lookahead_m: float = 0.5
    lookahead_time_s: float = 0.5


@dataclass(frozen=True)
class BiasConfig:
    """Integral action against a steady steering offset: the kart's pull (positive left) is estimated
    and steered against.

    Attributes:
        gain_rad_per_m_s: the estimate changes by this much per second per metre of cross-track error
            (0 switches compensation off).
        limit_rad: the estimate's bound.
        within_m: integrate only while the error is smaller than this (not during a large correction).
        min_speed_mps: integrate only while moving at least this fast.
        initial_rad: the estimate to start from (a kart's known drag, e.g. from
            :func:`estimate_steer_bias` on the taught drive), so the first metres need no correction.
    """

    gain_rad_per_m_s: float = 0.15
    limit_rad: float = 0.1
    within_m: float = 0.3
    min_speed_mps: float = 0.2
    initial_rad: float = 0.0


def estimate_steer_bias(steer_rad: Array, curvature_per_m: Array, speed_mps: Array, wheelbase_m: float,
                        max_abs_curvature_per_m: float = 0.02, min_speed_mps: float = 0.3) -> float:
    """The steady steering offset of a drive: what the kart turned (``atan(L * curvature)``) minus what it
    was commanded, the median over moving samples on gentle curvature (where the kinematic model holds).

    Positive when the kart pulls left (it turns more to the left than commanded). 0 without samples.
    """
    steer, curvature, speed = (np.asarray(a, float) for a in (steer_rad, curvature_per_m, speed_mps))
    use = (np.abs(curvature) < max_abs_curvature_per_m) & (speed > min_speed_mps) & np.isfinite(steer)
    if not np.any(use):
        return 0.0
    return float(np.median(np.arctan(wheelbase_m * curvature[use]) - steer[use]))


def steer_bias_of_drive(path: ReferencePath, ground_xy_yaw: Array, stamps_ns: np.ndarray,
                        command_stamps_ns: np.ndarray, command_steer_rad: Array, wheelbase_m: float) -> float:
    """:func:`estimate_steer_bias` of a recorded drive: its poses (``(N, 3)`` at ``stamps_ns``, the path's
    frame), the path built from them (for curvature) and the commands it was driven with (held until
    the next one)."""
    poses = np.asarray(ground_xy_yaw, float)
    stamps = np.asarray(stamps_ns, np.int64)
    if len(poses) < 3 or len(command_stamps_ns) == 0:
        return 0.0
    active = np.searchsorted(np.asarray(command_stamps_ns, np.int64), stamps, side="right") - 1
    steer = np.where(active >= 0, np.asarray(command_steer_rad, float)[np.clip(active, 0, None)], np.nan)
    index, curvature = 0, np.empty(len(poses))
    for k, (x, y, _) in enumerate(poses):
        index = advance_progress(path, float(x), float(y), index, 2.0)
        curvature[k] = path.curvature_per_m[index]
    dt = np.maximum(np.diff(stamps) * 1e-9, 1e-3)
    speed = np.r_[0.0, np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1])) / dt]
    return estimate_steer_bias(steer, curvature, speed, wheelbase_m)


@dataclass(frozen=True)
class PathFollowConfig:
    """Attributes:
        controller: ``stanley`` or ``pure_pursuit``.
        search_ahead_m: the window, ahead of the last progress point, in which the nearest waypoint is sought.
        max_steer_rad: the steering range (0: the vehicle's).
        max_steer_rate_radps: how fast the commanded angle may change.
        speed_control: ``pi`` (PI on the path's speed profile) or ``constant_throttle`` (the thesis).
        max_speed_mps: cap on the path's speed profile (0: no cap).
        constant_throttle: the throttle in ``constant_throttle`` mode.
        speed_input: ``odometry`` (the measured speed, for Stanley and the PI) or ``assumed``
            (``assumed_speed_mps``, the thesis's hand-measured constant).
    """

    controller: Literal["stanley", "pure_pursuit"] = "stanley"
    stanley: StanleyConfig = field(default_factory=StanleyConfig)
    pure_pursuit: PurePursuitConfig = field(default_factory=PurePursuitConfig)
    bias: BiasConfig = field(default_factory=BiasConfig)
    search_ahead_m: float = 2.0
    max_steer_rad: float = 0.0
    max_steer_rate_radps: float = 3.0
    speed_control: Literal["pi", "constant_throttle"] = "pi"
    speed_pi: SpeedPIConfig = field(default_factory=SpeedPIConfig)
    max_speed_mps: float = 0.0
    constant_throttle: float = 0.12
    speed_input: Literal["odometry", "assumed"] = "odometry"
    assumed_speed_mps: float = 0.62

    def __post_init__(self) -> None:
        if self.controller not in ("stanley", "pure_pursuit"):
            raise ConfigError(f"path_follow.controller: unknown controller {self.controller!r} "
                              "(stanley or pure_pursuit)")
        if self.speed_control not in ("pi", "constant_throttle"):
            raise ConfigError(f"path_follow.speed_control: unknown mode {self.speed_control!r} "
                              "(pi or constant_throttle)")
        if self.speed_input not in ("odometry", "assumed"):
            raise ConfigError(f"path_follow.speed_input: unknown input {self.speed_input!r} (odometry or assumed)")
        if self.search_ahead_m <= 0 or self.max_steer_rate_radps <= 0:
            raise ConfigError("path_follow.search_ahead_m and max_steer_rate_radps must be positive")
        if not 0.0 <= self.constant_throttle <= 1.0:
            raise ConfigError("path_follow.constant_throttle must be in [0, 1]")


@dataclass(frozen=True)
class PathFollowState:
    """What one step hands to the next. ``bias_rad`` is the estimated pull of the kart (positive left)."""

    index: int = 0
    bias_rad: float = 0.0
    steer_rad: float = 0.0
    speed: SpeedPIState = field(default_factory=SpeedPIState)

    @classmethod
    def start(cls, config: PathFollowConfig) -> PathFollowState:
        """The state at the start of a drive (the bias estimate from the config)."""
        return cls(bias_rad=config.bias.initial_rad)


@dataclass(frozen=True)
class PathFollowOutput:
    """The command and what it was computed from.

    ``cross_track_m`` is at the controller's reference point (front axle for Stanley, rear for pure
    pursuit), positive left of the path; ``done`` once the end of the path is reached.
    """

    steer_rad: float
    throttle: float
    brake: float
    cross_track_m: float
    heading_error_rad: float
    target_speed_mps: float
    index: int
    done: bool


def path_follow_step(config: PathFollowConfig, state: PathFollowState, path: ReferencePath, pose: VehiclePose,
                     dt_s: float, wheelbase_m: float, max_steer_rad: float) -> tuple[PathFollowOutput, PathFollowState]:
    """One control step. ``max_steer_rad`` is the vehicle's range (``config.max_steer_rad`` narrows it)."""
    speed = pose.speed_mps if config.speed_input == "odometry" else config.assumed_speed_mps
    index = advance_progress(path, pose.x_m, pose.y_m, state.index, config.search_ahead_m + abs(speed) * dt_s)
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    s_rear, cross = lateral_offset(path, index, pose.x_m, pose.y_m)
    done = s_rear >= path.s_m[-1]  # the path is the rear axle's
    if config.controller == "stanley":
        fx, fy = pose.x_m + wheelbase_m * c, pose.y_m + wheelbase_m * s
        front = advance_progress(path, fx, fy, index, wheelbase_m + config.search_ahead_m)
        _, cross = lateral_offset(path, front, fx, fy)
        ahead = index_ahead(path, front, heading_lookahead_m(config.stanley, speed))
        heading_error = math.remainder(float(path.heading_rad[ahead]) - pose.yaw_rad, math.tau)
        steer = stanley_steer(config.stanley, cross, heading_error, speed, float(path.curvature_per_m[ahead]),
                              wheelbase_m)
    else:
        lookahead = config.pure_pursuit.lookahead_m + config.pure_pursuit.lookahead_time_s * abs(speed)
        target = index_ahead(path, index, lookahead)
        heading_error = math.remainder(float(path.heading_rad[index]) - pose.yaw_rad, math.tau)
        if path.s_m[target] - path.s_m[index] < lookahead:  # near the end: aim past it along the last heading
            extra = lookahead - (path.s_m[target] - path.s_m[index])
            tx = path.x_m[-1] + extra * math.cos(path.heading_rad[-1])
            ty = path.y_m[-1] + extra * math.sin(path.heading_rad[-1])
        else:
            tx, ty = path.x_m[target], path.y_m[target]
        steer = pure_pursuit_steer(pose.x_m, pose.y_m, pose.yaw_rad, float(tx), float(ty), wheelbase_m)

    bias = state.bias_rad
    b = config.bias
    if b.gain_rad_per_m_s > 0 and abs(cross) < b.within_m and abs(speed) >= b.min_speed_mps and not done:
        bias = min(max(bias + b.gain_rad_per_m_s * cross * dt_s, -b.limit_rad), b.limit_rad)
    limit = min(max_steer_rad, config.max_steer_rad) if config.max_steer_rad > 0 else max_steer_rad
    steer = min(max(steer - bias, -limit), limit)  # cancel the estimated pull
    step = config.max_steer_rate_radps * dt_s
    steer = min(max(steer, state.steer_rad - step), state.steer_rad + step)

    # the profile ends at zero; creep on until the rear axle is there, then brake
    target_speed = 0.0 if done else max(float(path.speed_mps[index]), CREEP_SPEED_MPS)
    if config.max_speed_mps > 0:
        target_speed = min(target_speed, config.max_speed_mps)
    speed_state = state.speed
    if done:
        throttle, brake = 0.0, 1.0
    elif config.speed_control == "constant_throttle":
        throttle, brake = config.constant_throttle, 0.0
    else:
        throttle, brake, speed_state = speed_pi(config.speed_pi, state.speed, target_speed, pose.speed_mps, dt_s)
    output = PathFollowOutput(steer, throttle, brake, cross, heading_error, target_speed, index, done)
    return output, PathFollowState(index, bias, steer, speed_state)

"""A path followed on the vehicle model alone: no rendering, no sensing, the true pose. What is left of a manoeuvre's
error then is the controller's and the kart's (its steering's lag and rate): the share a better camera cannot take
away. ``benchmarks/manoeuvre_follow.py`` compares path followers on the event's manoeuvres with it."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from kartpilot.control.path_follow import PathFollowConfig, PathFollowState, path_follow_step
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array
from kartpilot.core.types import ActuatorCommand, VehiclePose
from kartpilot.core.vehicle import VehicleParams
from kartpilot.planning.reference_path import ReferencePath, advance_progress, lateral_offset
from kartpilot.sim.dynamics import VehicleState, step_vehicle

__all__ = ["PathDrive", "follow_on_model"]


@dataclass(frozen=True)
class PathDrive:
    """Where the rear axle went along a path, and how far from it.

    Attributes:
        xy_m, yaw_rad: the rear axle's positions and the heading, one row per control step.
        max_offset_m: the largest distance of the rear axle from the path on the way.
        end_offset_m: the rear axle's distance from the path where the kart stopped (positive: left of it).
        end_yaw_error_rad: the kart's heading less the path's at its end, where it stopped.
        end_short_m: how far before the path's end the rear axle stopped (negative: past it).
        finished: whether the follower reached the path's end and the kart stood still.
    """

    xy_m: Array
    yaw_rad: Array
    max_offset_m: float
    end_offset_m: float
    end_yaw_error_rad: float
    end_short_m: float
    finished: bool


def follow_on_model(path: ReferencePath, config: PathFollowConfig, vehicle: VehicleParams, speed_mps: float,
                    dt_s: float, delay_steps: int = 1, max_time_s: float = 60.0) -> PathDrive:
    """The kart on ``vehicle``'s model, starting on the path's first point along its heading at ``speed_mps``,
    steered and driven by :func:`path_follow_step` on its true pose every ``dt_s``; each command reaches the
    actuators ``delay_steps`` steps after the pose it was computed from (a camera pipeline's frame of latency)."""
    if dt_s <= 0 or speed_mps < 0 or delay_steps < 0 or max_time_s <= 0:
        raise ConfigError("follow_on_model: dt_s and max_time_s must be positive, speed_mps and delay_steps not "
                          "negative")
    state = VehicleState(x_m=float(path.x_m[0]), y_m=float(path.y_m[0]), yaw_rad=float(path.heading_rad[0]),
                         vx_mps=speed_mps)
    follow = PathFollowState.start(config)
    pending: deque[ActuatorCommand] = deque(ActuatorCommand(0, 0.0, 0.0, 0.0) for _ in range(delay_steps))
    xy, yaw, offsets = [], [], []
    index, done = 0, False
    for step in range(math.ceil(max_time_s / dt_s)):
        stamp_ns = round(step * dt_s * 1e9)
        pose = VehiclePose(stamp_ns, state.x_m, state.y_m, state.yaw_rad, state.vx_mps, 0.0, "ok", "model")
        out, follow = path_follow_step(config, follow, path, pose, dt_s, vehicle.wheelbase_m, vehicle.max_steer_rad)
        pending.append(ActuatorCommand(stamp_ns, out.steer_rad, out.throttle, out.brake))
        state = step_vehicle(vehicle, state, pending.popleft(), dt_s)
        index = advance_progress(path, state.x_m, state.y_m, index, 2.0 + state.vx_mps * dt_s)
        offsets.append(lateral_offset(path, index, state.x_m, state.y_m)[1])
        xy.append((state.x_m, state.y_m))
        yaw.append(state.yaw_rad)
        done = out.done and state.vx_mps < 0.01
        if done:
            break
    s_end, end_offset = lateral_offset(path, index, state.x_m, state.y_m)
    return PathDrive(np.asarray(xy), np.asarray(yaw), float(np.max(np.abs(offsets))), float(end_offset),
                     math.remainder(state.yaw_rad - float(path.heading_rad[-1]), math.tau),
                     float(path.s_m[-1] - s_end), done)

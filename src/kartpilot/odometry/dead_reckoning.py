"""Dead reckoning: the kart's pose carried forward from its measured speed and its steering angle (the kinematic
single-track model, ``yaw rate = speed tan(steer) / wheelbase``). It holds for the few tens of metres of a
manoeuvre (an overtake) and drifts beyond; where visual odometry runs, its pose is the better one."""

from __future__ import annotations

import math

from kartpilot.core.types import VehiclePose

__all__ = ["dead_reckon"]


def dead_reckon(pose: VehiclePose, speed_mps: float, steer_rad: float, wheelbase_m: float, dt_s: float,
                stamp_ns: int | None = None) -> VehiclePose:
    """The pose ``dt_s`` later, having driven at ``speed_mps`` with the front wheels at ``steer_rad`` (the
    motion integrated exactly along its arc). A speed or steer that is not finite counts as zero."""
    speed = speed_mps if math.isfinite(speed_mps) else 0.0
    steer = steer_rad if math.isfinite(steer_rad) else 0.0
    yaw_rate = speed * math.tan(steer) / wheelbase_m
    turn = yaw_rate * dt_s
    if abs(turn) < 1e-9:
        dx, dy = speed * dt_s, 0.0
    else:
        radius = speed / yaw_rate
        dx, dy = radius * math.sin(turn), radius * (1.0 - math.cos(turn))
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    return VehiclePose(pose.stamp_ns if stamp_ns is None else stamp_ns, pose.x_m + c * dx - s * dy,
                       pose.y_m + s * dx + c * dy, math.remainder(pose.yaw_rad + turn, math.tau), speed, yaw_rate,
                       "bridged", "dead reckoning")

"""Dead reckoning: the kart's pose carried forward from its measured speed and its steering angle (the kinematic
single-track model, ``yaw rate = speed tan(steer) / wheelbase``). It holds for the few tens of metres of a
manoeuvre (an overtake) and drifts beyond; where visual odometry runs, its pose is the better one."""

from __future__ import annotations

import math

from kartpilot.core.geometry import arc_2d, compose_2d
from kartpilot.core.types import VehiclePose

__all__ = ["dead_reckon"]


def dead_reckon(pose: VehiclePose, speed_mps: float, steer_rad: float, wheelbase_m: float, dt_s: float,
                stamp_ns: int | None = None) -> VehiclePose:
    """The pose ``dt_s`` later, having driven at ``speed_mps`` with the front wheels at ``steer_rad`` (the
    motion integrated exactly along its arc). A speed or steer that is not finite counts as zero."""
    speed = speed_mps if math.isfinite(speed_mps) else 0.0
    steer = steer_rad if math.isfinite(steer_rad) else 0.0
    yaw_rate = speed * math.tan(steer) / wheelbase_m
    x, y, yaw = compose_2d((pose.x_m, pose.y_m, pose.yaw_rad), arc_2d(speed, yaw_rate, dt_s))
    return VehiclePose(pose.stamp_ns if stamp_ns is None else stamp_ns, x, y, yaw, speed, yaw_rate, "bridged",
                       "dead reckoning")

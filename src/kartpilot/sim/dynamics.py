"""Vehicle dynamics and actuators as pure functions of (parameters, state, input, dt).

Two single-track ("bicycle") models, blended by speed as in f1tenth_gym:

* kinematic, for low speed: no tyre slip, yaw rate ``v tan(delta) / L``;
* dynamic, for speed: lateral and yaw dynamics with tyre slip angles and a
  tyre force that is linear for small slip and saturates at ``friction * load``.

Actuators: the steering servo follows its command with a first-order lag and a
rate limit, plus a constant bias (the thesis's kart pulled to one side); the
throttle drives toward a top speed that sags as the battery drains; the brake
decelerates. A cross-slope adds a lateral acceleration, which the tyres resist
with a small slip, so the kart drifts downhill unless the controller corrects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from kartpilot.core.types import ActuatorCommand
from kartpilot.core.vehicle import GRAVITY_MPS2, VehicleParams

__all__ = ["Disturbances", "VehicleState", "actuate", "dynamic_derivatives", "kinematic_derivatives", "step_vehicle"]

MAX_SUBSTEP_S = 0.002


@dataclass(frozen=True)
class VehicleState:
    """Pose of the body frame (rear axle centre) and velocities at the centre of gravity."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    yaw_rate_radps: float = 0.0
    steer_rad: float = 0.0
    battery: float = 1.0
    odometer_m: float = 0.0


@dataclass(frozen=True)
class Disturbances:
    """What pushes the kart off its commanded course.

    Attributes:
        steer_bias_rad: added to the servo's angle (positive pulls left).
        lateral_accel_mps2: lateral acceleration in the body frame, positive to the left (a cross-slope
            gives ``g sin(slope)`` toward its low side).
    """

    steer_bias_rad: float = 0.0
    lateral_accel_mps2: float = 0.0


def actuate(params: VehicleParams, state: VehicleState, command: ActuatorCommand, dt_s: float
            ) -> tuple[float, float]:
    """The servo's new angle and the longitudinal acceleration the command produces."""
    target = min(max(command.steer_rad, -params.max_steer_rad), params.max_steer_rad)
    wanted_rate = (target - state.steer_rad) / max(params.steer_lag_s, dt_s)
    rate = min(max(wanted_rate, -params.steer_rate_radps), params.steer_rate_radps)
    steer = state.steer_rad + rate * dt_s

    throttle = min(max(command.throttle, 0.0), 1.0)
    brake = min(max(command.brake, 0.0), 1.0)
    top = params.top_speed_mps * (1.0 - params.battery_sag * (1.0 - state.battery))
    v = state.vx_mps
    drive = params.max_accel_mps2 * throttle * max(0.0, 1.0 - v / top)
    accel = drive - params.rolling_decel_mps2 - brake * params.max_brake_mps2
    if v + accel * dt_s < 0.0:  # brakes and rolling resistance stop the kart, never reverse it
        accel = -v / dt_s
    return steer, accel


def kinematic_derivatives(params: VehicleParams, vx: float, steer: float, lateral_accel: float
                          ) -> tuple[float, float]:
    """(vy at the CG, yaw rate) of a kart whose tyres do not slip, plus the drift a lateral pull causes."""
    yaw_rate = vx * math.tan(steer) / params.wheelbase_m
    drift = lateral_accel * vx / (params.tyre_stiffness_per_rad * GRAVITY_MPS2) if vx > 0 else 0.0
    return params.cg_to_rear_m * yaw_rate + drift, yaw_rate


def dynamic_derivatives(params: VehicleParams, vx: float, vy: float, yaw_rate: float, steer: float,
                        lateral_accel: float) -> tuple[float, float]:
    """(d vy / dt, d yaw_rate / dt) of the dynamic single-track model with saturating tyres."""
    lf, lr = params.cg_to_front_m, params.cg_to_rear_m
    load_f = params.mass_kg * GRAVITY_MPS2 * lr / params.wheelbase_m
    load_r = params.mass_kg * GRAVITY_MPS2 * lf / params.wheelbase_m
    vx_safe = max(vx, 0.1)
    slip_f = steer - math.atan2(vy + lf * yaw_rate, vx_safe)
    slip_r = -math.atan2(vy - lr * yaw_rate, vx_safe)
    mu, c = params.friction, params.tyre_stiffness_per_rad
    force_f = mu * load_f * math.tanh(c * slip_f / mu)
    force_r = mu * load_r * math.tanh(c * slip_r / mu)
    dvy = (force_f * math.cos(steer) + force_r) / params.mass_kg - vx * yaw_rate + lateral_accel
    dr = (lf * force_f * math.cos(steer) - lr * force_r) / params.yaw_inertia_kgm2
    return dvy, dr


def step_vehicle(params: VehicleParams, state: VehicleState, command: ActuatorCommand, dt_s: float,
                 disturbances: Disturbances = Disturbances()) -> VehicleState:
    """Advance the kart by ``dt_s`` under ``command`` (internally in steps of at most 2 ms)."""
    if dt_s <= 0:
        raise ValueError("dt_s must be positive")
    n = max(1, math.ceil(dt_s / MAX_SUBSTEP_S))
    h = dt_s / n
    for _ in range(n):
        state = _substep(params, state, command, h, disturbances)
    return state


def _substep(params: VehicleParams, s: VehicleState, command: ActuatorCommand, h: float,
             dist: Disturbances) -> VehicleState:
    steer, accel = actuate(params, s, command, h)
    wheel = steer + dist.steer_bias_rad
    vx = max(0.0, s.vx_mps + accel * h)

    vy_kin, r_kin = kinematic_derivatives(params, vx, wheel, dist.lateral_accel_mps2)
    dvy, dr = dynamic_derivatives(params, s.vx_mps, s.vy_mps, s.yaw_rate_radps, wheel, dist.lateral_accel_mps2)
    vy_dyn, r_dyn = s.vy_mps + dvy * h, s.yaw_rate_radps + dr * h
    w = params.dynamic_share(vx)
    vy = w * vy_dyn + (1 - w) * vy_kin
    r = w * r_dyn + (1 - w) * r_kin

    # the body frame sits on the rear axle: its lateral velocity is the CG's minus the yaw's share
    v_rear_y = vy - params.cg_to_rear_m * r
    c, si = math.cos(s.yaw_rad), math.sin(s.yaw_rad)
    throttle = min(max(command.throttle, 0.0), 1.0)
    return replace(
        s,
        x_m=s.x_m + (vx * c - v_rear_y * si) * h,
        y_m=s.y_m + (vx * si + v_rear_y * c) * h,
        yaw_rad=s.yaw_rad + r * h,
        vx_mps=vx, vy_mps=vy, yaw_rate_radps=r, steer_rad=steer,
        battery=max(0.0, s.battery - throttle * h / params.battery_endurance_s),
        odometer_m=s.odometer_m + math.hypot(vx, v_rear_y) * h,
    )

"""Speed control: a PI controller on speed that outputs throttle and brake."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SpeedPIConfig", "SpeedPIState", "speed_pi"]


@dataclass(frozen=True)
class SpeedPIConfig:
    """Gains per m/s of speed error. The integral is clamped (anti-windup); braking starts when the
    kart is faster than wanted by more than ``brake_deadband_mps``."""

    kp_per_mps: float = 0.6
    ki_per_m: float = 0.4
    integral_limit: float = 0.6
    brake_gain_per_mps: float = 0.8
    brake_deadband_mps: float = 0.15


@dataclass(frozen=True)
class SpeedPIState:
    integral: float = 0.0


def speed_pi(config: SpeedPIConfig, state: SpeedPIState, target_mps: float, measured_mps: float, dt_s: float
             ) -> tuple[float, float, SpeedPIState]:
    """(throttle, brake, next state), both commands in [0, 1]."""
    error = target_mps - measured_mps
    integral = min(max(state.integral + config.ki_per_m * error * dt_s, 0.0), config.integral_limit)
    throttle = min(max(config.kp_per_mps * error + integral, 0.0), 1.0)
    brake = 0.0
    if error < -config.brake_deadband_mps or target_mps <= 0.0:
        brake = min(max(-config.brake_gain_per_mps * error, 0.0 if target_mps > 0 else 0.3), 1.0)
        throttle = 0.0
    return throttle, brake, SpeedPIState(integral)

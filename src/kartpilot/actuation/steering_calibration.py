"""The steering calibration of a kart whose steering ECU takes a normalised value (the RDW kart).

With the kart on stands (or rolling slowly), :func:`sweep_steering` steps the ECU's value across its
range, waits for the wheels to settle and reads the steering sensor at each step. :func:`fit_steering`
fits the sensor's counts to the value (a straight line: a linear actuator and potentiometer), and
takes the road-wheel angle per unit of value from a measured turning circle at full lock
(:func:`steer_of_turning_circle`, the kinematic single-track model: ``tan(delta) = L / R`` for the rear
axle's radius ``R``) or from a number given by hand. The result is a
:class:`~kartpilot.core.vehicle.SteeringCalibration`, written into the rig file.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable, Sequence

import can
import numpy as np

from kartpilot.actuation.can_bus import ActuatorLimits, CanActuator, CanConfig
from kartpilot.actuation.rdw_protocol import RdwProtocol
from kartpilot.core.errors import ActuationError, CalibrationError
from kartpilot.core.types import ActuatorCommand
from kartpilot.core.vehicle import SteeringCalibration

__all__ = ["RAW_STEERING", "calibrate_steering", "fit_steering", "steer_of_turning_circle", "steering_actuator",
           "sweep_steering", "sweep_values"]

RAW_STEERING = SteeringCalibration(value_sign=1, rad_per_value=1.0)
"""A calibration through which ``steer_rad`` is the ECU's value itself: what the sweep sends with."""
HOLD_STEP_S = 0.02  # the sweep repeats its command this often, well within the actuator's quiet-loop stop
MIN_R_SQUARED = 0.99  # a sensor that follows its actuator; below this something slips, sticks or is unplugged


def sweep_values(max_value: float, steps: int) -> list[float]:
    """``steps`` values evenly across ``[-max_value, max_value]``, from the centre out to one side, back
    through the centre to the other (so the sweep never jumps from lock to lock)."""
    if steps < 3:
        raise CalibrationError("a steering sweep needs at least 3 steps")
    grid = np.linspace(-max_value, max_value, steps)
    right = [float(v) for v in grid if v >= 0]
    left = [float(v) for v in grid[::-1] if v < 0]
    return right + left


def sweep_steering(send: Callable[[ActuatorCommand], None], read_counts: Callable[[], float | None],
                   wait: Callable[[float], None], values: Sequence[float], settle_s: float = 1.0,
                   samples: int = 5) -> list[tuple[float, float]]:
    """(value, sensor counts) at each value: the ECU's value sent through ``send`` (with the brake on
    and no throttle), then ``settle_s`` for the wheels to get there, then the median of ``samples``
    readings ``settle_s / 5`` apart; the command is repeated every ``HOLD_STEP_S`` meanwhile. ``send`` must
    take ``steer_rad`` as the ECU's value
    (:data:`RAW_STEERING`). A sensor that says nothing is an error naming the value."""
    def hold(value: float, seconds: float) -> None:  # the command keeps coming, as from a loop
        for _ in range(max(1, math.ceil(seconds / HOLD_STEP_S))):
            send(ActuatorCommand(0, value, 0.0, 1.0))
            wait(min(HOLD_STEP_S, seconds))

    points = []
    for value in values:
        hold(value, settle_s)
        readings = []
        for _ in range(samples):
            hold(value, settle_s / 5)
            counts = read_counts()
            if counts is not None:
                readings.append(counts)
        if not readings:
            raise ActuationError(f"the steering sensor said nothing at value {value:+.3f} (is 0x1e5 on the bus?)")
        points.append((value, statistics.median(readings)))
    send(ActuatorCommand(0, 0.0, 0.0, 1.0))
    return points


def steer_of_turning_circle(diameter_m: float, wheelbase_m: float) -> float:
    """The road-wheel angle (rad) of a kart whose rear axle's centre drives a circle of ``diameter_m``."""
    if not (math.isfinite(diameter_m) and diameter_m > 0):
        raise CalibrationError(f"the turning circle's diameter must be a positive number of metres, got {diameter_m}")
    return math.atan(wheelbase_m / (diameter_m / 2))


def fit_steering(points: Sequence[tuple[float, float]], rad_per_value: float, value_sign: int = -1,
                 max_value: float = 1.25) -> tuple[SteeringCalibration, float]:
    """The calibration from the sweep's (value, counts), and the fit's R².

    Args:
        points: (value, counts) pairs from :func:`sweep_steering`.
        rad_per_value: road-wheel radians per unit of value (from the turning circle, or by hand).
        value_sign: the sign of the value that steers left (-1: positive steers right, as on the RDW kart).
    """
    if len(points) < 3:
        raise CalibrationError(f"a steering fit needs at least 3 points, got {len(points)}")
    values, counts = (np.array(c, float) for c in zip(*points, strict=True))
    if np.ptp(values) <= 0:
        raise CalibrationError("the sweep's values are all the same")
    slope, offset = np.polyfit(values, counts, 1)
    residual = counts - (slope * values + offset)
    spread = float(np.sum((counts - counts.mean()) ** 2))
    r_squared = 1.0 - float(np.sum(residual**2)) / spread if spread > 0 else 0.0
    if r_squared < MIN_R_SQUARED:
        raise CalibrationError(f"the steering sensor does not follow the command (R² {r_squared:.3f} of a straight "
                               f"line; counts {', '.join(f'{c:.0f}' for c in counts)}): check the sensor and that "
                               "the wheels are free to turn")
    calibration = SteeringCalibration(value_sign=value_sign, rad_per_value=rad_per_value, max_value=max_value,
                                      counts_per_value=round(float(slope), 3), count_offset=round(float(offset), 3))
    return calibration, r_squared


def steering_actuator(bus: can.BusABC, config: CanConfig, values: Sequence[float],
                      clock: Callable[[], int] = time.monotonic_ns) -> tuple[CanActuator, RdwProtocol]:
    """The actuator a sweep sends with: the raw value (:data:`RAW_STEERING`) in the RDW protocol, no limit
    on the steering's rate, in the operator's (manual) state."""
    protocol = RdwProtocol(RAW_STEERING, config.rdw, clock())
    limits = ActuatorLimits(max_steer_rad=max(abs(v) for v in values), max_steer_rate_radps=1e3)  # raw values
    actuator = CanActuator(bus, protocol, config, limits, clock)
    actuator.state = "manual"
    return actuator, protocol


def calibrate_steering(bus: can.BusABC, config: CanConfig, rad_per_value: float, values: Sequence[float],
                       settle_s: float = 1.0, value_sign: int = -1
                       ) -> tuple[SteeringCalibration, float, list[tuple[float, float]]]:
    """Sweep the RDW kart's steering on ``bus`` (live: its sender thread, the wall clock) and fit its
    calibration: (calibration, R², the sweep's points)."""
    actuator, protocol = steering_actuator(bus, config, values)
    actuator.start()
    try:
        points = sweep_steering(actuator.send, lambda: protocol.sensor_counts(time.monotonic_ns()), time.sleep, values,
                                settle_s)
    finally:
        actuator.close()
    calibration, r_squared = fit_steering(points, rad_per_value, value_sign)
    return calibration, r_squared, points

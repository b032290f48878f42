"""Manoeuvres as planned paths, followed by the path follower (Stanley) on the kart's pose: overtaking a
stationary car in the lane, and parking in a bay beside the road between two barriers. A path is in the frame
of the lane where the manoeuvre starts (x ahead along the lane from the kart's rear axle, y to the left of the
lane's centre), from what the camera measured: for an overtake, the car's distance (out to the next lane with the
shift done before the kart's front reaches the car, along it, and back once the kart's rear is past the car with
a margin); for parking, the bay's start, free length and side (forward into the bay, where the cameras look:
an S from the lane's centre to the bay's line that ends with the kart's front ``front_gap_m`` before the
far barrier, and stops there)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kartpilot.core.errors import ConfigError
from kartpilot.planning.reference_path import PathConfig, ReferencePath, build_reference_path

__all__ = ["OvertakeConfig", "ParkConfig", "plan_overtake", "plan_park"]


@dataclass(frozen=True)
class OvertakeConfig:
    """Attributes:
        lane_offset_m: how far to the left the kart passes (the next lane's centre: one lane's width).
        shift_m: the length over which the kart moves out or back (a smooth S).
        car_length_m: the car's length (the camera sees only its rear; an inflatable car is about 4 m).
        front_m: from the kart's rear axle (the body origin) to its front.
        rear_m: from the rear axle to the kart's back.
        before_m, after_m: the least gap, along the lane, between the kart and the car when the kart is fully
            out, and when it starts back.
        run_out_m: straight path in the lane after the return.
        speed_mps: the path's cruise speed.
    """

    lane_offset_m: float = 3.0
    shift_m: float = 8.0
    car_length_m: float = 4.0
    front_m: float = 1.5
    rear_m: float = 0.3
    before_m: float = 1.0
    after_m: float = 2.0
    run_out_m: float = 5.0
    speed_mps: float = 4.0

    def __post_init__(self) -> None:
        if min(self.lane_offset_m, self.shift_m, self.car_length_m, self.speed_mps) <= 0 or min(
                self.front_m, self.rear_m, self.before_m, self.after_m, self.run_out_m) < 0:
            raise ConfigError("overtake: lane_offset_m, shift_m, car_length_m and speed_mps must be positive, the "
                              "margins not negative")


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * t * (10 - 15 * t + 6 * t * t)  # zero slope and curvature at both ends


def plan_overtake(car_distance_m: float, config: OvertakeConfig = OvertakeConfig()) -> ReferencePath | None:
    """The path around a car whose rear is ``car_distance_m`` ahead of the kart's rear axle; None when it is too
    near to be out of the lane before the kart reaches it with a shift of at least 90 % of ``shift_m`` (a
    sharper swerve asks more of the tyres than the plan allows: the curvature grows with the shift's square)."""
    out_by = car_distance_m - config.front_m - config.before_m  # the rear axle's x when the kart is fully out
    shift = min(config.shift_m, out_by)
    if shift < 0.9 * config.shift_m:
        return None
    back_at = car_distance_m + config.car_length_m + config.rear_m + config.after_m
    end = back_at + config.shift_m + config.run_out_m
    x = np.arange(0.0, end + 0.05, 0.1)
    y = config.lane_offset_m * (_smoothstep(x / shift) - _smoothstep((x - back_at) / config.shift_m))
    return build_reference_path(np.column_stack([x, y]), PathConfig(
        spacing_m=0.1, smoothing_m=0.0, cruise_speed_mps=config.speed_mps, max_lateral_accel_mps2=2.0,
        max_accel_mps2=1.5, max_decel_mps2=1.5, min_speed_mps=0.5, stop_at_end=False))


@dataclass(frozen=True)
class ParkConfig:
    """Attributes:
        shift_m: the length of the S into the bay.
        front_m, rear_m: from the kart's rear axle to its front and to its back.
        half_width_m: half the kart's width.
        front_gap_m: where the kart's front stops before the far barrier.
        side_gap_m: the least gap, across the road, between the kart's side and the near barrier while the kart
            passes it; ``barrier_half_width_m`` is half a barrier's width across the road (the bay's line, as the
            camera measures it, is the barriers' middle).
        min_free_m: the least free length a bay needs (the kart's length and both gaps).
        speed_mps: the path's speed.
    """

    shift_m: float = 7.0
    front_m: float = 1.5
    rear_m: float = 0.3
    half_width_m: float = 0.6
    front_gap_m: float = 0.5
    side_gap_m: float = 0.2
    barrier_half_width_m: float = 0.75
    min_free_m: float = 3.5
    speed_mps: float = 2.0

    def __post_init__(self) -> None:
        if min(self.shift_m, self.front_m, self.half_width_m, self.min_free_m, self.speed_mps) <= 0 or min(
                self.rear_m, self.front_gap_m, self.side_gap_m) < 0:
            raise ConfigError("park: the lengths and the speed must be positive, the gaps not negative")


def plan_park(bay_start_m: float, free_m: float, lateral_m: float, config: ParkConfig = ParkConfig()
              ) -> ReferencePath | None:
    """The path into a bay whose free length ``free_m`` begins ``bay_start_m`` ahead of the kart's rear axle, its
    middle ``lateral_m`` to the left (negative: the right), ending where the kart stops; None when the bay is too
    short, too near to reach with the S, or the S would bring the kart's side to the near barrier before its back
    has passed it."""
    if free_m < config.min_free_m:
        return None
    stop = bay_start_m + free_m - config.front_gap_m - config.front_m  # the rear axle where the kart stops
    start = stop - config.shift_m
    if start < 0:
        return None
    x = np.arange(0.0, stop + 0.05, 0.1)
    y = lateral_m * _smoothstep((x - start) / config.shift_m)
    # while the kart's back has not passed the near barrier's end, its side keeps side_gap_m from the bay's line
    beside = x - config.rear_m < bay_start_m
    reach = np.abs(y[beside]).max(initial=0.0) + config.half_width_m + config.side_gap_m
    if reach > abs(lateral_m) - config.barrier_half_width_m:
        return None
    return build_reference_path(np.column_stack([x, y]), PathConfig(
        spacing_m=0.1, smoothing_m=0.0, cruise_speed_mps=config.speed_mps, max_lateral_accel_mps2=1.5,
        max_accel_mps2=1.0, max_decel_mps2=1.0, min_speed_mps=0.3, stop_at_end=True))

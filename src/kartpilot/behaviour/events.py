"""The event's rules as one small state machine: a target speed and, where the kart must stop, a stop point.

A state machine rather than a behaviour tree: the scenarios are a handful of modes the kart is in one at a time
(waiting at the start, driving, stopping for a red light or a pedestrian, waiting), each left on one named
condition; every state and transition can be read, logged and tested on its own. Lane following keeps the
steering; this layer only says how fast, and where to stop. The supervisor stays above it: a fault still stops
the kart whatever this says.

States:

- ``wait_start``: standing at the start until a green light is seen (``start_on_green``; else straight to
  ``drive``).
- ``drive``: at the posted limit (the last speed sign read, ``limit_kmh`` until one is) or the mode's speed,
  whichever is lower.
- ``stop_red``: a red light and a stop line ahead: braking to stop ``stop_margin_m`` before the line; ``wait_red``
  once stopped; back to ``drive`` on green.
- ``yield``: a person on or beside a zebra crossing ahead: braking to stop ``stop_margin_m`` before the crossing;
  waiting until no person has been seen on or beside it for ``clear_s``.

Braking is planned from the stop point's distance, the measured speed and the brake's delay (the RDW brake
actuator travels before it bites, ``brake_delay_s``): the target speed is the one from which ``decel_mps2`` stops
the kart at the stop point after the delay, so it starts braking neither early nor late.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

from kartpilot.core.errors import ConfigError
from kartpilot.perception.objects import Detection

__all__ = ["BehaviourConfig", "BehaviourDecision", "BehaviourState", "behaviour_step", "stopping_speed"]

State = Literal["wait_start", "drive", "stop_red", "wait_red", "yield"]


@dataclass(frozen=True)
class BehaviourConfig:
    """Attributes:
        start_on_green: stand at the start until a green light is seen.
        limit_kmh: the speed limit until a sign says otherwise (the event's signs: 10, 15 and 20 km/h).
        limit_margin: drive this share under the posted limit (a speedometer's and a controller's error).
        stop_margin_m: where the kart's front stops before a stop line or a crossing (the event: 0.2 to 1.5 m).
        front_m: from the body frame's origin (where detections' distances are measured from) to the kart's front
            (the sdc-kart: its rear axle, 1.05 m of wheelbase and 0.45 m of overhang).
        decel_mps2: the braking the plan uses (comfortable, well under the kart's maximum).
        brake_delay_s: the brake's delay before it bites (the RDW brake actuator travels first).
        light_range_m: a light farther than this does not stop the kart yet.
        stop_line_range_m: a stop line this far ahead belongs to a red light seen with it.
        crossing_range_m: a person on or beside a crossing within this distance makes the kart yield.
        clear_s: the crossing counts as clear after this long with no person seen on or beside it.
        stopped_mps: the kart counts as stopped below this speed.
    """

    start_on_green: bool = False
    limit_kmh: float = 20.0
    limit_margin: float = 0.1
    stop_margin_m: float = 0.7
    front_m: float = 1.5
    decel_mps2: float = 1.5
    brake_delay_s: float = 0.4
    light_range_m: float = 25.0
    stop_line_range_m: float = 25.0
    crossing_range_m: float = 20.0
    clear_s: float = 1.5
    stopped_mps: float = 0.15

    def __post_init__(self) -> None:
        if min(self.limit_kmh, self.decel_mps2, self.light_range_m, self.crossing_range_m) <= 0:
            raise ConfigError("behaviour: limit_kmh, decel_mps2 and the ranges must be positive")
        if not 0 <= self.limit_margin < 1 or self.stop_margin_m < 0 or self.brake_delay_s < 0:
            raise ConfigError("behaviour: limit_margin must be in [0, 1), stop_margin_m and brake_delay_s not negative")


@dataclass(frozen=True)
class BehaviourState:
    """What persists between frames: the state, the posted limit, the stop point (metres driven at which to
    stop; NaN for none: it is kept by the metres driven once the line goes out of view under the kart's nose),
    the metres driven so far and the time since a person was last seen at a crossing."""

    state: State = "drive"
    limit_kmh: float = math.nan
    stop_at_m: float = math.nan
    odometer_m: float = 0.0
    clear_for_s: float = 0.0

    @classmethod
    def start(cls, config: BehaviourConfig) -> BehaviourState:
        return cls(state="wait_start" if config.start_on_green else "drive", limit_kmh=config.limit_kmh)


@dataclass(frozen=True)
class BehaviourDecision:
    """The step's decision: the most speed allowed now (m/s; 0: stand), and the state and the reason it is in."""

    speed_cap_mps: float
    state: State
    reason: str
    stop_distance_m: float = math.nan


def stopping_speed(distance_m: float, decel_mps2: float, delay_s: float) -> float:
    """The speed from which braking at ``decel_mps2``, after ``delay_s`` at that speed, stops in ``distance_m``:
    v delay + v^2 / (2 a) = d."""
    if distance_m <= 0:
        return 0.0
    a = decel_mps2
    return -a * delay_s + math.sqrt((a * delay_s) ** 2 + 2 * a * distance_m)


def _nearest(detections: list[Detection], label: str, state: str | None = None) -> Detection | None:
    found = [d for d in detections if d.label == label and (state is None or d.state == state)
             and math.isfinite(d.distance_m) and d.distance_m > 0]
    return min(found, key=lambda d: d.distance_m) if found else None


def behaviour_step(config: BehaviourConfig, state: BehaviourState, detections: list[Detection], speed_mps: float,
                   dt_s: float) -> tuple[BehaviourDecision, BehaviourState]:
    """One step: the decision and the next state, from this frame's detections (placed on the ground, distances
    from the body frame's origin) and the measured speed."""
    if not math.isfinite(speed_mps):
        speed_mps = 0.0
    odometer = state.odometer_m + max(speed_mps, 0.0) * dt_s
    s = replace(state, odometer_m=odometer)
    sign = _nearest(detections, "speed_sign")
    if sign is not None and sign.state.isdigit():
        s = replace(s, limit_kmh=float(sign.state))
    cruise = (s.limit_kmh if math.isfinite(s.limit_kmh) else config.limit_kmh) / 3.6 * (1.0 - config.limit_margin)
    green = _nearest(detections, "traffic_light", "green")
    red = _nearest(detections, "traffic_light", "red")
    line = _nearest(detections, "stop_line")
    crossing = _nearest(detections, "zebra")
    waiting = [d for d in detections if d.label == "person" and d.state in ("on_crossing", "beside_crossing")
               and math.isfinite(d.distance_m) and d.distance_m <= config.crossing_range_m]

    if s.state == "wait_start":
        if green is not None:
            return BehaviourDecision(cruise, "drive", "green: start"), replace(s, state="drive")
        return BehaviourDecision(0.0, "wait_start", "waiting for green"), s

    if s.state in ("drive", "stop_red", "wait_red") and red is not None and red.distance_m <= config.light_range_m:
        if line is not None and line.distance_m <= config.stop_line_range_m:
            s = replace(s, stop_at_m=odometer + line.distance_m - config.front_m - config.stop_margin_m)
        elif not math.isfinite(s.stop_at_m):
            s = replace(s, stop_at_m=odometer + max(red.distance_m - 3.0 - config.front_m, 0.0))  # no line: short
        if s.state == "drive":
            s = replace(s, state="stop_red")
    elif s.state in ("stop_red", "wait_red") and green is not None:
        return BehaviourDecision(cruise, "drive", "green: go on"), replace(s, state="drive", stop_at_m=math.nan)

    if waiting and s.state in ("drive", "yield"):
        edge = crossing.distance_m if crossing is not None else min(p.distance_m for p in waiting) - 2.0
        if s.state == "drive":
            s = replace(s, state="yield", stop_at_m=odometer + edge - config.front_m - config.stop_margin_m)
        s = replace(s, clear_for_s=0.0)
    elif s.state == "yield":
        s = replace(s, clear_for_s=s.clear_for_s + dt_s)
        if s.clear_for_s >= config.clear_s:
            return BehaviourDecision(cruise, "drive", "crossing clear: go on"), replace(
                s, state="drive", stop_at_m=math.nan)

    if s.state in ("stop_red", "wait_red", "yield"):
        remaining = s.stop_at_m - odometer
        cap = min(cruise, stopping_speed(remaining, config.decel_mps2, config.brake_delay_s))
        name: State = s.state
        if s.state == "stop_red" and speed_mps <= config.stopped_mps and remaining < 2.0:
            name = "wait_red"
            s = replace(s, state="wait_red")
        reason = {"stop_red": "red light: stopping before the line", "wait_red": "red light: waiting for green",
                  "yield": "pedestrian at the crossing: waiting"}[name]
        return BehaviourDecision(cap, name, reason, remaining), s
    return BehaviourDecision(cruise, "drive", f"limit {s.limit_kmh:g} km/h"), s

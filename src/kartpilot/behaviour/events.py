"""The event's rules as one small state machine: a target speed and, where the kart must stop, a stop point.

A state machine rather than a behaviour tree: the scenarios are a handful of modes the kart is in one at a time
(waiting at the start, driving, stopping for a red light or a pedestrian, waiting), each left on one named
condition; every state and transition can be read, logged and tested on its own. Lane following keeps the
steering, except in a manoeuvre: this layer says how fast, where to stop and, for an overtake, the path
(:mod:`manoeuvres`) that the path follower steers along. The supervisor stays above it: a fault still stops the
kart whatever this says.

States:

- ``wait_start``: standing at the start until a green light is seen (``start_on_green``; else straight to
  ``drive``).
- ``drive``: at the posted limit (the last speed sign read, ``limit_kmh`` until one is) or the mode's speed,
  whichever is lower. A lower limit holds from the moment its sign is read (the kart is down to it by the sign);
  a higher one from where the kart's front reaches its sign (the event: "keep to the posted speed limit until a
  new sign is given"), as the sign's distance said when it was last read, the nearest reading the surest.
- ``stop_red``: a red light and a stop line ahead (before the light, where its line lies): braking to stop
  ``stop_margin_m`` before the line; ``wait_red``
  once stopped; back to ``drive`` on green.
- ``yield``: a person on or beside a zebra crossing ahead, or on the road in the kart's corridor: braking to stop
  ``crossing_margin_m`` before the crossing (``person_clearance_m`` before the person where no crossing is seen yet);
  waiting until no such person has been seen for ``clear_s``. A car found in the lane while no such person is seen,
  standing where the kart was to stop (within a car's length beyond), is what was taken for people (a car's two
  sides, where its back was not found upright, are each as tall and thin as a person): the car's rule at once.
- ``overtake``: a car in the kart's lane within ``car_range_m`` (with ``overtake`` on): the path around it is
  planned once, from the car's measured distance, and followed until its end; then ``drive``.
- ``wait_car``: the same car with ``overtake`` off, or too near to pass: stopping ``car_gap_m`` behind it and
  waiting until the lane has been clear for ``clear_s``.
- ``park``: a parking bay (two barriers beside the road, a free length between them) within ``bay_range_m``
  (with ``park`` on): the path into it is planned and followed, slowing to stop where it ends; ``parked``
  once stopped there, for good. The camera places a far barrier worse the farther it stands (a degree of the
  mount's pitch moves a foot 25 m ahead by metres), so the bay is measured again from every nearer view of its far
  barrier: the path replanned while its S has not begun, the stop point brought nearer after.

Braking is planned from the stop point's distance, the measured speed and the brake's delay (the RDW brake
actuator travels before it bites, ``brake_delay_s``): the target speed is the one from which ``decel_mps2`` stops
the kart at the stop point after the delay, so it starts braking neither early nor late.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from kartpilot.behaviour.manoeuvres import OvertakeConfig, ParkConfig, plan_overtake, plan_park
from kartpilot.core.errors import ConfigError
from kartpilot.perception.objects import CROSSING_DEPTH_M, Detection
from kartpilot.perception.scan import LidarView, bay_between_barriers, corridor_free_m, side_clear
from kartpilot.planning.reference_path import ReferencePath

__all__ = ["ACTED_ON", "BehaviourConfig", "BehaviourDecision", "BehaviourState", "act_window", "behaviour_step",
           "stopping_speed"]

State = Literal["wait_start", "drive", "stop_red", "wait_red", "yield", "overtake", "wait_car", "park", "parked"]


@dataclass(frozen=True)
class BehaviourConfig:
    """Attributes:
        start_on_green: stand at the start until a green light is seen.
        limit_kmh: the speed limit until a sign says otherwise (the event's signs: 10, 15 and 20 km/h).
        limit_margin: drive this share under the posted limit (a speedometer's and a controller's error).
        stop_margin_m: where the kart's front stops before a stop line (the event: 0.2 to 1.5 m).
        stop_margin_max_m: where a light standing past its line would leave the camera's view before the kart
            stops (a signal head 2 m up, a few metres past the line, rises out of the top of a low camera's image:
            the kart then waited for a green it could not see), the kart stops farther back, up to this far before
            the line (the light's ``view_to_m``).
        crossing_margin_m: where the kart's front stops before a crossing it yields at: out of the last metres
            before it, where a kart still rolling as a pedestrian steps onto the road is faulted (the scenario
            referee watches 3 m).
        front_m: from the body frame's origin (where detections' distances are measured from) to the kart's front
            (the sdc-kart: its rear axle, 1.05 m of wheelbase and 0.45 m of overhang).
        decel_mps2: the braking the plan uses (comfortable, well under the kart's maximum).
        brake_delay_s: the brake's delay before it bites (the RDW brake actuator travels first).
        light_range_m: a light farther than this does not stop the kart yet.
        light_confirm_s: a light's colour is acted on once it has been seen this long without a break (a lamp
            found in one frame, a person's face at the image's edge once, held the kart at a red light for good;
            at 15 frames/s, three frames: 1.1 m at 20 km/h).
        stop_line_range_m: a stop line this far ahead belongs to a red light seen with it.
        line_refine_m: how much farther a stop line seen again may move the stop point (its placement refines as
            the kart comes; a jump beyond is not the line it is stopping at).
        crossing_range_m: a person on or beside a crossing, or on the road in the kart's corridor, within this
            distance makes the kart yield.
        corridor_m: a person this close to the kart's line (either side) is on its road, crossing or not.
        person_clearance_m: with no crossing seen, the kart's front stops this far before such a person.
        crossed_m: a person beside a crossing who is this much farther across the road from its middle than the
            nearest they came (measured from the crossing seen with them: in a bend the kart's own line points off
            the road ahead), having come within ``corridor_m`` of it and left it again, has crossed; on that side,
            people hold the kart only within ``corridor_m - crossed_m`` (come back onto its road) until the kart
            has driven ``crossing_range_m`` on (the one who crossed, stopped at the road's edge and placed nearer
            as the kart comes, or lost at the image's edge and seen again as another track, held it for good).
        past_end_share: a person beside a crossing has also left the kart's corridor (for ``crossed_m`` above) where
            they stand beyond the crossing's end by this share of its half-width, both measured together (a camera
            pitched off its mount places a person and the crossing's ends short, or long, by the same share: the
            corridor's metres it misjudges, the crossing's end it does not; the event's teams go on when the
            person has reached the crossing's far edge, moving away).
        clear_s: the crossing counts as clear after this long with no person seen on or beside it.
        stopped_mps: the kart counts as stopped below this speed.
        overtake: pass a stationary car in the lane (where the road allows it: the scenario, a team's
            knowledge of the course); off, the kart stops ``car_gap_m`` behind it and waits.
        car_range_m: a car in the corridor this near starts the overtake (or the stop).
        car_corridor_m: a car whose middle is this close to the kart's line is in its lane.
        car_gap_m: where the kart's front stops behind a car it does not pass.
        park: park in the first bay between barriers seen within ``bay_range_m`` (the event's last scenario), once
            the kart has driven ``park_after_m`` (a team's knowledge of the course: where its bay comes last).
        bay_gate_m, bay_gate_share: while parking, a barrier on the bay's side is its far barrier seen again when
            it stands within ``max(bay_gate_m, bay_gate_share * D)`` of where the bay's far end was put, D being
            the distance it was last measured from (the camera's error grows with the distance's square).
        lidar_corridor_m: with a LiDAR, anything in the strip this far either side of the kart's line ahead of its
            front is in its way, seen by the camera or not: the kart stops ``lidar_gap_m`` before it.
        lidar_gap_m: where the kart's front stops before something the LiDAR sees in its way.
        return_extend_m: with a LiDAR, an overtake's return waits while the scan shows something beside the kart in
            the lane it returns to: the pass goes on this much farther each time (at most ``return_wait_m`` in
            all; then it returns as planned, and says so).
    """

    start_on_green: bool = False
    limit_kmh: float = 20.0
    limit_margin: float = 0.1
    stop_margin_m: float = 0.7
    stop_margin_max_m: float = 1.2
    crossing_margin_m: float = 3.0
    front_m: float = 1.5
    decel_mps2: float = 1.5
    brake_delay_s: float = 0.4
    light_range_m: float = 25.0
    light_confirm_s: float = 0.2
    stop_line_range_m: float = 25.0
    line_refine_m: float = 1.5
    crossing_range_m: float = 20.0
    corridor_m: float = 2.0
    person_clearance_m: float = 2.0
    crossed_m: float = 1.0
    past_end_share: float = 0.2
    clear_s: float = 1.5
    stopped_mps: float = 0.15
    overtake: bool = False
    car_range_m: float = 14.0
    car_corridor_m: float = 1.2
    car_gap_m: float = 3.0
    passing: OvertakeConfig = field(default_factory=OvertakeConfig)
    park: bool = False
    park_after_m: float = 0.0
    bay_range_m: float = 12.0
    bay_gate_m: float = 1.0
    bay_gate_share: float = 0.25
    parking: ParkConfig = field(default_factory=ParkConfig)
    lidar_corridor_m: float = 0.9
    lidar_gap_m: float = 1.5
    return_extend_m: float = 1.0
    return_wait_m: float = 10.0

    def __post_init__(self) -> None:
        if min(self.limit_kmh, self.decel_mps2, self.light_range_m, self.crossing_range_m) <= 0:
            raise ConfigError("behaviour: limit_kmh, decel_mps2 and the ranges must be positive")
        if not 0 <= self.light_confirm_s <= 2.0:
            raise ConfigError("behaviour: light_confirm_s must be between 0 and 2 s")
        if not 0 <= self.limit_margin < 1 or min(self.stop_margin_m, self.crossing_margin_m, self.line_refine_m,
                                                 self.brake_delay_s) < 0:
            raise ConfigError("behaviour: limit_margin must be in [0, 1), stop_margin_m, crossing_margin_m, "
                              "line_refine_m and brake_delay_s not negative")
        if not 0 <= self.past_end_share <= 1:
            raise ConfigError("behaviour: past_end_share must be between 0 and 1")
        if self.bay_gate_m <= 0 or not 0 <= self.bay_gate_share <= 1:
            raise ConfigError("behaviour: bay_gate_m must be positive, bay_gate_share between 0 and 1")
        if self.stop_margin_max_m < self.stop_margin_m:
            raise ConfigError("behaviour: stop_margin_max_m must be at least stop_margin_m (the farthest back the "
                              "kart may stop before a line for its light to stay in view)")


@dataclass(frozen=True)
class BehaviourState:
    """What persists between frames: the state, the posted limit, the stop point (metres driven at which to
    stop; NaN for none: it is kept by the metres driven once the line goes out of view under the kart's nose),
    the metres driven so far, the time since a person was last seen at a crossing, for each person tracked
    the nearest they came to the crossing's middle and the side the last one crossed to (one who crossed and walks
    away is done), and how long a red and a green light have been seen without a break."""

    state: State = "drive"
    limit_kmh: float = math.nan
    stop_at_m: float = math.nan
    odometer_m: float = 0.0
    clear_for_s: float = 0.0
    # per person's track id: the least |offset| from the crossing's middle seen while one was seen with them
    nearest_lateral_m: tuple[tuple[int, float], ...] = ()
    crossed_to: int = 0  # the side (+1 left, -1 right) a person last crossed the kart's corridor to, and the
    crossed_at_m: float = math.nan  # metres driven then (on that side, people hold the kart only on its road)
    manoeuvre_end_m: float = math.nan
    red_seen_s: float = 0.0
    green_seen_s: float = 0.0
    rising_limit_kmh: float = math.nan  # a higher limit read ahead, and the metres driven at which it holds
    rising_at_m: float = math.nan
    manoeuvre_start_m: float = math.nan  # an overtake's start (metres driven), the car's distance then, and the
    car_distance_m: float = math.nan  # car length its path is planned with now (longer while the scan shows the
    car_length_m: float = math.nan  # car still beside the kart)
    bay_m: tuple[float, float, float] = (math.nan, math.nan, math.nan)  # parking: the bay's start (metres driven),
    bay_measured: bool = False  # free length and line as planned; whether the scan has measured it since
    bay_seen_m: float = math.nan  # how far ahead the bay's far end stood when the camera last measured it

    @classmethod
    def start(cls, config: BehaviourConfig) -> BehaviourState:
        return cls(state="wait_start" if config.start_on_green else "drive", limit_kmh=config.limit_kmh)


@dataclass(frozen=True)
class BehaviourDecision:
    """The step's decision: the most speed allowed now (m/s; 0: stand), the state and the reason it is in, and
    where a manoeuvre starts, its path."""

    speed_cap_mps: float
    state: State
    reason: str
    stop_distance_m: float = math.nan
    path: ReferencePath | None = None  # a manoeuvre's path, given on the step it starts (the lane's frame there)
    replanned: bool = False  # the path replaces the one under way, in the same frame (an overtake's return waits)
    sensors: str = "camera"  # what the decision was made from: camera, lidar, or camera+lidar


_TRACKED_PEOPLE = 32


ACTED_ON = ("traffic_light", "speed_sign", "stop_line", "crosswalk", "person", "car", "barrier", "parking_bay")
"""The classes of things the rules act on."""


def act_window(label: str, config: BehaviourConfig) -> tuple[float, float]:
    """Where (metres ahead of the rear axle) the kart acts on a thing of class ``label``, as the rules play them.

    Near end: where the kart stands still before it (its front and margin before a light's line or a sign, its
    margin before a crossing, its clearance before a person, its gap behind a car), or for a bay, where the bay
    passes under its front; nearer, the kart has acted already (the stop point is kept by the metres driven, a
    manoeuvre's path is planned once). Far end: where it must have seen it: for a light, a sign, a stop line, a
    crossing or a person, the near end plus the stopping distance from ``limit_kmh`` with the planned braking after
    the brake's delay (for a light and its stop line, after the light has been seen for ``light_confirm_s`` too);
    for a car, where the overtake is planned; for a parking bay and its barriers, where parking starts. What a
    detector must find, and where (:mod:`kartpilot.eval.detection` scores it so)."""
    b = config
    if label == "car":
        return b.front_m + b.car_gap_m, b.car_range_m
    if label in ("barrier", "parking_bay"):
        return b.front_m, b.bay_range_m
    margin = {"crosswalk": b.crossing_margin_m, "person": b.person_clearance_m}.get(label, b.stop_margin_m)
    v = b.limit_kmh / 3.6
    confirm = b.light_confirm_s if label in ("traffic_light", "stop_line") else 0.0
    return b.front_m + margin, b.front_m + margin + v * (confirm + b.brake_delay_s) + v * v / (2 * b.decel_mps2)


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


def _posted_limit(config: BehaviourConfig, state: BehaviourState, sign: Detection | None) -> BehaviourState:
    """The limit after this frame's nearest sign: a lower one at once, a higher one kept until the kart's front
    reaches its sign (each new reading of it, nearer, replaces the last)."""
    s = state
    if sign is not None and sign.state.isdigit():
        value = float(sign.state)
        current = s.limit_kmh if math.isfinite(s.limit_kmh) else config.limit_kmh
        if value > current:
            s = replace(s, rising_limit_kmh=value, rising_at_m=s.odometer_m + sign.distance_m - config.front_m)
        else:
            s = replace(s, limit_kmh=value, rising_limit_kmh=math.nan, rising_at_m=math.nan)
    if math.isfinite(s.rising_at_m) and s.odometer_m >= s.rising_at_m:
        s = replace(s, limit_kmh=s.rising_limit_kmh, rising_limit_kmh=math.nan, rising_at_m=math.nan)
    return s


def behaviour_step(config: BehaviourConfig, state: BehaviourState, detections: list[Detection], speed_mps: float,
                   dt_s: float, lidar: LidarView | None = None) -> tuple[BehaviourDecision, BehaviourState]:
    """One step: the decision and the next state, from this frame's detections (placed on the ground, distances
    from the body frame's origin) and the measured speed.

    With ``lidar`` (a healthy LiDAR's latest sweep; None: the camera-only rules), the same rules, and: a parking
    bay's start and free length measured between the barriers the scan sees; an overtake's return held while the
    scan shows something beside the kart in the lane it returns to; and a stop before anything the scan sees in
    the kart's way, whether the camera saw it or not. Each decision says in ``sensors`` what it was made from."""
    decision, s = _rules_step(config, state, detections, speed_mps, dt_s, lidar)
    if lidar is None:
        return decision, s
    if decision.sensors == "camera":
        decision = replace(decision, sensors="camera+lidar")
    if decision.state in ("drive", "stop_red", "wait_red", "yield", "wait_car"):
        w = config.lidar_corridor_m
        free = corridor_free_m(lidar.points_m, -w, w, config.front_m, config.front_m + 40.0)
        if math.isfinite(free):
            gap = free - config.lidar_gap_m
            cap = stopping_speed(gap, config.decel_mps2, config.brake_delay_s)
            if cap < decision.speed_cap_mps:
                decision = replace(decision, speed_cap_mps=cap, stop_distance_m=gap, sensors="lidar",
                                   reason=f"something in the lane {free:.1f} m ahead of the front (lidar)")
    return decision, s


def _hold_return(config: BehaviourConfig, s: BehaviourState, odometer: float, lidar: LidarView
                 ) -> tuple[ReferencePath | None, BehaviourState, str]:
    """Just before an overtake's return, the lane it returns to beside the kart (from ``after_m`` behind its back
    to a metre ahead of its front) as the scan shows it: where something is there (the car, longer than assumed),
    the pass replanned ``return_extend_m`` longer, in the same frame, and why; no path where the return may go
    ahead (with the reason where it goes ahead though the lane beside is not clear: ``return_wait_m`` waited)."""
    passing = config.passing
    back_at = s.car_distance_m + s.car_length_m + passing.rear_m + passing.after_m  # where the return begins
    progress = odometer - s.manoeuvre_start_m
    lane = passing.lane_offset_m
    if not back_at - config.return_extend_m <= progress <= back_at or side_clear(
            lidar.points_m, -(passing.rear_m + passing.after_m), passing.front_m + 1.0, -lane - 1.2, -lane + 1.2):
        return None, s, ""
    if s.car_length_m - passing.car_length_m >= config.return_wait_m:
        return None, s, (f"the lane beside still not clear after {config.return_wait_m:g} m more: returning as "
                         "planned (lidar)")
    length = s.car_length_m + config.return_extend_m
    path = plan_overtake(s.car_distance_m, replace(passing, car_length_m=length))
    if path is None:
        return None, s, ""
    return path, replace(s, car_length_m=length, manoeuvre_end_m=s.manoeuvre_start_m + float(path.s_m[-1])), (
        "something still beside the kart in the lane: the return waits (lidar)")


def _measure_bay(config: BehaviourConfig, s: BehaviourState, odometer: float, lidar: LidarView
                 ) -> tuple[ReferencePath, BehaviourState] | None:
    """While parking on the camera's estimate of the bay, before the S into it begins: the bay between its barriers
    as the scan measures it, once both are within its range; the path replanned from it in the same frame (the lane's
    where parking began). None until then, or where the scan's bay cannot be driven into."""
    start_m, _, lateral_m = s.bay_m
    progress = odometer - s.manoeuvre_start_m
    measured = bay_between_barriers(lidar.clusters, math.copysign(1.0, lateral_m), start_m - odometer, lateral_m)
    if measured is None:
        return None
    start, free = measured
    path = plan_park(start + progress, free, lateral_m, config.parking)
    if path is None or float(path.x_m[np.argmax(np.abs(path.y_m) > 0.01)]) < progress:
        return None  # too short for the S, or its S would have begun behind the kart already
    return path, replace(s, stop_at_m=s.manoeuvre_start_m + float(path.s_m[-1]), bay_measured=True,
                         bay_m=(odometer + start, free, lateral_m))


def _bay_seen_again(config: BehaviourConfig, s: BehaviourState, odometer: float, detections: list[Detection]
                    ) -> tuple[ReferencePath | None, BehaviourState] | None:
    """While parking on the camera's estimate of the bay: its far barrier seen from nearer than it was last measured
    (a barrier on the bay's side, beyond its start, within the gate of where its far end was put; or the bay
    itself), the nearest such view taken, with the bay's start and line from the bay seen in the same frame (its
    line, the barriers' middle, is placed worse from afar too: a degree of the mount's roll moves it by a metre at
    12 m). While the S into the bay has not begun, the path is replanned from them (the lane's frame where parking
    began); after, the stop point only comes nearer (the kart then stands nearly along the bay, so the barrier's
    distance ahead is its distance along it). None when no such view is in this frame."""
    start_m, free_m, lateral_m = s.bay_m
    side = math.copysign(1.0, lateral_m)
    gate = max(config.bay_gate_m, config.bay_gate_share * s.bay_seen_m)
    far_views, bays = [], []  # (the far end in metres driven, how far ahead); (the start in metres driven, line)
    for d in detections:
        if not (math.isfinite(d.distance_m) and math.isfinite(d.lateral_m)) or d.lateral_m * side <= 0:
            continue
        if d.label == "parking_bay":
            try:
                free = float(d.state)
            except ValueError:
                continue
            far_views.append((odometer + d.distance_m + free, d.distance_m + free))
            if abs(odometer + d.distance_m - start_m) <= gate and abs(d.lateral_m - lateral_m) <= gate:
                bays.append((odometer + d.distance_m, d.lateral_m))
        elif d.label == "barrier":
            far_views.append((odometer + d.distance_m, d.distance_m))
    far_views = [v for v in far_views if v[1] < s.bay_seen_m and abs(v[0] - (start_m + free_m)) <= gate
                 and v[0] - start_m >= config.parking.min_free_m / 2]
    if not far_views:
        return None
    far, ahead = min(far_views, key=lambda v: v[1])
    start, line = min(bays, key=lambda b: b[0]) if bays else (start_m, lateral_m)
    progress = odometer - s.manoeuvre_start_m
    path = plan_park(start - s.manoeuvre_start_m, far - start, line, config.parking)
    if path is not None and float(path.x_m[np.argmax(np.abs(path.y_m) > 0.01)]) >= progress:
        return path, replace(s, bay_m=(start, far - start, line), bay_seen_m=ahead,
                             stop_at_m=s.manoeuvre_start_m + float(path.s_m[-1]))
    stop = odometer + ahead - config.parking.front_gap_m - config.parking.front_m
    return None, replace(s, bay_m=(start_m, far - start_m, lateral_m), bay_seen_m=ahead,
                         stop_at_m=min(s.stop_at_m, stop))


def _rules_step(config: BehaviourConfig, state: BehaviourState, detections: list[Detection], speed_mps: float,
                dt_s: float, lidar: LidarView | None) -> tuple[BehaviourDecision, BehaviourState]:
    if not math.isfinite(speed_mps):
        speed_mps = 0.0
    odometer = state.odometer_m + max(speed_mps, 0.0) * dt_s
    s = replace(state, odometer_m=odometer)
    s = _posted_limit(config, s, _nearest(detections, "speed_sign"))
    cruise = (s.limit_kmh if math.isfinite(s.limit_kmh) else config.limit_kmh) / 3.6 * (1.0 - config.limit_margin)
    green = _nearest(detections, "traffic_light", "green")
    red = _nearest(detections, "traffic_light", "red")
    s = replace(s, red_seen_s=s.red_seen_s + dt_s if red is not None else 0.0,
                green_seen_s=s.green_seen_s + dt_s if green is not None else 0.0)
    if s.red_seen_s < config.light_confirm_s - 1e-6:  # not yet seen long enough to act on
        red = None
    if s.green_seen_s < config.light_confirm_s - 1e-6:
        green = None
    line = _nearest(detections, "stop_line")
    crossing = _nearest(detections, "crosswalk")
    people = [d for d in detections if d.label == "person" and math.isfinite(d.distance_m)
              and 0 < d.distance_m <= config.crossing_range_m]
    # a person's offset across the road: from the crossing seen with them where there is one (in a bend the kart's
    # own line points off the road ahead: a person standing 2.6 m beside a crossing 17 m ahead was placed on the
    # kart's line, then 2.4 m beside it at 10 m, and so "crossed" it without a step); else from the kart's line
    def across(p: Detection) -> float:
        if crossing is not None and math.isfinite(crossing.lateral_m) and \
                abs(p.distance_m - crossing.distance_m) <= CROSSING_DEPTH_M + config.person_clearance_m:
            return p.lateral_m - crossing.lateral_m
        return math.nan

    def offset(p: Detection) -> float:
        road = across(p)
        return road if math.isfinite(road) else p.lateral_m

    nearest = dict(s.nearest_lateral_m)
    for p in people:
        if p.track_id > 0 and math.isfinite(across(p)):
            nearest[p.track_id] = min(nearest.get(p.track_id, math.inf), abs(across(p)))
    # the newest tracks only (ids grow): a long drive's people do not pile up
    s = replace(s, nearest_lateral_m=tuple(sorted(nearest.items()))[-_TRACKED_PEOPLE:])
    # a person on the road in the kart's way (whether a crossing is seen yet or not: the camera finds a zebra on
    # the ground nearer than it finds a person), or on or beside a crossing unless they have crossed the kart's
    # line and walk away from it (one who stops at the crossing's far end is seen on it or beside it by turns)
    half_width = crossing.width_m / 2.0 if crossing is not None else math.nan

    def left_corridor(p: Detection) -> bool:  # out of the kart's corridor, or past the crossing's end
        return abs(across(p)) > config.corridor_m or abs(across(p)) > half_width * (1.0 + config.past_end_share)

    crossed = [p for p in people if nearest.get(p.track_id, math.inf) <= config.corridor_m and left_corridor(p)
               and abs(across(p)) - nearest[p.track_id] >= config.crossed_m]
    if crossed:  # one who came into the kart's way and walked on across it
        s = replace(s, crossed_to=1 if across(crossed[0]) > 0 else -1, crossed_at_m=s.odometer_m)
    elif s.crossed_to and not s.odometer_m - s.crossed_at_m <= config.crossing_range_m:
        s = replace(s, crossed_to=0, crossed_at_m=math.nan)  # that crossing is behind the kart

    # on the side a pedestrian has crossed to, a person standing at the road's edge (placed nearer as the kart
    # comes on, or seen again under another track after being lost at the image's edge) is the one who crossed:
    # they hold the kart again by coming back crossed_m into its corridor
    def holds(p: Detection) -> bool:
        if s.crossed_to and (offset(p) > 0) == (s.crossed_to > 0):
            return abs(offset(p)) <= config.corridor_m - config.crossed_m
        return abs(p.lateral_m) <= config.corridor_m or (
            p.state in ("on_crossing", "beside_crossing")
            and abs(offset(p)) - nearest.get(p.track_id, math.inf) < config.crossed_m)

    waiting = [p for p in people if holds(p)]

    car = min((d for d in detections if d.label == "car" and math.isfinite(d.distance_m) and d.distance_m > 0
               and abs(d.lateral_m) <= config.car_corridor_m), key=lambda d: d.distance_m, default=None)
    if s.state == "parked":
        return BehaviourDecision(0.0, "parked", "parked in the bay"), s
    if s.state == "park" and lidar is not None and not s.bay_measured:
        remeasured = _measure_bay(config, s, odometer, lidar)
        if remeasured is not None:
            bay_path, s = remeasured
            return BehaviourDecision(min(cruise, config.parking.speed_mps), "park", f"bay measured {s.bay_m[1]:.2f} m "
                                     "long between its barriers (lidar)", s.stop_at_m - odometer, bay_path,
                                     replanned=True, sensors="lidar"), s
    if s.state == "park" and not s.bay_measured:
        again = _bay_seen_again(config, s, odometer, detections)
        if again is not None:
            replanned, s = again
            if replanned is not None:
                return BehaviourDecision(min(cruise, config.parking.speed_mps), "park", f"bay measured again: "
                                         f"{s.bay_m[1]:.2f} m long, its far end {s.bay_seen_m:.1f} m ahead",
                                         s.stop_at_m - odometer, replanned, replanned=True), s
    if s.state == "park":
        remaining = s.stop_at_m - odometer
        if speed_mps <= config.stopped_mps and remaining < 0.5:
            return BehaviourDecision(0.0, "parked", "parked in the bay"), replace(s, state="parked")
        cap = min(cruise, config.parking.speed_mps, stopping_speed(remaining, config.decel_mps2, config.brake_delay_s))
        return BehaviourDecision(cap, "park", "parking in the bay", remaining), s
    bay = _nearest(detections, "parking_bay")
    if (config.park and s.state == "drive" and bay is not None and bay.distance_m <= config.bay_range_m
            and odometer >= config.park_after_m):
        try:
            free = float(bay.state)
        except ValueError:
            free = math.nan
        start, sensors = bay.distance_m, "camera"
        measured = bay_between_barriers(lidar.clusters, math.copysign(1.0, bay.lateral_m), bay.distance_m,
                                        bay.lateral_m) if lidar is not None else None
        if measured is not None:  # the scan measures between the barriers; the camera said where to look
            (start, free), sensors = measured, "camera+lidar"
        path = plan_park(start, free, bay.lateral_m, config.parking) if math.isfinite(free) else None
        if path is not None:
            s = replace(s, state="park", stop_at_m=odometer + float(path.s_m[-1]), manoeuvre_start_m=odometer,
                        bay_m=(odometer + start, free, bay.lateral_m), bay_measured=measured is not None,
                        bay_seen_m=start + free)
            return BehaviourDecision(min(cruise, config.parking.speed_mps), "park",
                                     f"bay {free:.1f} m long {start:.1f} m ahead: parking",
                                     float(path.s_m[-1]), path, sensors=sensors), s
    if s.state == "overtake":
        held, s, why = _hold_return(config, s, odometer, lidar) if lidar is not None else (None, s, "")
        if held is not None:
            return BehaviourDecision(cruise, "overtake", why, path=held, replanned=True, sensors="lidar"), s
        if odometer < s.manoeuvre_end_m:
            return BehaviourDecision(cruise, "overtake", why or "overtaking the car", sensors="lidar" if why else
                                     "camera"), s
        s = replace(s, state="drive", manoeuvre_end_m=math.nan, manoeuvre_start_m=math.nan, car_distance_m=math.nan,
                    car_length_m=math.nan)
        return BehaviourDecision(cruise, "drive", "back in the lane"), s

    if s.state == "wait_start":
        if green is not None:
            return BehaviourDecision(cruise, "drive", "green: start"), replace(s, state="drive")
        return BehaviourDecision(0.0, "wait_start", "waiting for green"), s

    if s.state in ("drive", "stop_red", "wait_red") and red is not None and red.distance_m <= config.light_range_m:
        # the light's stop line lies before it: a line beyond the light (by more than the light's placement, from
        # its lamp's size, may be off) is another, or paint taken for one, and does not move the stop point
        if line is not None and line.distance_m <= min(config.stop_line_range_m, red.distance_m
                                                       + max(1.0, 0.1 * red.distance_m)):
            stop_at = odometer + line.distance_m - config.front_m - config.stop_margin_m
            if math.isfinite(red.view_to_m):  # where the light would leave the view, farther back if it must
                farthest = odometer + line.distance_m - config.front_m - config.stop_margin_max_m
                stop_at = min(stop_at, max(odometer + red.distance_m - red.view_to_m, farthest))
            # nearer is always taken; farther only by a line's placement as the kart comes (a line far beyond the
            # one the kart is stopping or standing at is another, or paint taken for one, seen for a frame)
            if not math.isfinite(s.stop_at_m) or stop_at <= s.stop_at_m + config.line_refine_m:
                s = replace(s, stop_at_m=stop_at)
        elif not math.isfinite(s.stop_at_m):
            s = replace(s, stop_at_m=odometer + max(red.distance_m - 3.0 - config.front_m, 0.0))  # no line: short
        if s.state == "drive":
            s = replace(s, state="stop_red")
    elif s.state in ("stop_red", "wait_red") and green is not None:
        return BehaviourDecision(cruise, "drive", "green: go on"), replace(s, state="drive", stop_at_m=math.nan)

    if waiting and s.state in ("drive", "yield"):
        edge = crossing.distance_m - config.crossing_margin_m if crossing is not None else (
            min(p.distance_m for p in waiting) - config.person_clearance_m)
        stop_at = odometer + edge - config.front_m
        if s.state == "drive" or stop_at < s.stop_at_m:  # a crossing seen nearer than the person: stop there
            s = replace(s, state="yield", stop_at_m=stop_at)
        s = replace(s, clear_for_s=0.0)
    elif s.state == "yield" and car is not None and car.distance_m <= s.stop_at_m - odometer + config.front_m + \
            config.person_clearance_m + config.passing.car_length_m:
        s = replace(s, state="drive", stop_at_m=math.nan, clear_for_s=0.0)  # the people were the car: its rule now
    elif s.state == "yield":
        s = replace(s, clear_for_s=s.clear_for_s + dt_s)
        if s.clear_for_s >= config.clear_s:
            return BehaviourDecision(cruise, "drive", "crossing clear: go on"), replace(
                s, state="drive", stop_at_m=math.nan)

    if car is not None and car.distance_m <= config.car_range_m and s.state in ("drive", "wait_car"):
        path = plan_overtake(car.distance_m, config.passing) if config.overtake and s.state == "drive" else None
        if path is not None:
            s = replace(s, state="overtake", manoeuvre_end_m=odometer + float(path.s_m[-1]), manoeuvre_start_m=odometer,
                        car_distance_m=car.distance_m, car_length_m=config.passing.car_length_m)
            return BehaviourDecision(cruise, "overtake", f"car in the lane {car.distance_m:.1f} m ahead: "
                                     "overtaking", path=path), s
        stop_at = odometer + car.distance_m - config.front_m - config.car_gap_m
        s = replace(s, state="wait_car", stop_at_m=min(stop_at, s.stop_at_m) if s.state == "wait_car" else stop_at,
                    clear_for_s=0.0)
    elif s.state == "wait_car":
        s = replace(s, clear_for_s=s.clear_for_s + dt_s)
        if s.clear_for_s >= config.clear_s:
            return BehaviourDecision(cruise, "drive", "lane clear: go on"), replace(s, state="drive",
                                                                                  stop_at_m=math.nan)

    if s.state in ("stop_red", "wait_red", "yield", "wait_car"):
        remaining = s.stop_at_m - odometer
        cap = min(cruise, stopping_speed(remaining, config.decel_mps2, config.brake_delay_s))
        name: State = s.state
        if s.state == "stop_red" and speed_mps <= config.stopped_mps and remaining < 2.0:
            name = "wait_red"
            s = replace(s, state="wait_red")
        reason = {"stop_red": "red light: stopping before the line", "wait_red": "red light: waiting for green",
                  "yield": "pedestrian at the crossing: waiting", "wait_car": "car in the lane: waiting"}[name]
        return BehaviourDecision(cap, name, reason, remaining), s
    return BehaviourDecision(cruise, "drive", f"limit {s.limit_kmh:g} km/h"), s

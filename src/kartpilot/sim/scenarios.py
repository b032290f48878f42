"""The event's scenarios on the venue track, with seeds that vary them, and a referee that scores as the event does.

Each scenario puts its props on ``lelystad`` (the venue modelled on the real kart's frames) and says what the
referee watches; a seed moves the props, changes the light's timing and the pedestrian's walk (and, through the
simulator's seed, the textures and the camera's noise). Four of the 2024 event's six are here:

- ``start-on-green``: the kart stands at the start before a red light; fault: it moved before green.
- ``speed-limit``: a 10 km/h sign after the start (the event's limits are 10, 15 and 20 km/h); fault: faster than
  the limit past the sign (by how much, for how long), beyond ``tolerance_kmh`` held for ``tolerance_s``.
- ``red-light``: a red light at the stop line that turns green a while after the kart arrives; faults: passed the
  line on red, stopped with its front more than 1.5 m or less than 0.2 m before the line, or never stopped.
- ``pedestrian``: a person beside the zebra crossing walks across as the kart comes; fault: moved within 3 m of the
  crossing while the person was on the road, or never went on.

Overtaking the inflatable car and parking between barriers need planned paths and are not here yet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from kartpilot.core.errors import ConfigError
from kartpilot.sim.track import Prop, Track

__all__ = ["SCENARIOS", "Scenario", "ScenarioReferee", "scenario"]

SCENARIOS = ("start-on-green", "speed-limit", "red-light", "pedestrian")


@dataclass(frozen=True)
class Scenario:
    """One scenario on one seed: its props, how long it runs, what the kart is told and where the referee looks."""

    name: str
    seed: int
    props: tuple[Prop, ...]
    duration_s: float
    start_on_green: bool = False
    limit_kmh: float = 20.0
    marks: dict[str, float] = field(default_factory=dict)  # where on the route the referee looks (metres)


def scenario(name: str, seed: int) -> Scenario:
    """The scenario ``name`` as seed ``seed`` lays it out on ``lelystad`` (start at 5 m, the stop line at 30 m,
    the zebra at 146 m)."""
    rng = np.random.default_rng(seed)
    if name == "start-on-green":
        green_at = float(rng.uniform(2.0, 6.0))
        light = Prop(kind="traffic_light", s_m=float(rng.uniform(14.0, 22.0)), offset_m=-2.5,
                     phases=(("red", green_at), ("green", 1e6)))
        return Scenario(name, seed, (light,), green_at + 8.0, start_on_green=True, marks={"green_at_s": green_at})
    if name == "speed-limit":
        sign_s = float(rng.uniform(18.0, 26.0))
        sign = Prop(kind="speed_sign", s_m=sign_s, offset_m=-2.3, value_kmh=10)
        return Scenario(name, seed, (sign,), 24.0, limit_kmh=20.0, marks={"sign_s": sign_s, "limit_kmh": 10.0})
    if name == "red-light":
        red_for = float(rng.uniform(12.0, 16.0))
        light = Prop(kind="traffic_light", s_m=float(rng.uniform(34.0, 38.0)), offset_m=-2.5,
                     phases=(("red", red_for), ("green", 1e6)))
        return Scenario(name, seed, (light,), red_for + 6.0, marks={"line_s": 30.0, "green_at_s": red_for})
    if name == "pedestrian":
        start = float(rng.uniform(4.0, 8.0))
        walk = float(rng.uniform(0.8, 1.3))
        person = Prop(kind="person", s_m=147.5, offset_m=-2.6, walk_to_offset_m=2.6, walk_start_s=start,
                      walk_speed_mps=walk)
        return Scenario(name, seed, (person,), start + 5.2 / walk + 12.0,
                        marks={"zebra_s": 146.0, "start_s": 128.0, "on_road_from_s": start + 1.1 / walk,
                               "on_road_until_s": start + 4.1 / walk})
    raise ConfigError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})")


@dataclass
class ScenarioReferee:
    """Watches each step (the time, where the kart's front is along the route, its speed) and lists the faults
    the event would count."""

    scenario: Scenario
    tolerance_kmh: float = 1.0
    tolerance_s: float = 0.5
    faults: list[str] = field(default_factory=list)
    _over_s: float = 0.0
    _worst_kmh: float = 0.0
    _stopped_gap: float = math.nan
    _start_front: float = math.nan

    def step(self, time_s: float, front_s_m: float, speed_mps: float, dt_s: float) -> None:
        s, marks = self.scenario, self.scenario.marks
        if math.isnan(self._start_front):
            self._start_front = front_s_m
        if s.name == "start-on-green" and time_s < marks["green_at_s"] and front_s_m - self._start_front > 0.2:
            self._fault(f"left before green ({front_s_m - self._start_front:.1f} m at {time_s:.1f} s)")
        if s.name == "speed-limit" and front_s_m > marks["sign_s"] + 1.5:
            over = speed_mps * 3.6 - marks["limit_kmh"]
            if over > self.tolerance_kmh:
                self._over_s += dt_s
                self._worst_kmh = max(self._worst_kmh, over)
        if s.name == "red-light":
            line = marks["line_s"]
            if time_s < marks["green_at_s"]:
                if front_s_m > line:
                    self._fault(f"passed the line on red at {time_s:.1f} s")
                if speed_mps < 0.05 and front_s_m > line - 3.0:
                    self._stopped_gap = line - front_s_m
        if s.name == "pedestrian":
            near = marks["zebra_s"] - 3.0 <= front_s_m <= marks["zebra_s"]
            if marks["on_road_from_s"] <= time_s <= marks["on_road_until_s"] and near and speed_mps > 0.1:
                self._fault(f"moved at the crossing while the pedestrian was on the road ({time_s:.1f} s)")

    def _fault(self, text: str) -> None:
        kind = text.split(" (")[0].split(" at ")[0]
        if not any(f.startswith(kind) for f in self.faults):
            self.faults.append(text)

    def result(self, front_s_m: float) -> dict[str, Any]:
        s, marks = self.scenario, self.scenario.marks
        faults = list(self.faults)
        if s.name == "speed-limit" and self._over_s > self.tolerance_s:
            faults.append(f"over the limit by up to {self._worst_kmh:.1f} km/h for {self._over_s:.1f} s")
        if s.name == "red-light":
            if math.isnan(self._stopped_gap):
                faults.append("did not stop at the red light")
            elif not 0.2 <= self._stopped_gap <= 1.5:
                faults.append(f"stopped {self._stopped_gap:.2f} m before the line (0.2 to 1.5 m wanted)")
            if front_s_m < marks["line_s"] + 2.0:
                faults.append("did not go on at green")
        if s.name == "start-on-green" and front_s_m - self._start_front < 2.0:
            faults.append("did not start on green")
        if s.name == "pedestrian" and front_s_m < marks["zebra_s"] + 3.0:
            faults.append("did not go on after the pedestrian had crossed")
        out: dict[str, Any] = {"name": s.name, "seed": s.seed, "passed": not faults, "faults": faults}
        if s.name == "red-light" and math.isfinite(self._stopped_gap):
            out["stopped_before_line_m"] = round(self._stopped_gap, 3)
        return out


def start_pose_s(track: Track, scenario: Scenario) -> float:
    """Where along the route the scenario starts."""
    return scenario.marks.get("start_s", track.spec.start_s_m)

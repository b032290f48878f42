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
- ``overtake``: the inflatable car stands in the lane on the stretch where the left line is a two-lane road's
  dashed centre line; the kart may cross that line (not a solid one); faults: touched the car, did not pass it,
  did not return to its lane.
- ``parking``: a bay beside the road on the right, between two red-and-white barriers, where the right line is
  dashed (the bay's entry); the kart parks forward in it; faults: touched a barrier, did not end stopped wholly
  inside the bay.
- ``event``: all six in a row on one drive (:func:`_event`), judged by every rule above.

A scenario is also a YAML file (:func:`load_scenario_file`, documented in ``docs/scenarios.md``): the track, where
the kart starts, what it is told, each prop, barrier and dashed stretch; the referee's marks are derived from them
(:func:`derive_marks`) unless the file gives its own. :func:`write_scenario_file` writes any scenario, a seeded
built-in one included, as the file that reproduces it exactly.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from kartpilot.core.config import config_to_dict, load_yaml_mapping, merge_config
from kartpilot.core.errors import ConfigError
from kartpilot.core.files import write_text_atomic
from kartpilot.sim.render import RenderConfig
from kartpilot.sim.simulator import CameraEffectsConfig
from kartpilot.sim.track import PROP_SIZES_M, BarrierBlock, Dashed, Prop, Track, TrackSpec, build_track, load_track_spec

__all__ = ["MARKS", "SCENARIOS", "Scenario", "ScenarioReferee", "check_scenario", "derive_marks", "footprints_touch",
           "load_scenario_file", "scenario", "scenario_or_file", "scenario_text", "write_scenario_file"]

SCENARIOS = ("start-on-green", "speed-limit", "red-light", "pedestrian", "overtake", "parking", "event")


@dataclass(frozen=True)
class Scenario:
    """One scenario on one seed: its props, how long it runs, what the kart is told and where the referee looks."""

    name: str
    seed: int
    props: tuple[Prop, ...]
    duration_s: float
    start_on_green: bool = False
    limit_kmh: float = 20.0
    overtake: bool = False
    park: bool = False
    park_after_m: float = 0.0
    laps: int = 1  # the track referee's laps (the drive ends at their finish)
    barriers: tuple[BarrierBlock, ...] = ()  # added to the track's own
    dashed: tuple[Dashed, ...] = ()
    marks: dict[str, float] = field(default_factory=dict)  # where on the route the referee looks (metres)
    track: str = "lelystad"
    render: RenderConfig = field(default_factory=RenderConfig)  # the sky, the sun, trees and shadows
    effects: CameraEffectsConfig = field(default_factory=CameraEffectsConfig)  # the camera, its mount

    @property
    def kinds(self) -> list[str]:
        """The kinds of object the scenario holds: its props' kinds, and ``barrier`` for a bay's."""
        return sorted({p.kind for p in self.props} | ({"barrier"} if self.barriers else set()))


MARKS = {
    "start_s": "where along the route the kart starts, m (default: the track's start)",
    "start_green_at_s": "the start light turns green at this time; moving before it is a fault",
    "line_s": "the stop line the kart must stop before at red, m along the route",
    "red_from_s": "the line's light is red from this time (default 0) ...",
    "red_until_s": "... until this time",
    "sign_s": "a speed limit applies from 1.5 m past this sign, m",
    "limit_kmh": "... this limit",
    "limit_until_s": "... until this point, m (the next sign)",
    "zebra_s": "the zebra crossing: no moving within 3 m before it while a person is on the road, m",
    "car_s": "the car to overtake, m",
    "back_by_s": "the kart is back in its lane (within 0.5 m of its centre) by here, m",
    "bay_s": "the parking bay's start along the route, m",
    "bay_end_s": "its end, m",
    "outer_m": "its outer edge beyond the right line, m",
}
"""The referee's marks a scenario file may give (each derived from the props when it does not)."""


def scenario(name: str, seed: int) -> Scenario:
    """The scenario ``name`` as seed ``seed`` lays it out on ``lelystad`` (start at 5 m, the stop line at 30 m,
    the zebra at 146 m, the dashed stretch 176 to 212 m, a loop of about 277 m)."""
    rng = np.random.default_rng(seed)
    if name == "start-on-green":
        green_at = float(rng.uniform(2.0, 6.0))
        light = Prop(kind="traffic_light", s_m=float(rng.uniform(14.0, 22.0)), offset_m=-2.5,
                     phases=(("red", green_at), ("green", 1e6)))
        return Scenario(name, seed, (light,), green_at + 8.0, start_on_green=True,
                        marks={"start_green_at_s": green_at})
    if name == "speed-limit":
        sign_s = float(rng.uniform(18.0, 26.0))
        sign = Prop(kind="speed_sign", s_m=sign_s, offset_m=-2.3, value_kmh=10)
        return Scenario(name, seed, (sign,), 24.0, limit_kmh=20.0, marks={"sign_s": sign_s, "limit_kmh": 10.0})
    if name == "red-light":
        red_for = float(rng.uniform(12.0, 16.0))
        light = Prop(kind="traffic_light", s_m=float(rng.uniform(34.0, 38.0)), offset_m=-2.5,
                     phases=(("red", red_for), ("green", 1e6)))
        return Scenario(name, seed, (light,), red_for + 6.0, marks={"line_s": 30.0, "red_until_s": red_for})
    if name == "pedestrian":
        start = float(rng.uniform(4.0, 8.0))
        walk = float(rng.uniform(0.8, 1.3))
        person = Prop(kind="person", s_m=147.5, offset_m=-2.6, walk_to_offset_m=2.6, walk_start_s=start,
                      walk_speed_mps=walk)
        return Scenario(name, seed, (person,), start + 5.2 / walk + 12.0, marks={"zebra_s": 146.0, "start_s": 128.0})
    if name == "overtake":
        car_s = float(rng.uniform(190.0, 195.0))  # on lelystad's dashed stretch (176 to 212 m)
        car = Prop(kind="car", s_m=car_s, offset_m=float(rng.uniform(-0.2, 0.2)))
        return Scenario(name, seed, (car,), 20.0, overtake=True,
                        marks={"car_s": car_s, "start_s": 165.0, "back_by_s": car_s + 22.0})
    if name == "parking":
        barriers, dashed, marks = _bay(rng, 0.0)
        return Scenario(name, seed, (), 22.0, park=True, barriers=barriers, dashed=dashed, marks=marks)
    if name == "event":
        return _event(rng, seed)
    raise ConfigError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})")


def _bay(rng: np.random.Generator, lap_m: float) -> tuple[tuple[BarrierBlock, ...], tuple[Dashed, ...],
                                                          dict[str, float]]:
    """A parking bay beyond the right line between two barriers across its ends, 1.5 m wide (a kart's bay), the
    near one's face toward the kart coming; the right line dashed along it (its entry). ``lap_m``: added to the
    referee's marks (the bay is judged on a later lap)."""
    bay_s, free = float(rng.uniform(19.0, 22.0)), float(rng.uniform(6.5, 7.5))
    offset = float(rng.uniform(0.2, 0.4))  # the barriers' inner end beyond the right line
    barriers = (BarrierBlock(side="right", s_m=bay_s - 0.4, offset_m=offset, length_m=0.4, depth_m=1.5),
                BarrierBlock(side="right", s_m=bay_s + free, offset_m=offset, length_m=0.4, depth_m=1.5))
    dashed = (Dashed(side="right", from_s_m=bay_s - 6.0, to_s_m=bay_s + free + 1.0, dash_m=1.0, gap_m=1.0),)
    return barriers, dashed, {"bay_s": bay_s + lap_m, "bay_end_s": bay_s + free + lap_m, "outer_m": offset + 1.8}


EVENT_LAP_M = 277.08
"""lelystad's loop, metres: the event course parks on its second lap."""


def _event(rng: np.random.Generator, seed: int) -> Scenario:
    """All six in a row on one drive, as the event's final runs them: start on green at the light 6 m before the
    stop line (beside the parking bay), which turns red again as the kart comes (stop before the line, go on
    green); a 10 km/h sign after
    the S-bend and a 20 km/h one after the hairpin; a pedestrian crossing the zebra back and forth (standing a
    while at each side); the car on the dashed stretch; the parking bay on the first straight, parked in on the
    second lap (the kart is told to park only after ``park_after_m``)."""
    green_at = float(rng.uniform(2.0, 5.0))
    red_for = float(rng.uniform(10.0, 14.0))
    light = Prop(kind="traffic_light", s_m=float(rng.uniform(34.0, 38.0)), offset_m=-2.5,
                 phases=(("red", green_at), ("green", 2.0), ("red", red_for), ("green", 1e6)))
    sign_s, sign2_s = float(rng.uniform(60.0, 66.0)), float(rng.uniform(118.0, 124.0))
    signs = (Prop(kind="speed_sign", s_m=sign_s, offset_m=-2.3, value_kmh=10),
             Prop(kind="speed_sign", s_m=sign2_s, offset_m=-2.3, value_kmh=20))
    walk = float(rng.uniform(0.8, 1.3))
    person = Prop(kind="person", s_m=147.5, offset_m=-2.6, walk_to_offset_m=2.6,
                  walk_start_s=float(rng.uniform(0.0, 20.0)), walk_speed_mps=walk, walk_pause_s=20.0)
    car_s = float(rng.uniform(190.0, 195.0))
    car = Prop(kind="car", s_m=car_s, offset_m=float(rng.uniform(-0.2, 0.2)))
    barriers, dashed, bay = _bay(rng, EVENT_LAP_M)
    marks = {"start_s": 22.0, "start_green_at_s": green_at, "line_s": 30.0, "red_from_s": green_at + 2.0,
             "red_until_s": green_at + 2.0 + red_for, "sign_s": sign_s, "limit_kmh": 10.0, "limit_until_s": sign2_s,
             "zebra_s": 146.0, "car_s": car_s, "back_by_s": car_s + 22.0, **bay}
    return Scenario("event", seed, (light, *signs, person, car), 240.0, start_on_green=True, overtake=True,
                    park=True, park_after_m=EVENT_LAP_M - 20.0, laps=2, barriers=barriers, dashed=dashed,
                    marks=marks)


@dataclass
class ScenarioReferee:
    """Watches each step (the time, where the kart's front is along the route, its speed) and lists the faults
    the event would count: each rule where the scenario's marks say its object is (so the ``event`` course, which
    holds them all, is judged by all)."""

    scenario: Scenario
    tolerance_kmh: float = 1.0
    tolerance_s: float = 0.5
    faults: list[str] = field(default_factory=list)
    _over_s: float = 0.0
    _worst_kmh: float = 0.0
    _stopped_gap: float = math.nan
    _start_front: float = math.nan
    _offset_m: float = 0.0
    _speed_mps: float = 0.0
    _footprint: np.ndarray | None = None
    _back_offset_m: float = math.nan

    def step(self, time_s: float, front_s_m: float, speed_mps: float, dt_s: float, touching: str = "",
             offset_m: float = 0.0, footprint: np.ndarray | None = None) -> None:
        """``front_s_m``: the kart's front along the route from its start, laps counted; ``touching``: the prop
        or barrier the kart's footprint touches now, if any; ``offset_m``: the kart's middle from its lane's
        centre (left positive); ``footprint``: its corners as (metres along the route as ``front_s_m``, metres
        left of its centre)."""
        marks = self.scenario.marks
        self._offset_m, self._speed_mps = offset_m, speed_mps
        if footprint is not None:
            self._footprint = footprint
        if math.isnan(self._start_front):
            self._start_front = front_s_m
        if touching:
            self._fault(f"touched the {touching} at {time_s:.1f} s")
        if "start_green_at_s" in marks and time_s < marks["start_green_at_s"] and (
                front_s_m - self._start_front > 0.2):
            self._fault(f"left before green ({front_s_m - self._start_front:.1f} m at {time_s:.1f} s)")
        if "sign_s" in marks and marks["sign_s"] + 1.5 < front_s_m < marks.get("limit_until_s", math.inf):
            over = speed_mps * 3.6 - marks["limit_kmh"]
            if over > self.tolerance_kmh:
                self._over_s += dt_s
                self._worst_kmh = max(self._worst_kmh, over)
        if "line_s" in marks and marks.get("red_from_s", 0.0) <= time_s < marks["red_until_s"]:
            line = marks["line_s"]
            if front_s_m > line:
                self._fault(f"passed the line on red at {time_s:.1f} s")
            if speed_mps < 0.05 and front_s_m > line - 3.0:
                self._stopped_gap = line - front_s_m
        if "back_by_s" in marks and math.isnan(self._back_offset_m) and front_s_m >= marks["back_by_s"]:
            self._back_offset_m = offset_m
        if "zebra_s" in marks:
            near = marks["zebra_s"] - 3.0 <= front_s_m <= marks["zebra_s"]
            walking = any(abs(p.offset_at(time_s)) <= 1.6 for p in self.scenario.props if p.kind == "person")
            if walking and near and speed_mps > 0.1:
                self._fault(f"moved at the crossing while the pedestrian was on the road ({time_s:.1f} s)")

    def decided(self, time_s: float, front_s_m: float) -> bool:
        """Whether nothing the kart does from now on can change the verdict on the scenario's marks: it has moved
        off after the start's green, is past the line after the red, past the last sign's stretch, past the zebra,
        back in its lane where the car was passed. Never for a bay (the drive ends when the kart has parked), for
        a limit that holds to the drive's end, or for a scenario without marks. A fault already counted stays."""
        marks = self.scenario.marks
        if (not marks.keys() & {"start_green_at_s", "line_s", "sign_s", "zebra_s", "car_s"} or "bay_s" in marks
                or math.isnan(front_s_m)):
            return False
        short = self._short_of(front_s_m)
        settled = [
            "start_green_at_s" not in marks or (time_s >= marks["start_green_at_s"] and not short["start_green_at_s"]),
            "line_s" not in marks or (time_s >= marks["red_until_s"] and not short["line_s"]),
            "sign_s" not in marks or front_s_m >= marks.get("limit_until_s", math.inf),
            "zebra_s" not in marks or not short["zebra_s"],
            "car_s" not in marks or (not math.isnan(self._back_offset_m) and not short["car_s"]),
        ]
        return all(settled)

    def _short_of(self, front_s_m: float) -> dict[str, bool]:
        """For each mark the kart must drive on past (where the scenario has it), whether its front is still short
        of where the event counts it as gone on: 2 m from where it started, 2 m past the stop line, 3 m past the
        zebra, 2 m past the car's back. The verdict's "did not ..." faults and :meth:`decided` both ask here."""
        marks, out = self.scenario.marks, {}
        if "start_green_at_s" in marks:
            out["start_green_at_s"] = front_s_m - self._start_front < 2.0
        if "line_s" in marks:
            out["line_s"] = front_s_m < marks["line_s"] + 2.0
        if "zebra_s" in marks:
            out["zebra_s"] = front_s_m < marks["zebra_s"] + 3.0
        if "car_s" in marks:
            out["car_s"] = front_s_m < marks["car_s"] + PROP_SIZES_M["car"][1] / 2 + 2.0
        return out

    def _fault(self, text: str) -> None:
        kind = text.split(" (")[0].split(" at ")[0]
        if not any(f.startswith(kind) for f in self.faults):
            self.faults.append(text)

    def result(self, front_s_m: float) -> dict[str, Any]:
        s, marks = self.scenario, self.scenario.marks
        faults = list(self.faults)
        short = self._short_of(front_s_m)
        if "sign_s" in marks and self._over_s > self.tolerance_s:
            faults.append(f"over the limit by up to {self._worst_kmh:.1f} km/h for {self._over_s:.1f} s")
        if "line_s" in marks:
            if math.isnan(self._stopped_gap):
                faults.append("did not stop at the red light")
            elif not 0.2 <= self._stopped_gap <= 1.5:
                faults.append(f"stopped {self._stopped_gap:.2f} m before the line (0.2 to 1.5 m wanted)")
            if short["line_s"]:
                faults.append("did not go on at green")
        if "start_green_at_s" in marks and short["start_green_at_s"]:
            faults.append("did not start on green")
        if "zebra_s" in marks and short["zebra_s"]:
            faults.append("did not go on after the pedestrian had crossed")
        if "car_s" in marks:
            if short["car_s"]:
                faults.append("did not pass the car")
            elif math.isnan(self._back_offset_m):
                faults.append("did not get back to the lane in time")
            elif abs(self._back_offset_m) > 0.5:
                faults.append(f"did not return to the lane ({self._back_offset_m:.1f} m from its centre "
                              f"{marks['back_by_s'] - marks['car_s']:.0f} m past the car)")
        if "bay_s" in marks:
            half = 1.5  # lelystad's half width
            f = self._footprint
            inside = f is not None and bool(
                np.all((f[:, 0] >= marks["bay_s"]) & (f[:, 0] <= marks["bay_end_s"])
                       & (f[:, 1] <= -half) & (f[:, 1] >= -(half + marks["outer_m"]))))
            if not inside:
                faults.append("did not end wholly inside the bay")
            elif self._speed_mps > 0.1:
                faults.append("did not stop in the bay")
        out: dict[str, Any] = {"name": s.name, "seed": s.seed, "passed": not faults, "faults": faults}
        if "line_s" in marks and math.isfinite(self._stopped_gap):
            out["stopped_before_line_m"] = round(self._stopped_gap, 3)
        return out


def start_pose_s(track: Track, scenario: Scenario) -> float:
    """Where along the route the scenario starts."""
    return scenario.marks.get("start_s", track.spec.start_s_m)


def footprints_touch(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two convex footprints (corners in order, (N, 2), metres) overlap: no edge of either separates
    them (the separating axis test)."""
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        for normal in np.column_stack([-edges[:, 1], edges[:, 0]]):
            pa, pb = a @ normal, b @ normal
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


# --- scenario files ---------------------------------------------------------------------------------------------

def _blank(name: str) -> Scenario:
    return Scenario(name, 1, (), 60.0)


_ALWAYS = {"traffic_light": ("kind", "s_m", "offset_m", "phases"),
           "speed_sign": ("kind", "s_m", "offset_m", "value_kmh"), "person": ("kind", "s_m", "offset_m"),
           "car": ("kind", "s_m", "offset_m"),
           "barriers": ("side", "s_m", "offset_m"), "dashed": ("side", "from_s_m", "to_s_m")}
"""What a written scenario file keeps of each object even where it is the default (the rest: only what differs)."""


def load_scenario_file(path: str | Path) -> Scenario:
    """A scenario from its YAML file: every key checked (an unknown key, a wrong type, a prop off the track, a
    light whose phases do not add up: one error naming it), the referee's marks derived from the props, and the
    file's own ``marks`` over them."""
    path = Path(path)
    mapping = dict(load_yaml_mapping(path))
    if not mapping:  # a file cut off or the wrong one, not a course: it would drive the defaults for a minute
        raise ConfigError(f"the scenario file {path} holds no keys (it is empty, or comments only): a scenario "
                          "gives at least its track (docs/scenarios.md)")
    marks = mapping.pop("marks", None)
    plan = merge_config(_blank(path.stem), mapping, "scenario")
    if marks is not None:
        if not isinstance(marks, dict):
            raise ConfigError("config key 'scenario.marks' must be a mapping")
        for key, value in marks.items():
            if key not in MARKS:
                raise ConfigError(f"unknown config key 'scenario.marks.{key}' (known here: {', '.join(MARKS)})")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"config key 'scenario.marks.{key}' must be a finite number, got {value!r}")
    spec = load_track_spec(plan.track)
    given = {k: float(v) for k, v in (marks or {}).items()}
    plan = replace(plan, marks={**derive_marks(replace(plan, marks=given), spec), **given})
    check_scenario(plan, spec)
    return plan


def scenario_text(plan: Scenario) -> str:
    """``plan`` as the YAML text that :func:`load_scenario_file` reads back to the same scenario."""
    full = config_to_dict(plan)
    defaults = {"props": config_to_dict(Prop()), "barriers": config_to_dict(BarrierBlock()),
                "dashed": config_to_dict(Dashed())}
    for key, default in defaults.items():  # each object with what is its own (a light's phases, a person's walk)
        full[key] = [{k: v for k, v in item.items() if v != default[k] or k in _ALWAYS.get(item.get("kind", key), ())}
                     for item in full[key]]
    # the world as far as it is not the default; the camera whole, so that a file reproduces its event whatever the
    # camera's defaults become (they changed once: the perfect pinhole until the kart's real camera)
    world = config_to_dict(RenderConfig())
    full["render"] = {k: v for k, v in full["render"].items() if v != world[k]}
    data = {"name": plan.name, "seed": plan.seed, "track": plan.track,
            **{k: v for k, v in full.items() if k not in ("name", "seed", "track", "marks") and v != {}},
            "marks": {k: float(v) for k, v in plan.marks.items()}}
    header = f"# kartpilot scenario {plan.name!r} (seed {plan.seed}): kartpilot sim --scenario THIS_FILE\n"
    return header + yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


def write_scenario_file(path: str | Path, plan: Scenario) -> Path:
    """:func:`scenario_text` written whole or not at all."""
    return write_text_atomic(Path(path), scenario_text(plan))


def scenario_or_file(name_or_path: str, seed: int | None = None) -> Scenario:
    """A built-in scenario by name (on ``seed``, 1 by default), or a scenario file by path (``seed``, if given, sets
    the simulator's seed: its textures and noise, not the props)."""
    if name_or_path in SCENARIOS:
        return scenario(name_or_path, 1 if seed is None else seed)
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        raise ConfigError(f"unknown scenario {name_or_path!r}: give one of {', '.join(SCENARIOS)} or a scenario "
                          "file (.yaml)")
    plan = load_scenario_file(path)
    return plan if seed is None else replace(plan, seed=seed)


def derive_marks(plan: Scenario, spec: TrackSpec) -> dict[str, float]:
    """Where the referee looks, from the props and the track: the start light (the first light ahead of the start
    when the kart is told to start on green: its first red), the stop line before a light (the track's stop line
    up to 10 m before it: the light's next red), the zebra nearest a person, the car, the parking bay between the
    first two barriers on the right (judged on the lap the kart is told to park on), one speed limit (the first
    sign's, until the next); where the kart starts is ``plan.marks['start_s']``, if given. A file that wants
    otherwise gives its own ``marks``."""
    marks = {"start_s": plan.marks["start_s"]} if "start_s" in plan.marks else {}
    lights = sorted((p for p in plan.props if p.kind == "traffic_light"), key=lambda p: p.s_m)
    reds_used = 0
    if plan.start_on_green and lights and lights[0].phases[0][0] == "red":
        marks["start_green_at_s"] = lights[0].phases[0][1]
        reds_used = 1
    lines = [m.s_m for m in spec.road_marks if m.kind == "stop_line"]
    for light in lights:
        line = [s for s in lines if 0.0 <= light.s_m - s <= 10.0]
        if not line:
            continue
        windows, t = [], 0.0
        for colour, seconds in light.phases:
            if colour == "red":
                windows.append((t, t + seconds))
            t += seconds
        windows = windows[reds_used if light is lights[0] else 0:]
        if windows:
            marks["line_s"] = max(line)
            if windows[0][0] > 0:
                marks["red_from_s"] = windows[0][0]
            marks["red_until_s"] = windows[0][1]
        break
    signs = sorted((p for p in plan.props if p.kind == "speed_sign"), key=lambda p: p.s_m)
    if signs:
        marks["sign_s"], marks["limit_kmh"] = signs[0].s_m, float(signs[0].value_kmh)
        if len(signs) > 1:
            marks["limit_until_s"] = signs[1].s_m
    zebras = [m.s_m for m in spec.road_marks if m.kind == "zebra"]
    for person in (p for p in plan.props if p.kind == "person"):
        if zebras:
            marks["zebra_s"] = min(zebras, key=lambda z: abs(z - person.s_m))
            break
    cars = [p for p in plan.props if p.kind == "car"]
    if cars and plan.overtake:
        marks["car_s"] = cars[0].s_m
        marks["back_by_s"] = cars[0].s_m + 22.0
    right = sorted((b for b in plan.barriers if b.side == "right"), key=lambda b: b.s_m)
    if plan.park and len(right) >= 2:
        lap = 0.0
        if spec.centerline.closed and plan.park_after_m > right[0].s_m:
            loop = build_track(spec).route.length_m
            lap = loop * math.ceil((plan.park_after_m - right[0].s_m) / loop)
        marks.update(bay_s=right[0].s_m + right[0].length_m + lap, bay_end_s=right[1].s_m + lap,
                     outer_m=right[0].offset_m + right[0].depth_m + 0.3)
    return marks


def check_scenario(plan: Scenario, spec: TrackSpec) -> None:
    """One clear error for what no event could hold: a prop off the track, a light whose phases do not alternate
    or are never all seen, a car off the road, a time or lap that is not positive."""
    if not (plan.duration_s > 0 and plan.laps >= 1):
        raise ConfigError("scenario: duration_s must be positive and laps at least 1")
    track = build_track(spec)
    length = track.route.length_m
    for i, prop in enumerate(plan.props):
        where = f"scenario.props[{i}] ({prop.kind})"
        if not (0.0 <= prop.s_m < length):
            raise ConfigError(f"{where}: s_m {prop.s_m:g} is off the track ({plan.track} is {length:.0f} m long)")
        half = float(track.route.half_width_m[track.route.index_at(prop.s_m)])
        reach = half if prop.kind == "car" else half + 8.0
        if abs(prop.offset_m) > reach or (prop.kind == "person" and abs(prop.walk_to_offset_m) > half + 8.0):
            place = "on the road" if prop.kind == "car" else "within 8 m of the road"
            raise ConfigError(f"{where}: offset_m {prop.offset_m:g} is off the track (a {prop.kind} stands "
                              f"{place}: at most {reach:.1f} m from the centre line here)")
        if prop.kind == "traffic_light":
            colours = [colour for colour, _ in prop.phases]
            if any(a == b for a, b in itertools.pairwise(colours)):
                raise ConfigError(f"{where}: the phases do not add up: {colours} (red and green take turns)")
            if sum(seconds for _, seconds in prop.phases[:-1]) >= plan.duration_s:
                raise ConfigError(f"{where}: the phases do not add up: the last ({colours[-1]}) starts after "
                                  f"{sum(seconds for _, seconds in prop.phases[:-1]):g} s, beyond the scenario's "
                                  f"{plan.duration_s:g} s")
    for i, block in enumerate(plan.barriers):
        if not 0.0 <= block.s_m < length:
            raise ConfigError(f"scenario.barriers[{i}]: s_m {block.s_m:g} is off the track ({length:.0f} m long)")
    start = plan.marks.get("start_s", spec.start_s_m)
    if not 0.0 <= start < length:
        raise ConfigError(f"scenario.marks.start_s {start:g} is off the track ({length:.0f} m long)")

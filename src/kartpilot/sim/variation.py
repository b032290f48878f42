"""The day as the organiser and the weather set it: named ranges a scenario is varied over, drawn from a seed.

A built-in scenario's seed moves its props within narrow ranges on an overcast day, through a perfect camera
exactly where the rig says. :func:`vary` redraws what the day may change, each from its own named range of
:class:`DayRanges` (a range of one value fixes it; a share of 0 turns a choice off): the sky and the sun (its
elevation through the hour, its direction, roadside trees and poles whose shadows cross the lane), the camera (its
mount off in pitch, roll and height, its exposure, noise and motion blur, frames dropped), and the props (the light
and the signs on either side, the signs' values, the pedestrian from either side at any walking pace). The result
is an ordinary :class:`~kartpilot.sim.scenarios.Scenario`, so a drawn event is written as the file that reproduces
it exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from kartpilot.core.errors import ConfigError
from kartpilot.sim.scenarios import Scenario, derive_marks
from kartpilot.sim.track import Prop, load_track_spec

__all__ = ["DayRanges", "vary"]

Span = tuple[float, float]


@dataclass(frozen=True)
class DayRanges:
    """What the day may change, each drawn uniformly from its range (``(low, high)``) or by its share.

    Attributes:
        sun_share: the share of events under a clear sky with hard shadows (the rest overcast, as the venue's
            frames are).
        time_of_day_h, sun_azimuth_deg: the sun's hour (its elevation) and direction, on a clear day.
        trees_spacing_m: roadside trees and poles about this far apart (their shadows cross the lane in the sun).
        mount_pitch_deg, mount_roll_deg, mount_height_m: the cameras off from where the rig says.
        exposure_gain: the camera's exposure, darker (< 1) or brighter (> 1) than the renderer's.
        noise_sigma: the sensor's noise, grey levels.
        blur_share: the share of events whose camera blurs over its 8 ms exposure.
        drop_probability: a camera's frame lost now and then.
        light_left_share, sign_left_share: the share of lights and signs standing on the left of the road. A
            light on the left is 0 by default: the event has put it on the right, and the rules count a light on
            the right only (``lane_policy``'s detector); widen it to test a light on the left.
        sign_values_kmh: a speed sign's value, drawn from these.
        person_left_share: the share of pedestrians who start on the left.
        walk_speed_mps: a pedestrian's pace.
    """

    sun_share: float = 0.5
    time_of_day_h: Span = (8.0, 18.0)
    sun_azimuth_deg: Span = (0.0, 360.0)
    trees_spacing_m: Span = (8.0, 25.0)
    mount_pitch_deg: Span = (-1.5, 1.5)
    mount_roll_deg: Span = (-1.5, 1.5)
    mount_height_m: Span = (-0.03, 0.03)
    exposure_gain: Span = (0.75, 1.3)
    noise_sigma: Span = (1.0, 4.0)
    blur_share: float = 0.5
    drop_probability: Span = (0.0, 0.03)
    light_left_share: float = 0.0
    sign_left_share: float = 0.5
    sign_values_kmh: tuple[int, ...] = (10, 15, 20)
    person_left_share: float = 0.5
    walk_speed_mps: Span = (0.6, 1.5)

    def __post_init__(self) -> None:
        for name in ("sun_share", "blur_share", "light_left_share", "sign_left_share", "person_left_share"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"variation.{name} must be a share from 0 to 1, got {getattr(self, name)}")
        for name, (low, high) in self.spans().items():
            if not (math.isfinite(low) and math.isfinite(high) and low <= high):
                raise ConfigError(f"variation.{name} must be a range (low, high) with low <= high, got "
                                  f"{(low, high)}")
        if not self.sign_values_kmh or any(v not in (10, 15, 20) for v in self.sign_values_kmh):
            raise ConfigError(f"variation.sign_values_kmh must be drawn from the event's 10, 15 and 20 km/h, got "
                              f"{self.sign_values_kmh}")
        if self.walk_speed_mps[0] <= 0 or self.drop_probability[1] > 0.5 or self.exposure_gain[0] <= 0:
            raise ConfigError("variation: walk_speed_mps and exposure_gain must be positive, drop_probability at "
                              "most 0.5")

    def spans(self) -> dict[str, Span]:
        return {name: getattr(self, name) for name in ("time_of_day_h", "sun_azimuth_deg", "trees_spacing_m",
                                                       "mount_pitch_deg", "mount_roll_deg", "mount_height_m",
                                                       "exposure_gain", "noise_sigma", "drop_probability",
                                                       "walk_speed_mps")}


def _draw(rng: np.random.Generator, span: Span) -> float:
    low, high = span
    return float(rng.uniform(low, high)) if high > low else float(low)


def _side(offset_m: float, left: bool) -> float:
    return abs(offset_m) if left else -abs(offset_m)


def vary(plan: Scenario, seed: int, ranges: DayRanges = DayRanges()) -> Scenario:
    """``plan`` as the day of event ``seed`` sets it: its world, camera and props drawn from ``ranges``, its
    referee's marks derived again from the moved props (where the kart starts kept)."""
    rng = np.random.default_rng([seed, 54])
    sunny = bool(rng.random() < ranges.sun_share)
    render = replace(plan.render, trees_spacing_m=_draw(rng, ranges.trees_spacing_m))
    hour, azimuth = _draw(rng, ranges.time_of_day_h), _draw(rng, ranges.sun_azimuth_deg)
    if sunny:
        render = replace(render, sky="clear", time_of_day_h=hour, sun_azimuth_deg=azimuth, shadows=True)
    blur = bool(rng.random() < ranges.blur_share)
    effects = replace(plan.effects, mount_pitch_deg=_draw(rng, ranges.mount_pitch_deg),
                      mount_roll_deg=_draw(rng, ranges.mount_roll_deg),
                      mount_height_m=_draw(rng, ranges.mount_height_m),
                      exposure_gain=_draw(rng, ranges.exposure_gain), noise_sigma=_draw(rng, ranges.noise_sigma),
                      exposure_blur_samples=3 if blur else 0, exposure_time_s=0.008,
                      drop_probability=_draw(rng, ranges.drop_probability))
    props: list[Prop] = []
    duration = plan.duration_s
    for prop in plan.props:
        left = rng.random()
        if prop.kind == "traffic_light":
            prop = replace(prop, offset_m=_side(prop.offset_m, left < ranges.light_left_share))
        elif prop.kind == "speed_sign":
            value = int(rng.choice(ranges.sign_values_kmh))
            prop = replace(prop, offset_m=_side(prop.offset_m, left < ranges.sign_left_share), value_kmh=value)
        elif prop.kind == "person":
            pace = _draw(rng, ranges.walk_speed_mps)
            from_left = left < ranges.person_left_share
            span = abs(prop.walk_to_offset_m - prop.offset_m)
            # slower than the built-in pace: the drive lasts the longer crossing too
            duration += max(span / pace - span / max(prop.walk_speed_mps, 1e-6), 0.0) * (
                1 if prop.walk_pause_s == 0 else 0)
            prop = replace(prop, offset_m=_side(prop.offset_m, from_left),
                           walk_to_offset_m=_side(prop.walk_to_offset_m, not from_left), walk_speed_mps=pace)
        props.append(prop)
    varied = replace(plan, props=tuple(props), render=render, effects=effects, duration_s=duration,
                     marks={"start_s": plan.marks["start_s"]} if "start_s" in plan.marks else {})
    return replace(varied, marks=derive_marks(varied, load_track_spec(plan.track)))

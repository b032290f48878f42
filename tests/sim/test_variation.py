"""The day's variation: each range drawn within its bounds, the same event from the same seed, the props moved as
drawn and the referee's marks following them, and a drawn event written as the file that reproduces it."""

import pytest

from kartpilot.core.errors import ConfigError
from kartpilot.sim.scenarios import load_scenario_file, scenario, write_scenario_file
from kartpilot.sim.variation import DayRanges, vary


def test_every_range_is_drawn_within_its_bounds_and_the_seed_decides_the_event(tmp_path):
    ranges = DayRanges()
    events = [vary(scenario(name, seed), seed, ranges) for seed in range(40)
              for name in ("red-light", "speed-limit", "pedestrian")]
    assert vary(scenario("red-light", 3), 3, ranges) == vary(scenario("red-light", 3), 3, ranges)
    assert vary(scenario("red-light", 3), 3, ranges) != vary(scenario("red-light", 3), 4, ranges)
    effects = [e.effects for e in events]
    for key in ("mount_pitch_deg", "mount_roll_deg", "mount_height_m", "exposure_gain", "noise_sigma",
                "drop_probability"):
        low, high = getattr(ranges, key)
        values = [getattr(e, key) for e in effects]
        assert all(low <= v <= high for v in values), key
        assert max(values) - min(values) > 0.5 * (high - low), key  # the whole range, not a corner of it
    sunny = [e for e in events if e.render.sky == "clear"]
    assert 0.3 < len(sunny) / len(events) < 0.7 and all(e.render.shadows for e in sunny)
    lights = [p for e in events for p in e.props if p.kind == "traffic_light"]
    signs = [p for e in events for p in e.props if p.kind == "speed_sign"]
    people = [p for e in events for p in e.props if p.kind == "person"]
    assert {p.offset_m > 0 for p in lights} == {False} and {p.offset_m > 0 for p in signs} == {True, False}
    widened = [p for seed in range(20) for p in vary(scenario("red-light", seed), seed,
                                                     DayRanges(light_left_share=0.5)).props]
    assert {p.offset_m > 0 for p in widened} == {True, False}
    assert {p.value_kmh for p in signs} == {10, 15, 20}
    assert {p.offset_m > 0 for p in people} == {True, False}
    assert all(p.offset_m * p.walk_to_offset_m < 0 for p in people)  # across the road, whichever side
    for event in events:
        for prop in event.props:
            if prop.kind == "speed_sign":
                assert event.marks["limit_kmh"] == prop.value_kmh
    event = events[7]
    assert load_scenario_file(write_scenario_file(tmp_path / "event.yaml", event)) == event


def test_a_range_that_is_no_range_is_refused_naming_it():
    with pytest.raises(ConfigError, match=r"variation\.mount_pitch_deg"):
        DayRanges(mount_pitch_deg=(1.0, -1.0))
    with pytest.raises(ConfigError, match=r"variation\.sun_share"):
        DayRanges(sun_share=1.5)
    with pytest.raises(ConfigError, match="sign_values_kmh"):
        DayRanges(sign_values_kmh=(30,))
    fixed = vary(scenario("pedestrian", 1), 1, DayRanges(sun_share=0.0, mount_pitch_deg=(0.5, 0.5),
                                                         person_left_share=1.0))
    assert fixed.render.sky != "clear" and fixed.effects.mount_pitch_deg == 0.5 and fixed.props[0].offset_m > 0

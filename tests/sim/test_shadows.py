"""The sun's hard shadows: cast along the light from the sun's place, dark by the sun's share of the light, on the
road where a tree or pole stands beside it, and none under an overcast sky."""

import math

import cv2
import numpy as np
import pytest

from kartpilot.sim.render import RenderConfig, lighting_for_time, shadow_polygons, sun_direction
from kartpilot.sim.simulator import SimConfig, Simulator
from kartpilot.sim.track import load_track, roadside_trees


def test_a_pole_s_shadow_points_away_from_the_sun_as_long_as_the_sun_is_low() -> None:
    elevation, _, _ = lighting_for_time(9.0)
    light = sun_direction(9.0, 90.0)  # the sun in the +y direction: shadows fall toward -y
    (polygon,) = shadow_polygons(np.array([[0.0, 0.0, 0.0, 0.1, 0.1, 2.0]]), np.zeros(1), light)
    length = 2.0 / math.tan(math.radians(elevation))
    assert polygon[:, 1].min() == pytest.approx(-0.05 - length, abs=1e-6)
    assert polygon[:, 1].max() == pytest.approx(0.05, abs=1e-6) and np.ptp(polygon[:, 0]) == pytest.approx(0.1)
    # a crown in the air throws its shadow away from the trunk's foot
    (crown,) = shadow_polygons(np.array([[0.0, 0.0, 0.0, 2.0, 2.0, 1.0]]), np.array([3.0]), light)
    assert crown[:, 1].max() == pytest.approx(1.0 - 3.0 / math.tan(math.radians(elevation)), abs=1e-6)
    assert shadow_polygons(np.array([[0.0, 0.0, 0.0, 1.0, 1.0, 1.0]]), np.zeros(1), np.array([0.0, 1.0, 0.0])) == []


def test_trees_stand_beside_the_road_never_on_it() -> None:
    track = load_track("lelystad")
    trees = roadside_trees(track, 10.0, 3)
    assert len(trees) > 15
    from kartpilot.sim.track import project_onto

    for x, y, trunk, _, crown in trees:
        here = project_onto(track.route, np.array([x, y]))
        assert abs(here.offset_m) - max(trunk, crown) / 2 >= here.half_width_m + 0.9


def test_the_sun_puts_shadows_on_the_road_and_an_overcast_sky_none() -> None:
    """The venue's start at 9 h with trees every 10 m: a share of the road before the kart lies in shadow, about
    as dark as the sun's share of the light; without shadows (the default), or overcast, none."""
    frames = {}
    for name, render in (("sun", RenderConfig(sky="clear", time_of_day_h=9.0, trees_spacing_m=10.0, shadows=True)),
                         ("no trees", RenderConfig(sky="clear", time_of_day_h=9.0, trees_spacing_m=10.0)),
                         ("overcast", RenderConfig(sky="overcast", time_of_day_h=9.0, trees_spacing_m=10.0,
                                                   shadows=True))):
        config = SimConfig(track="lelystad", vehicle="sdc-kart", cameras=("center",), seed=1, render=render)
        with Simulator(config) as sim:
            frame = sim.read()
        assert frame is not None
        # the asphalt's grain smoothed away: a shadow is a patch, not a pixel
        frames[name] = cv2.blur(frame.images["center"].astype(np.float32).mean(axis=2), (15, 15))
    road = (slice(300, 480), slice(200, 650))  # the lane ahead of the kart
    for name in ("no trees", "overcast"):
        assert np.mean(frames[name][road] < 0.75 * np.median(frames[name][road])) < 0.01, name
    sun = frames["sun"][road]
    shade = sun < 0.75 * np.median(frames["no trees"][road])
    ratio = float(np.median(sun[shade]) / np.median(frames["no trees"][road][shade]))
    elevation, colour, ambient = lighting_for_time(9.0)
    sunlit = float(np.mean(colour)) * math.sin(math.radians(elevation))
    print(f"\n{np.mean(shade):.0%} of the lane in shadow, {ratio:.2f} as bright "
          f"(expected {ambient / (ambient + sunlit):.2f})")
    assert np.mean(shade) > 0.1
    assert ratio == pytest.approx(ambient / (ambient + sunlit), abs=0.1)

"""The simulated planar LiDAR (issue 58) against the track's geometry: ranges within the sensor's noise, its
angular step and rate, what the scan plane does and does not hit, missing returns, and the sweep's skew."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from kartpilot.core.errors import ConfigError
from kartpilot.core.types import LidarMount
from kartpilot.sim.lidar import LidarConfig, cast_rays, near_segments, scene_segments, simulate_scan
from kartpilot.sim.track import Prop, load_track


def test_rays_meet_a_wall_where_geometry_says() -> None:
    """A wall 5 m ahead, 10 m wide: the ray straight ahead at 5 m, one at 30 deg at 5 / cos 30, one parallel to it
    and one away from it at none."""
    wall = np.array([[[5.0, -5.0], [5.0, 5.0]]])
    angles = np.radians([0.0, 30.0, 90.0, 180.0])
    distance, hit = cast_rays(np.zeros((4, 2)), np.column_stack([np.cos(angles), np.sin(angles)]), wall)
    assert distance[0] == pytest.approx(5.0) and distance[1] == pytest.approx(5.0 / math.cos(math.radians(30)))
    assert np.isinf(distance[2:]).all() and (hit == [0, 0, -1, -1]).all()


AT_AXLE = LidarMount(0.0, 0.0, 0.3)
"""A sensor over the rear axle, its plane 0.3 m up."""


def _straight_with(props: tuple[Prop, ...]):
    track = load_track("straight20")
    return replace(track, spec=replace(track.spec, props=props))


def test_a_car_ahead_is_where_the_track_put_it_within_the_sensor_s_noise() -> None:
    """A car 10 m ahead of the sensor on a straight: the beams straight ahead read the distance to its near face
    (10 m less half its length), within three of the sensor's standard deviations, at the sensor's step."""
    track = _straight_with((Prop(kind="car", s_m=14.0, offset_m=0.0),))
    config = LidarConfig(noise_m=0.01, noise_share=0.0, dropout={})
    x, y, yaw = track.start_pose()  # 2 m along: the car's centre 12 m ahead, its near face 12 - 3.8 / 2
    scan = simulate_scan(track, (x, y, yaw), 0.0, 0.0, 0.0, config, AT_AXLE, np.random.default_rng(0))
    assert len(scan.ranges_m) == 800 and scan.angle_increment_rad == pytest.approx(math.radians(0.45))
    ahead = np.abs(scan.angles_rad()) < math.radians(2.0)
    expected = 12.0 - 3.8 / 2
    print(f"ahead: {np.nanmean(scan.ranges_m[ahead]):.3f} m (geometry {expected:.3f} m)")
    assert np.all(np.abs(scan.ranges_m[ahead] - expected) < 3 * 0.01 + 0.02)  # a face seen slightly off-axis
    behind = np.abs(np.abs(scan.angles_rad()) - math.pi) < math.radians(10.0)
    assert np.all(np.isnan(scan.ranges_m[behind]))  # nothing stands behind within 12 m on a car park


def test_the_plane_hits_what_stands_above_it_and_the_cones_below_it_only_when_low() -> None:
    """straight20's cones are 0.30 m tall: a scan plane at 0.2 m sees the lane's two rows, one at 0.4 m does not."""
    track = load_track("straight20")
    low, _ = scene_segments(track, 0.0, 0.2)
    high, _ = scene_segments(track, 0.0, 0.4)
    assert len(low) == 4 * len(track.cones) and len(high) == 0
    config = LidarConfig(dropout={})
    scan = simulate_scan(track, track.start_pose(), 0.0, 0.0, 0.0, config, LidarMount(0.0, 0.0, 0.2),
                         np.random.default_rng(1))
    points = scan.points_m()
    sides = points[np.abs(points[:, 0]) < 3.0, 1]
    print(f"cone returns beside the kart: {np.sort(np.abs(sides))[:3]} m")
    assert np.all(np.abs(np.abs(sides) - 0.75) < 0.1)  # the rows 0.75 m either side of the lane's centre


def test_dark_surfaces_lose_their_share_of_returns() -> None:
    track = _straight_with((Prop(kind="person", s_m=6.0, offset_m=0.0),))
    seen = []
    for share in (0.0, 0.5):
        config = LidarConfig(dropout={"person": share})
        scans = [simulate_scan(track, track.start_pose(), 0.0, 0.0, 0.0, config, AT_AXLE, np.random.default_rng(k))
                 for k in range(20)]
        ahead = np.abs(scans[0].angles_rad()) < math.radians(3.0)
        seen.append(float(np.mean([np.isfinite(s.ranges_m[ahead]).mean() for s in scans])))
    print(f"returns from the person: {seen[0]:.2f} with no dropout, {seen[1]:.2f} with half")
    assert seen[0] == 1.0 and 0.35 < seen[1] < 0.65


def test_a_sweep_taken_while_moving_is_skewed_by_the_distance_driven() -> None:
    """At 5 m/s a 10 Hz sweep spans 0.5 m: the last beam (just short of straight behind, then round to ahead) is
    taken 0.1 s after the first; a wall ahead is read 0.5 m nearer by the beams at the sweep's end than a scan
    standing still at the sweep's start reads it."""
    track = _straight_with((Prop(kind="car", s_m=14.0, offset_m=0.0),))
    config = LidarConfig(noise_m=0.0, noise_share=0.0, dropout={})
    backwards = LidarMount(0.0, 0.0, 0.3, math.pi)
    # mounted backwards, the beam ahead of the kart is the sweep's first and last (angle -180 and +179.55)
    still = simulate_scan(track, track.start_pose(), 0.0, 0.0, 0.0, config, backwards, np.random.default_rng(0))
    moving = simulate_scan(track, track.start_pose(), 5.0, 0.0, 0.0, config, backwards, np.random.default_rng(0))
    first, last = moving.ranges_m[0], moving.ranges_m[-1]
    print(f"ahead: {still.ranges_m[0]:.3f} m standing; moving {first:.3f} m at the sweep's start, "
          f"{last:.3f} at its end")
    assert first == pytest.approx(still.ranges_m[0], abs=1e-3)
    assert first - last == pytest.approx(5.0 * 0.1 * 799 / 800, abs=0.01)


@pytest.mark.parametrize(("field", "value"), [("rate_hz", 0.0), ("step_deg", math.nan), ("range_max_m", 500.0),
                                              ("noise_m", -0.1)])
def test_a_sensor_that_cannot_be_is_refused_by_name(field: str, value: float) -> None:
    with pytest.raises(ConfigError, match=rf"lidar\.{field}"):
        LidarConfig(**{field: value})
    with pytest.raises(ConfigError, match=r"lidar\.dropout\.ghost"):
        LidarConfig(dropout={"ghost": 0.5})


def test_nothing_within_reach_is_a_sweep_without_returns() -> None:
    """A sensor in the middle of an empty car park (everything standing is farther than its range): every beam NaN,
    whatever the dropouts; the segments out of reach are not cast against, and the result is the same as when
    they are."""
    track = _straight_with((Prop(kind="car", s_m=19.9, offset_m=0.0),))
    config = LidarConfig(range_max_m=5.0)
    scan = simulate_scan(track, track.start_pose(), 0.0, 0.0, 0.0, config, AT_AXLE, np.random.default_rng(0))
    assert np.isnan(scan.ranges_m).all() and not scan.intensities.any()
    segments, _ = scene_segments(track, 0.0, 0.3)
    assert not near_segments(segments, track.start_pose()[:2], 5.0 + 1.0).any() and len(segments) == 4

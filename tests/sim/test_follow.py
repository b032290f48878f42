"""A path followed on the vehicle model alone (kartpilot.sim.follow), and the manoeuvre follower on parking's S."""

import math

import numpy as np
import pytest

from kartpilot.behaviour.manoeuvres import ParkConfig, plan_park
from kartpilot.control.path_follow import PathFollowConfig
from kartpilot.core.errors import ConfigError
from kartpilot.core.vehicle import get_vehicle
from kartpilot.planning.reference_path import PathConfig, build_reference_path
from kartpilot.runtime.lane_policy import MANOEUVRE_FOLLOW
from kartpilot.sim.follow import follow_on_model

KART = get_vehicle("sdc-kart")


def test_a_straight_path_is_followed_to_its_end_and_stopped_on():
    xy = np.column_stack([np.arange(0.0, 10.05, 0.1), np.zeros(101)])
    path = build_reference_path(xy, PathConfig(spacing_m=0.1, smoothing_m=0.0, cruise_speed_mps=2.0,
                                               stop_at_end=True))
    drive = follow_on_model(path, PathFollowConfig(), KART, 2.0, 1 / 15)
    assert drive.finished
    assert drive.max_offset_m < 1e-6 and abs(drive.end_yaw_error_rad) < 1e-6
    assert -0.3 < drive.end_short_m < 0.1  # braked at the end, within the last creep
    assert len(drive.xy_m) == len(drive.yaw_rad) > 10


def test_bad_arguments_are_refused():
    path = plan_park(12.0, 7.0, -2.4)
    with pytest.raises(ConfigError):
        follow_on_model(path, PathFollowConfig(), KART, 2.0, 0.0)


def test_the_manoeuvre_follower_ends_parking_s_along_the_bay_where_the_path_follower_ends_yawed():
    """A bay the manoeuvre follower's gains were not chosen on (benchmarks/manoeuvre_follow.py): the teach-and-repeat
    follower's look-ahead and steady-bend feed-forward end the S about 6 degrees across the bay, the manoeuvre
    follower under 2, and nearer the path all the way."""
    path = plan_park(14.0, 7.0, -2.5, ParkConfig())
    assert path is not None
    old = follow_on_model(path, PathFollowConfig(), KART, 2.0, 1 / 15)
    new = follow_on_model(path, MANOEUVRE_FOLLOW, KART, 2.0, 1 / 15)
    print(f"\nend yaw {math.degrees(old.end_yaw_error_rad):+.1f} -> {math.degrees(new.end_yaw_error_rad):+.1f} deg, "
          f"max offset {old.max_offset_m:.3f} -> {new.max_offset_m:.3f} m")
    assert old.finished and new.finished
    assert abs(math.degrees(old.end_yaw_error_rad)) > 4.0
    assert abs(math.degrees(new.end_yaw_error_rad)) < 2.0
    assert new.max_offset_m < 0.5 * old.max_offset_m
    assert abs(new.end_offset_m) < 0.1

"""Acceptance: the lane-following pipeline drives the sdc-kart on sdc-assen, closed loop, through the split."""

import pytest
from tests.conftest import track_starting_at

from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.simulator import SimConfig, perfect_camera


@pytest.mark.slow
def test_lane_following_drives_through_the_split_on_the_right_route(tmp_path):
    """The split lies between 200 and 300 m along the route (the branch leaves at 200 m, 25 m of ramp): the drive
    starts at 170 m (the track as it is, its start moved), 30 m before it on the bend that leads into it, so that the
    split is driven from a settled lane, and ends past 300 m. What the drive before it held (the first bends, from
    100 m; shortened for the suite's time, issue 52) is driven by the venue and scenario drives; the whole laps at 15
    and 30 km/h are measured by benchmarks/drive.py. 15 km/h mode; 15 Hz. Through the perfect camera: the route's
    choice is this test's, and the real camera's lane following is the venue's and the scenarios' tests' (the
    suite's time)."""
    config = SimConfig(track=track_starting_at(tmp_path, "sdc-assen", 170.0), vehicle="sdc-kart",
                       speed_mode_mps=15 / 3.6, camera_rate_hz=15.0, max_time_s=42.0, seed=1,
                       effects=perfect_camera())
    run = run_simulation(config, driver="lanes")
    result = run.result
    print(result)
    assert not result.disqualified, result.reason
    assert result.distance_m > 135.0  # past 305 m along the route: the split behind it
    # 0.97 m on this drive (2026-12-02): the split, where the road widens to the branch, is most of it now; the
    # bound is the one the longer drive had
    assert result.mean_center_offset_m < 1.0

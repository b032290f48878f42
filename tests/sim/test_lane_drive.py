"""Acceptance: the lane-following pipeline drives the sdc-kart on sdc-assen, closed loop, through the split."""

import pytest

from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.simulator import SimConfig


@pytest.mark.slow
def test_lane_following_drives_through_the_split_on_the_right_route():
    # 15 km/h mode; 15 Hz keeps the test near a minute (the full laps at 30 Hz are in the README)
    config = SimConfig(track="sdc-assen", vehicle="sdc-kart", speed_mode_mps=15 / 3.6, camera_rate_hz=15.0,
                       max_time_s=85.0, seed=1)
    run = run_simulation(config, driver="lanes")
    result = run.result
    print(result)
    assert not result.disqualified, result.reason
    # the split lies between 200 and 300 m along the route; the run starts at 20 m
    assert result.distance_m > 290.0
    assert result.mean_center_offset_m < 1.0

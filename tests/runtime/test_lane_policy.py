"""The lane policy's speed: open-loop throttle as the thesis had it, or closed on the kart's measured speed."""

from dataclasses import replace

import pytest

from kartpilot.core.errors import ConfigError
from kartpilot.core.types import FrameSet, VehicleFeedback
from kartpilot.runtime.lane_policy import LanePolicy, LanePolicyConfig
from kartpilot.sim.simulator import SimConfig, Simulator


@pytest.fixture(scope="module")
def cameras():
    with Simulator(SimConfig(track="sdc-assen", vehicle="sdc-kart", render_images=False)) as sim:
        return sim.cameras


def test_without_a_measured_speed_the_throttle_is_open_loop(cameras):
    policy = LanePolicy(cameras, LanePolicyConfig(speed_mps=3.0))
    command = policy(FrameSet(0, 0, {}))  # no boundary seen yet: the follower holds at its turn throttle
    assert command.throttle == policy.config.follow.throttle_turn and command.brake == 0.0


def test_a_measured_speed_closes_the_loop_around_a_fraction_of_speed_mps(cameras):
    policy = LanePolicy(cameras, LanePolicyConfig(speed_mps=3.0))
    policy.observe_vehicle(VehicleFeedback(0, speed_mps=4.0))  # faster than 0.6 x 3 m/s: brake
    fast = policy(FrameSet(0, 0, {}))
    assert fast.throttle == 0.0 and fast.brake > 0.0
    policy.observe_vehicle(VehicleFeedback(1, speed_mps=0.0))  # standing: throttle, not the fixed 0.6
    slow = policy(FrameSet(1, 33_000_000, {}))
    assert 0.0 < slow.throttle != policy.config.follow.throttle_turn and slow.brake == 0.0
    assert policy.outputs()["lanes"]["throttle"] == slow.throttle  # the recording shows what was sent
    for k in range(2, 12):  # no boundary for longer than the follower holds: it halts whatever the speed
        halted = policy(FrameSet(k, k * 33_000_000, {}))
    assert halted.brake == 1.0 and halted.throttle == 0.0


def test_open_loop_by_default_and_a_negative_speed_is_refused(cameras):
    policy = LanePolicy(cameras)
    policy.observe_vehicle(VehicleFeedback(0, speed_mps=9.0))
    assert policy(FrameSet(0, 0, {})).throttle == policy.config.follow.throttle_turn
    with pytest.raises(ConfigError, match="speed_mps"):
        LanePolicyConfig(speed_mps=-1.0)


def test_a_lanes_drive_on_the_sdc_kart_runs_at_the_fastest_known_good_speed_mode_unless_told(capsys):
    """A user's first `kartpilot sim --driver lanes` used to run at the kart's top speed and touch a line."""
    from kartpilot.cli.main import main
    from kartpilot.runtime.lane_policy import KNOWN_GOOD_SPEED_MODE_KMH, lane_speed_mode_mps

    assert lane_speed_mode_mps("lanes", "sdc-kart", 0.0) == pytest.approx(KNOWN_GOOD_SPEED_MODE_KMH / 3.6)
    assert lane_speed_mode_mps("lanes", "sdc-kart", 15 / 3.6) == pytest.approx(15 / 3.6)  # asked for
    assert lane_speed_mode_mps("stereo-vo", "rc-kart", 0.0) == 0.0
    main(["sim", "--track", "sdc-assen", "--vehicle", "sdc-kart", "--driver", "lanes", "--no-render"])
    assert f"speed mode {KNOWN_GOOD_SPEED_MODE_KMH:g} km/h" in capsys.readouterr().out


def test_on_a_taped_track_the_policy_steers_toward_the_track_and_records_its_target(cameras):
    import numpy as np
    from tests.perception.test_tape import render, straight

    policy = LanePolicy(cameras, LanePolicyConfig(boundaries="tape"))
    command = policy(FrameSet(0, 0, {"center": render(straight(0.1))}))  # the track's centre is to the right
    assert command.steer_rad < 0 and policy.outputs()["lanes"]["target_bearing_rad"] > 0
    assert policy.overlay(FrameSet(0, 0, {"center": render(straight(0.1))})) is not None
    for k in range(1, 12):  # a black camera: hold, then halt
        halted = policy(FrameSet(k, k, {"center": np.zeros((120, 160, 3), np.uint8)}))
    assert halted.brake == 1.0 and policy.fault()


def test_on_the_way_back_the_lane_in_view_corrects_the_dead_reckoned_pose():
    """Sweep event 10190: dead reckoned from a first view of the lane 4 deg off, the kart thought itself 2.9 m left of
    its lane's centre where it was 1.5 m, and returned onto the right line. The lane seen on the way back (its
    centre 1.63 m to the right, at 11 deg) pulls the pose halfway there each frame; a reading off the road, too far
    from the pose, or as near as the other lane's, is left."""
    import math

    from kartpilot.core.types import VehiclePose
    from kartpilot.runtime.lane_policy import lane_fix

    pose = VehiclePose(0, 18.5, 2.90, math.radians(-7.8), 3.7, 0.0, "bridged", "dead reckoning")
    fixed = lane_fix(pose, (-1.63, math.radians(11.4)), 3.0)
    assert fixed.y_m == pytest.approx((2.90 + 1.63) / 2) and fixed.x_m == pose.x_m
    assert math.degrees(fixed.yaw_rad) == pytest.approx((-7.8 - 11.4) / 2)
    assert lane_fix(fixed, (-1.63, math.radians(11.4)), 3.0).y_m == pytest.approx(1.63 + (2.90 - 1.63) / 4)
    assert lane_fix(pose, (1.7, math.radians(11.4)), 3.0) == pose  # the kart 1.7 m right of its lane: 4.6 m off
    assert lane_fix(pose, (-1.63, math.radians(25.0)), 3.0) == pose  # a heading 17 deg from the pose's
    middle = replace(pose, y_m=1.5)
    assert lane_fix(middle, (0.0, 0.0), 3.0) == middle  # 0 or 3 m: as near, either lane

"""The lane policy's speed: open-loop throttle as the thesis had it, or closed on the kart's measured speed."""

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

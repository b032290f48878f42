import numpy as np
import pytest

from kartpilot.control.lane_follow import LaneFollowConfig, LaneFollowState, lane_follow_step
from kartpilot.perception.lanes import LaneLine, LaneObservation, intersection

W, H, TOP = 960, 540, 300.0


def observation(left_bottom: float, right_bottom: float, vp_x: float = 480.0, left=True, right=True):
    """Two boundaries through a vanishing point at (vp_x, 250)."""
    def line(x_bottom: float) -> LaneLine:
        t = (TOP - (H - 1)) / (250.0 - (H - 1))
        return LaneLine(x_bottom, H - 1.0, x_bottom + t * (vp_x - x_bottom), TOP)

    lft = line(left_bottom) if left else LaneLine(0.0, H - 1.0, 0.0, TOP)
    rgt = line(right_bottom) if right else LaneLine(W - 1.0, H - 1.0, W - 1.0, TOP)
    return LaneObservation(W, H, lft, rgt, "detected" if left else "extreme", "detected" if right else "extreme",
                           intersection(lft, rgt), 1.0)


def run(config, observations, state=None):
    state = state or LaneFollowState()
    decisions = []
    for obs in observations:
        decision, state = lane_follow_step(config, state, obs)
        decisions.append(decision)
    return decisions, state


def test_centred_lane_goes_straight_and_a_lane_bending_right_steers_right():
    config = LaneFollowConfig(smoothing=0.0, max_steer_rate_radps=100.0)
    straight, _ = run(config, [observation(100, 860)])
    assert straight[0].steer_rad == pytest.approx(0.0, abs=5e-3) and straight[0].reason == "centre"
    right, _ = run(config, [observation(100, 860, vp_x=640)])
    assert right[0].steer_rad < -0.05  # positive is left


def test_offset_term_pulls_back_to_the_centre_where_the_thesis_did_not():
    # the kart sits left of the lane centre but heading along it: the vanishing point is straight ahead
    off_centre = observation(250, 1010)
    thesis = LaneFollowConfig(offset_gain=0.0, smoothing=0.0, max_steer_rate_radps=100.0)
    ours = LaneFollowConfig(smoothing=0.0, max_steer_rate_radps=100.0)
    assert run(thesis, [off_centre])[0][0].steer_rad == pytest.approx(0.0, abs=5e-3)  # settles off-centre
    assert run(ours, [off_centre])[0][0].steer_rad < -0.02  # steers right, toward the centre


def test_smoothing_and_rate_limit_damp_a_jumping_target():
    jumping = [observation(100, 860, vp_x=480 + (150 if k % 2 else -150)) for k in range(20)]
    raw, _ = run(LaneFollowConfig(smoothing=0.0, max_steer_rate_radps=100.0), jumping)
    damped, _ = run(LaneFollowConfig(), jumping)
    assert np.std([d.steer_rad for d in damped[5:]]) < 0.5 * np.std([d.steer_rad for d in raw[5:]])


def test_no_lane_holds_then_halts():
    config = LaneFollowConfig(hold_frames=3)
    decisions, _ = run(config, [observation(100, 860, vp_x=600)] * 5 + [None] * 5)
    assert [d.reason for d in decisions[5:]] == ["hold", "hold", "hold", "halt", "halt"]
    assert decisions[6].steer_rad == decisions[4].steer_rad
    assert decisions[-1].throttle == 0.0 and decisions[-1].brake == 1.0


def test_side_cameras_override_and_the_nearer_boundary_wins():
    config = LaneFollowConfig(max_steer_rate_radps=100.0)
    state = LaneFollowState()
    left_only, _ = lane_follow_step(config, state, observation(100, 860), away_from_left=0.5)
    assert left_only.reason == "side-left" and left_only.steer_rad == pytest.approx(-0.5 * config.max_steer_rad)
    both, _ = lane_follow_step(config, state, observation(100, 860), away_from_left=0.2, away_from_right=0.7)
    assert both.reason == "side-right" and both.steer_rad > 0
    thesis = LaneFollowConfig(max_steer_rate_radps=100.0, both_sides="left_first")
    assert lane_follow_step(thesis, state, None, 0.2, 0.7)[0].reason == "side-left"


def test_at_a_split_the_preferred_side_is_followed():
    config = LaneFollowConfig(smoothing=0.0, max_steer_rate_radps=100.0, split_preference="right")
    warmup = [observation(100, 860)] * 10
    # the left boundary jumps far out (a branch opens on the left) while the right one stays
    decisions, _ = run(config, [*warmup, observation(-600, 860)])
    assert decisions[-1].reason == "split"
    assert abs(decisions[-1].steer_rad) < 0.1  # keeps following the right boundary, does not veer left
    # one side missing: a remembered lane width stands in for it
    decisions, _ = run(config, [*warmup, observation(100, 860, left=False)])
    assert decisions[-1].steer_rad == pytest.approx(0.0, abs=0.02)

"""Overtaking and parking as planned paths: the plans' geometry, dead reckoning along an arc, the footprint test
the referee uses, the rules' transitions, and (slow) both scenarios closed loop."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from kartpilot.behaviour.events import BehaviourConfig, BehaviourState, behaviour_step
from kartpilot.behaviour.manoeuvres import OvertakeConfig, ParkConfig, plan_overtake, plan_park
from kartpilot.core.types import VehiclePose
from kartpilot.odometry.dead_reckoning import dead_reckon
from kartpilot.perception.objects import Detection
from kartpilot.sim.scenarios import footprints_touch


@pytest.mark.parametrize("car_m", [11.5, 14.0, 20.0])
def test_the_plan_is_out_of_the_lane_before_the_car_and_back_only_after_it(car_m):
    config = OvertakeConfig()
    path = plan_overtake(car_m, config)
    assert path is not None
    # fully out from before the kart's front (front_m ahead of the rear axle, the path's point) comes within
    # before_m of the car's back, until the kart's back has cleared the car's front by after_m
    beside = ((path.x_m + config.front_m >= car_m - config.before_m + 1e-6)
              & (path.x_m - config.rear_m <= car_m + config.car_length_m + config.after_m - 1e-6))
    assert beside.any() and np.all(path.y_m[beside] >= config.lane_offset_m - 0.05)
    assert abs(path.y_m[-1]) < 1e-6 and abs(path.y_m[0]) < 1e-6  # starts and ends on the lane's centre
    assert np.max(np.abs(path.curvature_per_m)) < 0.25  # a kart's steering can follow it


def test_a_car_too_near_to_pass_gets_no_plan():
    assert plan_overtake(9.0) is None  # it would swerve out over 6.5 m, not the 8 m planned


def test_dead_reckoning_follows_an_arc_and_a_line():
    pose = VehiclePose(0, 0.0, 0.0, 0.0, 0.0, 0.0, "ok")
    wheelbase, steer = 1.05, 0.2
    radius = wheelbase / math.tan(steer)
    quarter = math.pi / 2 * radius
    for _ in range(100):
        pose = dead_reckon(pose, quarter, steer, wheelbase, 0.01)
    assert (pose.x_m, pose.y_m, pose.yaw_rad) == pytest.approx((radius, radius, math.pi / 2), abs=1e-6)
    straight = dead_reckon(VehiclePose(0, 1.0, 2.0, math.pi, 0.0, 0.0, "ok"), 2.0, 0.0, wheelbase, 0.5)
    assert (straight.x_m, straight.y_m) == pytest.approx((0.0, 2.0))
    assert dead_reckon(pose, math.nan, math.nan, wheelbase, 0.1).x_m == pose.x_m  # nothing measured: no motion


def test_footprints_touch_only_where_they_overlap():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    assert footprints_touch(square, square + np.array([0.9, 0.9]))
    assert not footprints_touch(square, square + np.array([1.1, 0.0]))
    diamond = np.array([[1.6, 0.5], [2.1, 1.0], [1.6, 1.5], [1.1, 1.0]])  # its corner 0.1 m from the square
    assert not footprints_touch(square, diamond)


def _car(distance_m, lateral_m=0.0):
    return Detection("car", (0, 0, 1, 1), 0.9, distance_m=distance_m, lateral_m=lateral_m, track_id=1)


def test_the_rules_plan_an_overtake_once_and_return_to_drive_at_its_end():
    config = BehaviourConfig(overtake=True)
    state = BehaviourState.start(config)
    decision, state = behaviour_step(config, state, [_car(20.0)], 4.0, 0.1)
    assert decision.state == "drive"  # not yet within car_range_m
    decision, state = behaviour_step(config, state, [_car(13.0)], 4.0, 0.1)
    assert decision.state == "overtake" and decision.path is not None
    length = float(decision.path.s_m[-1])
    decision, state = behaviour_step(config, state, [_car(12.6)], 4.0, 0.1)
    assert decision.state == "overtake" and decision.path is None  # planned once
    for _ in range(int(length / 0.4) + 2):
        decision, state = behaviour_step(config, state, [], 4.0, 0.1)
    assert decision.state == "drive"


def test_without_overtaking_the_kart_stops_behind_the_car_and_waits():
    config = BehaviourConfig(overtake=False, front_m=1.5, car_gap_m=3.0)
    state = BehaviourState.start(config)
    decision, state = behaviour_step(config, state, [_car(12.0)], 4.0, 0.1)
    assert decision.state == "wait_car"
    assert decision.stop_distance_m == pytest.approx(12.0 - 1.5 - 3.0, abs=0.5)
    decision, _ = behaviour_step(config, state, [_car(12.0, lateral_m=3.0)], 4.0, 0.1)  # in the other lane
    assert decision.state == "wait_car"  # the one it stopped for is not seen; it waits clear_s first


@pytest.mark.slow
@pytest.mark.parametrize(("name", "seed"), [("overtake", 3), ("parking", 2)])
def test_the_scenario_passes_closed_loop(name, seed):
    """The scenario as ``kartpilot sim --scenario`` drives it: the kart's own camera, the rules, the path."""
    from kartpilot.runtime.scenarios import run_scenario

    result = run_scenario(name, seed)
    print(result)
    assert result["passed"], result["faults"]


@pytest.mark.parametrize(("bay_m", "free_m"), [(6.0, 6.5), (10.0, 7.5), (14.0, 7.0)])
def test_the_parking_path_clears_the_near_barrier_and_stops_short_of_the_far_one(bay_m, free_m):
    config = ParkConfig()
    lateral = -2.5
    path = plan_park(bay_m, free_m, lateral, config)
    assert path is not None
    # the kart's front stops front_gap_m before the far barrier, on the bay's line
    assert path.x_m[-1] + config.front_m == pytest.approx(bay_m + free_m - config.front_gap_m, abs=0.1)
    assert path.y_m[-1] == pytest.approx(lateral, abs=0.01) and path.speed_mps[-1] == 0.0
    # until its back has passed the near barrier, its side keeps side_gap_m from the barrier's inner end
    passing = path.x_m - config.rear_m < bay_m
    inner = abs(lateral) - config.barrier_half_width_m
    assert np.all(np.abs(path.y_m[passing]) + config.half_width_m + config.side_gap_m <= inner + 1e-6)


def test_a_short_or_near_bay_gets_no_parking_plan():
    assert plan_park(10.0, 3.0, -2.5) is None  # shorter than the kart and its gaps
    assert plan_park(10.0, 5.5, -2.5) is None  # the S would bring the kart's side onto the near barrier
    assert plan_park(-3.0, 7.0, -2.5) is None  # the bay is beside the kart already


def test_the_rules_park_in_a_bay_and_stay_parked():
    config = BehaviourConfig(park=True)
    state = BehaviourState.start(config)
    bay = Detection("parking_bay", (0, 0, 1, 1), 0.9, "7.0", distance_m=10.0, lateral_m=-2.5)
    decision, state = behaviour_step(config, state, [bay], 3.0, 0.1)
    assert decision.state == "park" and decision.path is not None
    length = float(decision.path.s_m[-1])
    assert decision.stop_distance_m == pytest.approx(length, abs=0.1)
    odometer = 0.0
    for _ in range(200):  # a kart that drives at the cap, braking at once
        decision, state = behaviour_step(config, state, [], min(decision.speed_cap_mps, 3.0), 0.1)
        odometer += min(decision.speed_cap_mps, 3.0) * 0.1
        if decision.state == "parked":
            break
    assert decision.state == "parked" and decision.speed_cap_mps == 0.0
    assert odometer == pytest.approx(length, abs=0.5)  # stopped where the path ends
    decision, _ = behaviour_step(config, state, [bay], 0.0, 0.1)
    assert decision.state == "parked"  # for good


def _park_from(bay: Detection, views: list[list[Detection]], speed_mps: float = 2.0, dt_s: float = 0.1):
    """The rules parking on ``bay`` and then seeing ``views`` frame by frame at ``speed_mps``: the decisions."""
    config = BehaviourConfig(park=True)
    decision, state = behaviour_step(config, BehaviourState.start(config), [bay], speed_mps, dt_s)
    assert decision.state == "park"
    out = [(decision, state)]
    for seen in views:
        out.append(behaviour_step(config, out[-1][1], seen, speed_mps, dt_s))
    return out


def test_a_far_barrier_seen_nearer_replans_the_bay_before_the_s_and_moves_the_stop_after():
    """Planned from afar on a bay 2 m too long (the camera's error at 20 m); the far barrier seen again from
    nearer: the path is replanned (shorter) while its S lies ahead, and after the S began only the stop comes
    nearer, never farther."""
    bay = Detection("parking_bay", (0, 0, 1, 1), 0.9, "9.5", distance_m=10.0, lateral_m=-2.5)
    far = 10.0 + 7.5  # where the far barrier truly stands from the kart's start
    frames = [[Detection("barrier", (0, 0, 1, 1), 0.9, distance_m=far - 0.2 * (k + 1), lateral_m=-2.6)]
              for k in range(60)]
    steps = _park_from(bay, frames)
    first = steps[0][0]
    replanned = [d for d, _ in steps[1:] if d.path is not None]
    assert replanned and all(d.replanned for d in replanned)
    assert float(replanned[-1].path.s_m[-1]) < float(first.path.s_m[-1]) - 1.5
    _, state = steps[-1]
    assert state.bay_m[1] == pytest.approx(7.5, abs=0.05)
    # the kart's front stops front_gap_m before the far barrier
    config = ParkConfig()
    assert state.stop_at_m == pytest.approx(far - config.front_gap_m - config.front_m, abs=0.3)
    # once the S has begun (no more paths), the stop only comes nearer
    last_path = max(k for k, (d, _) in enumerate(steps) if d.path is not None)
    after = [s.stop_at_m for _, s in steps[last_path:]]
    assert len(after) > 10 and all(b <= a + 1e-9 for a, b in itertools.pairwise(after))


def test_what_is_not_the_far_barrier_leaves_the_plan_alone():
    """A barrier on the other side, one beyond the gate, the near barrier itself, and one seen from no nearer
    than the plan's: nothing replanned."""
    bay = Detection("parking_bay", (0, 0, 1, 1), 0.9, "7.5", distance_m=10.0, lateral_m=-2.5)
    others = [Detection("barrier", (0, 0, 1, 1), 0.9, distance_m=15.0, lateral_m=2.5),  # across the road
              Detection("barrier", (0, 0, 1, 1), 0.9, distance_m=12.0, lateral_m=-2.5),  # before the bay's end
              Detection("barrier", (0, 0, 1, 1), 0.9, distance_m=9.8, lateral_m=-2.5)]  # the near one
    steps = _park_from(bay, [others] * 3)
    assert all(d.path is None for d, _ in steps[1:])
    assert steps[-1][1].bay_m == steps[0][1].bay_m and steps[-1][1].stop_at_m == steps[0][1].stop_at_m

"""The event's rules with the 2026 kart's LiDAR (issue 58): what the scan changes in a decision (an overtake's return
held while something is beside the kart, a stop before what is in the lane, a bay measured between its barriers),
that each decision says what it was made from, and (slow) the overtake and parking scenarios closed loop with the
LiDAR, one of them losing it halfway."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from kartpilot.behaviour.events import BehaviourConfig, BehaviourState, behaviour_step
from kartpilot.perception.objects import Detection
from kartpilot.perception.scan import LidarView, ScanCluster, bay_between_barriers
from kartpilot.runtime.faults import Injection
from kartpilot.runtime.scenarios import run_scenario
from kartpilot.sensors.health import LidarHealthConfig
from kartpilot.sim.scenarios import scenario
from kartpilot.sim.simulator import perfect_camera

CONFIG = BehaviourConfig(overtake=True, park=True)
CONFIG_TIMEOUT_S = LidarHealthConfig().timeout_s


def _view(points: list[tuple[float, float]], clusters: tuple[ScanCluster, ...] = ()) -> LidarView:
    return LidarView(0, np.array(points, float).reshape(-1, 2), clusters)


def _overtaking(car_m: float = 12.0) -> tuple[BehaviourState, float]:
    """The rules' state one step into an overtake of a car ``car_m`` ahead, and the metres driven then."""
    car = Detection("car", (0, 0, 1, 1), 0.9, distance_m=car_m, lateral_m=0.0, track_id=1)
    decision, state = behaviour_step(CONFIG, BehaviourState.start(CONFIG), [car], 4.0, 0.1, _view([]))
    assert decision.state == "overtake" and decision.path is not None and decision.sensors == "camera+lidar"
    return state, state.odometer_m


def test_the_return_waits_while_the_scan_shows_something_beside_the_kart() -> None:
    """At the point the return begins (the car's assumed 4 m past, with the margins), a car still beside the kart
    in the lane it returns to (3 m to its right) holds the return: the pass is replanned a metre longer, in the same
    frame, and the rules say the scan made them; with the lane beside clear, the return goes ahead as planned."""
    state, start = _overtaking()
    p = CONFIG.passing
    back_at = 12.0 + p.car_length_m + p.rear_m + p.after_m
    at_return = BehaviourState(**{**state.__dict__, "odometer_m": start + back_at - 0.5})
    beside = _view([(x, -3.0) for x in np.arange(-2.0, 1.0, 0.1)])
    decision, held = behaviour_step(CONFIG, at_return, [], 0.0, 0.1, beside)
    print(decision.reason)
    assert decision.replanned and decision.sensors == "lidar" and decision.path is not None
    assert held.car_length_m == pytest.approx(p.car_length_m + CONFIG.return_extend_m)
    assert held.manoeuvre_end_m > state.manoeuvre_end_m
    far = int(np.argmax(decision.path.x_m >= back_at))  # where the planned return had begun, the new path is out
    assert decision.path.y_m[far] == pytest.approx(p.lane_offset_m, abs=1e-6)
    decision, clear = behaviour_step(CONFIG, at_return, [], 0.0, 0.1, _view([(5.0, 3.5)]))
    assert not decision.replanned and clear.car_length_m == p.car_length_m
    # never more than return_wait_m: then the return goes ahead, as planned last
    waited = BehaviourState(**{**at_return.__dict__, "car_length_m": p.car_length_m + CONFIG.return_wait_m,
                               "odometer_m": start + back_at + CONFIG.return_wait_m - 0.5})
    decision = behaviour_step(CONFIG, waited, [], 0.0, 0.1, beside)[0]
    assert not decision.replanned and "returning as planned" in decision.reason and decision.sensors == "lidar"


def test_something_in_the_lane_stops_the_kart_whether_the_camera_saw_it_or_not() -> None:
    """Nothing detected by the camera, a return 6 m ahead on the kart's line: the speed is capped to stop
    ``lidar_gap_m`` before it, said to come from the scan; the same return beside the lane changes nothing, and
    without a LiDAR the rules are the camera's alone."""
    state = BehaviourState.start(CONFIG)
    decision, _ = behaviour_step(CONFIG, state, [], 4.0, 0.1, _view([(6.0, 0.2), (6.0, 0.3)]))
    gap = 6.0 - CONFIG.front_m - CONFIG.lidar_gap_m
    print(decision.reason, decision.speed_cap_mps)
    assert decision.sensors == "lidar" and decision.stop_distance_m == pytest.approx(gap)
    assert decision.speed_cap_mps < 2.5 and "(lidar)" in decision.reason
    beside, _ = behaviour_step(CONFIG, state, [], 4.0, 0.1, _view([(6.0, 2.5)]))
    camera, _ = behaviour_step(CONFIG, state, [], 4.0, 0.1, None)
    assert beside.speed_cap_mps == camera.speed_cap_mps and beside.sensors == "camera+lidar"
    assert camera.sensors == "camera"


def _barrier(x0: float, x1: float, y: float) -> ScanCluster:
    return ScanCluster(((x0 + x1) / 2, y), (x0, y), x1 - x0, 0.1, 0.0, 10, (x0, x1), (y - 0.05, y + 0.05))


def test_a_bay_is_measured_between_the_barriers_on_its_side() -> None:
    clusters = [_barrier(9.6, 10.0, -2.5), _barrier(13.1, 13.5, -2.5), _barrier(9.6, 10.0, 2.5)]
    start, free = bay_between_barriers(clusters, -1.0, 10.3, -2.4) or (math.nan, math.nan)
    assert (start, free) == pytest.approx((10.0, 3.1))
    assert bay_between_barriers(clusters, -1.0, 14.0, -2.4) is None  # not where the camera put the bay
    assert bay_between_barriers(clusters[:1], -1.0, 10.3, -2.4) is None  # the far barrier out of range yet


@pytest.mark.slow
def test_the_overtake_passes_with_the_lidar_and_when_it_is_lost_halfway() -> None:
    """The 2026 kart on overtake seed 5 (not one the rules were tuned on): its LiDAR lost 6 s in, during the pass.
    It passes on the camera-only rules, and the result says when and why it fell back."""
    plan = replace(scenario("overtake", 5), effects=perfect_camera())  # the LiDAR's test (the suite's time)
    result = run_scenario(plan, vehicle="sdc-kart-2026", injections=[Injection("lidar-loss", 6.0)])
    print(result["passed"], result["faults"], result["lidar"], result["states"])
    assert result["passed"], result["faults"]
    (at_s, why), = result["lidar"]
    timeout = CONFIG_TIMEOUT_S  # from its last sweep (up to a sweep's period before 6 s), told at a frame's time
    assert 6.0 + timeout - 0.1 <= at_s <= 6.0 + timeout + 2 / 15 and "no good sweep for" in why


@pytest.mark.slow
def test_parking_measures_its_bay_with_the_lidar_and_passes() -> None:
    """Parking seed 4 (held out) on the 2026 kart: planned from the camera's bay, measured again between the
    barriers once the scan reaches the far one, and parked wholly inside."""
    result = run_scenario(replace(scenario("parking", 4), effects=perfect_camera()), vehicle="sdc-kart-2026")
    print(result["passed"], result["faults"], result["states"])
    assert result["passed"], result["faults"]
    assert result["lidar"] == []  # healthy throughout


@pytest.mark.slow
def test_a_line_of_cars_longer_than_the_plan_assumes_is_passed_by_waiting_for_the_scan() -> None:
    """tests/data/lidar/overtake-three-cars.yaml (kept apart from the sweep's fixed failures, which run
    camera-only): three cars nose to tail where the plan assumes one of 4 m. The camera-only rules return onto the
    third car (touched at 9.9 s, measured); the 2026 kart's return waits for the scan to show the lane beside
    clear, and passes."""
    from pathlib import Path

    from kartpilot.sim.scenarios import load_scenario_file

    plan = load_scenario_file(Path(__file__).parents[1] / "data" / "lidar" / "overtake-three-cars.yaml")
    result = run_scenario(replace(plan, effects=perfect_camera()), vehicle="sdc-kart-2026")
    print(result["passed"], result["faults"], result["states"])
    assert result["passed"], result["faults"]

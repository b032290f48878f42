"""The scenarios' layouts vary with the seed, and their referee counts the faults the event counts."""

import numpy as np
import pytest

from kartpilot.core.errors import ConfigError
from kartpilot.sim.scenarios import SCENARIOS, ScenarioReferee, scenario


def run(name, seed, trajectory, dt=0.1):
    """Score a trajectory: ``trajectory(t)`` gives (the front's place along the route, the speed)."""
    plan = scenario(name, seed)
    referee = ScenarioReferee(plan)
    t = 0.0
    front = 0.0
    while t < plan.duration_s:
        front, speed = trajectory(t, plan.marks)
        referee.step(t, front, speed, dt)
        t += dt
    return referee.result(front)


def test_every_scenario_varies_with_its_seed():
    for name in SCENARIOS:
        assert scenario(name, 1) != scenario(name, 2)
        assert scenario(name, 1) == scenario(name, 1)
    with pytest.raises(ConfigError, match="unknown scenario"):
        scenario("overtake-on-the-left", 1)


def test_red_light_faults():
    good = run("red-light", 2, lambda t, m: (29.3, 0.0) if t < m["red_until_s"] else (40.0, 4.0))
    assert good["passed"] and good["stopped_before_line_m"] == pytest.approx(0.7)
    past = run("red-light", 2, lambda t, m: (30.4, 0.0) if t < m["red_until_s"] else (40.0, 4.0))
    assert not past["passed"] and any("passed the line on red" in f for f in past["faults"])
    early = run("red-light", 2, lambda t, m: (27.5, 0.0) if t < m["red_until_s"] else (40.0, 4.0))
    assert any("2.50 m before the line" in f for f in early["faults"])
    stays = run("red-light", 2, lambda t, m: (29.3, 0.0))
    assert "did not go on at green" in stays["faults"]


def test_start_on_green_speed_limit_and_pedestrian_faults():
    early = run("start-on-green", 3, lambda t, m: (6.5 + 3.0 * t, 3.0))
    assert any("left before green" in f for f in early["faults"])
    waited = run("start-on-green", 3, lambda t, m: (6.5 + 3.0 * max(t - m["start_green_at_s"], 0.0), 3.0))
    assert waited["passed"]
    fast = run("speed-limit", 1, lambda t, m: (6.5 + 4.0 * t, 4.0))  # 14.4 km/h past a 10 km/h sign
    assert any("over the limit by up to 4.4 km/h" in f for f in fast["faults"])
    assert run("speed-limit", 1, lambda t, m: (6.5 + 2.6 * t, 2.6))["passed"]
    # reaching the crossing while the pedestrian is on the road, and not stopping
    person = scenario("pedestrian", 1).props[0]
    on_road_from = person.walk_start_s + 1.1 / person.walk_speed_mps  # from 2.6 m right to the lane's edge
    on_road_until = person.walk_start_s + 4.1 / person.walk_speed_mps
    rushed = run("pedestrian", 1, lambda t, m: (143.0 + 1.0 * (t - on_road_from), 1.0))
    assert any("moved at the crossing" in f for f in rushed["faults"])

    def yielding(t, m):
        if t < on_road_until + 1.0:
            return min(136.0 + 3.0 * t, 145.0), 0.0 if 136.0 + 3.0 * t >= 145.0 else 3.0
        return 145.0 + 3.0 * (t - on_road_until - 1.0), 3.0

    assert run("pedestrian", 1, yielding)["passed"]


def test_overtake_faults():
    def scored(front_end, offset_end, touching_at=None):
        plan = scenario("overtake", 4)
        referee = ScenarioReferee(plan)
        t = 0.0
        while t < plan.duration_s:
            front = 165.0 + (front_end - 165.0) * t / plan.duration_s
            touching = "car" if touching_at is not None and abs(t - touching_at) < 0.05 else ""
            referee.step(t, front, 4.0, 0.1, touching, 3.0 if front < plan.marks["car_s"] + 12.0 else offset_end)
            t += 0.1
        return referee.result(front)

    car = scenario("overtake", 4).marks["car_s"]
    assert scored(car + 30.0, 0.1)["passed"]
    assert any("touched the car" in f for f in scored(car + 30.0, 0.1, touching_at=5.0)["faults"])
    assert "did not pass the car" in scored(car - 3.0, 0.1)["faults"]
    assert any("did not return to the lane" in f for f in scored(car + 30.0, 3.0)["faults"])


def test_the_track_referee_lets_a_kart_cross_a_dashed_line_only_where_allowed():
    """On lelystad's dashed stretch the kart drives one lane to the left: disqualified unless the referee
    allows crossing a dashed line; a solid line stays a line."""
    from dataclasses import replace

    from kartpilot.core.types import ActuatorCommand
    from kartpilot.sim.referee import RefereeConfig
    from kartpilot.sim.simulator import SimConfig, Simulator
    from kartpilot.sim.track import build_track, load_track_spec

    def drive_left_lane(allowed: bool, s_m: float) -> str:
        config = SimConfig(track="lelystad", vehicle="sdc-kart", cameras=(), max_time_s=1.0,
                           referee=RefereeConfig(may_cross_dashed=allowed))
        track = build_track(replace(load_track_spec("lelystad"), start_s_m=s_m))
        with Simulator(config, track=track) as sim:
            route = sim.track.route
            i = route.index_at(s_m)
            x, y = route.xy_m[i] + 3.0 * route.normal()[i]
            sim.state = type(sim.state)(x_m=float(x), y_m=float(y), yaw_rad=float(route.heading_rad[i]), vx_mps=2.0)
            while sim.read() is not None:
                sim.send(ActuatorCommand(0, 0.0, 0.1, 0.0))
            return sim.referee.reason if sim.referee.disqualified else ""

    assert drive_left_lane(True, 190.0) == ""
    assert drive_left_lane(False, 190.0) != ""
    assert drive_left_lane(True, 20.0) != ""  # a solid line there


def test_parking_faults():
    plan = scenario("parking", 3)
    m = plan.marks

    def scored(s_back, lateral, speed=0.0, touching=""):
        referee = ScenarioReferee(plan)
        kart = np.array([[s_back, lateral - 0.6], [s_back + 1.8, lateral - 0.6], [s_back + 1.8, lateral + 0.6],
                         [s_back, lateral + 0.6]])
        referee.step(1.0, s_back + 1.8, speed, 0.1, touching, lateral, kart)
        return referee.result(s_back + 1.8)

    middle = -(1.5 + m["outer_m"] / 2)
    assert scored(m["bay_s"] + 1.0, middle)["passed"]
    assert "did not end wholly inside the bay" in scored(m["bay_end_s"] - 1.0, middle)["faults"]  # front past it
    assert "did not end wholly inside the bay" in scored(m["bay_s"] + 1.0, -1.2)["faults"]  # still in the lane
    assert "did not stop in the bay" in scored(m["bay_s"] + 1.0, middle, speed=1.0)["faults"]
    assert any("touched the barrier" in f for f in scored(m["bay_s"] + 1.0, middle, touching="barrier")["faults"])


def test_the_event_course_holds_all_six_on_one_loop():
    from kartpilot.sim.scenarios import EVENT_LAP_M
    from kartpilot.sim.track import build_track, load_track_spec

    assert pytest.approx(build_track(load_track_spec("lelystad")).route.length_m, abs=0.05) == EVENT_LAP_M
    plan = scenario("event", 4)
    kinds = sorted(p.kind for p in plan.props)
    assert kinds == ["car", "person", "speed_sign", "speed_sign", "traffic_light"]
    light = next(p for p in plan.props if p.kind == "traffic_light")
    m = plan.marks
    # red at the start, green to start on, red again as the kart comes, green for good
    assert [light.light_at(t) for t in (0.0, m["start_green_at_s"] + 0.1, m["red_from_s"] + 0.1,
                                        m["red_until_s"] + 0.1, 1e5)] == ["red", "green", "red", "green", "green"]
    assert plan.start_on_green and plan.overtake and plan.park and plan.laps == 2 and len(plan.barriers) == 2
    assert m["bay_s"] > EVENT_LAP_M > plan.park_after_m  # parked in on the second lap, not the first
    # the referee judges every rule on it: a kart that never moves breaks all six
    referee = ScenarioReferee(plan)
    for k in range(100):
        referee.step(k * 0.1, m["start_s"] + 1.5, 0.0, 0.1)
    faults = referee.result(m["start_s"] + 1.5)["faults"]
    for fault in ("did not start on green", "did not go on at green", "did not go on after the pedestrian",
                  "did not pass the car", "did not end wholly inside the bay"):
        assert any(f.startswith(fault) for f in faults), fault


def test_the_verdict_is_sure_only_once_every_mark_is_behind_the_kart():
    """A drive ends a second after ``decided``: never before a mark's check is settled (a stop that is still to
    come, a light still red, a lane not yet regained), never for a bay or a limit that holds to the end; and the
    verdict a drive ended there gets is the one the whole drive gets."""
    def first_decided(name, seed, trajectory, dt=0.1):
        plan = scenario(name, seed)
        referee = ScenarioReferee(plan)
        t = 0.0
        while t < plan.duration_s:
            front, speed = trajectory(t, plan.marks)
            referee.step(t, front, speed, dt)
            if referee.decided(t, front):
                return t, front, plan.marks, referee.result(front)
            t += dt
        return None

    def stop_and_go(t, m):
        return (29.3, 0.0) if t < m["red_until_s"] else (29.3 + 4.0 * (t - m["red_until_s"]), 4.0)

    t, front, marks, verdict = first_decided("red-light", 2, stop_and_go)
    assert t >= marks["red_until_s"] and front >= marks["line_s"] + 2.0
    assert verdict == run("red-light", 2, stop_and_go) and verdict["passed"]
    early = first_decided("red-light", 2, lambda t, m: (30.4, 0.0) if t < m["red_until_s"] else (
        30.4 + 4.0 * (t - m["red_until_s"]), 4.0))  # stopped past the line: the fault is already counted
    assert early is not None and not early[3]["passed"]
    assert first_decided("red-light", 2, lambda t, m: (29.3, 0.0)) is None  # stays at the line: never sure
    t, front, marks, _ = first_decided("start-on-green", 3,
                                    lambda t, m: (6.5 + 3.0 * max(t - m["start_green_at_s"], 0.0), 3.0))
    assert t >= marks["start_green_at_s"] and front >= 8.5
    assert first_decided("pedestrian", 1, lambda t, m: (136.0 + 2.0 * t, 2.0))[1] >= 149.0
    assert first_decided("speed-limit", 1, lambda t, m: (6.5 + 2.6 * t, 2.6)) is None  # the limit holds to the end
    assert first_decided("parking", 1, lambda t, m: (5.0 + 3.0 * t, 3.0)) is None  # ends when parked

    plan = scenario("overtake", 4)
    car = plan.marks["car_s"]
    referee = ScenarioReferee(plan)
    for k in range(150):  # out on the other lane, past the car, back in lane by back_by_s
        front = 165.0 + 0.4 * k
        referee.step(k * 0.1, front, 4.0, 0.1, "", 3.0 if front < car + 12.0 else 0.1)
        assert referee.decided(k * 0.1, front) == (front >= plan.marks["back_by_s"])

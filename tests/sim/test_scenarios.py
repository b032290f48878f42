"""The scenarios' layouts vary with the seed, and their referee counts the faults the event counts."""

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
    good = run("red-light", 2, lambda t, m: (29.3, 0.0) if t < m["green_at_s"] else (40.0, 4.0))
    assert good["passed"] and good["stopped_before_line_m"] == pytest.approx(0.7)
    past = run("red-light", 2, lambda t, m: (30.4, 0.0) if t < m["green_at_s"] else (40.0, 4.0))
    assert not past["passed"] and any("passed the line on red" in f for f in past["faults"])
    early = run("red-light", 2, lambda t, m: (27.5, 0.0) if t < m["green_at_s"] else (40.0, 4.0))
    assert any("2.50 m before the line" in f for f in early["faults"])
    stays = run("red-light", 2, lambda t, m: (29.3, 0.0))
    assert "did not go on at green" in stays["faults"]


def test_start_on_green_speed_limit_and_pedestrian_faults():
    early = run("start-on-green", 3, lambda t, m: (6.5 + 3.0 * t, 3.0))
    assert any("left before green" in f for f in early["faults"])
    waited = run("start-on-green", 3, lambda t, m: (6.5 + 3.0 * max(t - m["green_at_s"], 0.0), 3.0))
    assert waited["passed"]
    fast = run("speed-limit", 1, lambda t, m: (6.5 + 4.0 * t, 4.0))  # 14.4 km/h past a 10 km/h sign
    assert any("over the limit by up to 4.4 km/h" in f for f in fast["faults"])
    assert run("speed-limit", 1, lambda t, m: (6.5 + 2.6 * t, 2.6))["passed"]
    # reaching the crossing while the pedestrian is on the road, and not stopping
    rushed = run("pedestrian", 1, lambda t, m: (143.0 + 1.0 * (t - m["on_road_from_s"]), 1.0))
    assert any("moved at the crossing" in f for f in rushed["faults"])

    def yielding(t, m):
        if t < m["on_road_until_s"] + 1.0:
            return min(136.0 + 3.0 * t, 145.0), 0.0 if 136.0 + 3.0 * t >= 145.0 else 3.0
        return 145.0 + 3.0 * (t - m["on_road_until_s"] - 1.0), 3.0

    assert run("pedestrian", 1, yielding)["passed"]

"""Scoring a sweep: each fault's cause from the rules' record of the drive, and a pass rate's interval."""

import pytest

from kartpilot.eval.scenarios import failure_causes, pass_rate, sweep_summary


def _result(faults, states):
    return {"passed": not faults, "faults": faults, "states": states}


@pytest.mark.parametrize(("fault", "states", "cause"), [
    ("passed the line on red at 9.0 s", [[0, "drive", 20]], "not seen"),
    ("passed the line on red at 9.0 s", [[0, "drive", 20], [7, "stop_red", 20]], "seen late"),
    ("stopped 2.50 m before the line (0.2 to 1.5 m wanted)", [[0, "drive", 20], [7, "wait_red", 20]], "controller"),
    ("did not go on at green", [[0, "drive", 20], [7, "wait_red", 20]], "wrong decision"),
    ("over the limit by up to 3.1 km/h for 2.5 s", [[0, "drive", 20]], "not seen"),
    ("over the limit by up to 3.1 km/h for 2.5 s", [[0, "drive", 20], [4, "drive", 10]], "seen late"),
    ("moved at the crossing while the pedestrian was on the road (8.0 s)", [[0, "drive", 20]], "not seen"),
    ("moved at the crossing while the pedestrian was on the road (8.0 s)", [[0, "drive", 20], [6, "yield", 20]],
     "seen late"),
    ("did not pass the car", [[0, "drive", 20], [3, "wait_car", 20]], "not seen"),
    ("touched the car at 5.0 s", [[0, "drive", 20], [3, "overtake", 20]], "controller"),
    ("did not end wholly inside the bay", [[0, "drive", 20]], "not seen"),
    ("did not end wholly inside the bay", [[0, "drive", 20], [9, "park", 20]], "controller"),
    ("left before green (1.2 m at 1.0 s)", [[0, "wait_start", 20], [0.5, "drive", 20]], "wrong decision"),
    ("did not start on green", [[0, "wait_start", 20]], "not seen"),
    ("touched the left line at s=75.8 m", [[0, "drive", 20]], "controller"),
])
def test_each_fault_gets_the_cause_the_rules_record_points_to(fault, states, cause):
    assert failure_causes(_result([fault], states)) == [(fault, cause)]


def test_a_stop_for_an_object_the_scenario_does_not_hold_is_seen_what_is_not_there():
    """The first sweep's pedestrians: the kart stopped for a red light in a scenario without one (a face before a
    tree's dark crown, taken for a lamp in its housing), then never went on."""
    result = {"faults": ["did not go on after the pedestrian had crossed"], "kinds": ["person"],
              "states": [[0, "drive", 20], [0.2, "stop_red", 20], [5.9, "wait_red", 20]]}
    assert failure_causes(result) == [(result["faults"][0], "seen what is not there")]
    held = {**result, "kinds": ["person", "traffic_light"]}
    assert failure_causes(held) == [(result["faults"][0], "wrong decision")]


def test_a_pass_rate_s_interval_is_honest_at_the_ends():
    rate, low, high = pass_rate(50, 50)
    assert rate == 1.0 and high == 1.0 and 0.9 < low < 0.95  # 50 of 50 does not prove 100 %
    rate, low, high = pass_rate(97, 100)
    assert rate == 0.97 and low < 0.97 < high
    rows = [{"scenario": "red-light", "seed": 1, **_result([], [])},
            {"scenario": "red-light", "seed": 2, **_result(["passed the line on red at 9.0 s"], [[0, "drive", 20]])}]
    summary = sweep_summary(rows, ("red-light", "parking"))
    assert summary["scenarios"]["red-light"]["passed"] == 1 and summary["scenarios"]["parking"]["events"] == 0
    assert summary["scenarios"]["red-light"]["causes"] == {"not seen": 1}
    assert summary["failures"][0]["seed"] == 2

"""Scenario files: every built-in scenario written as a file reads back the same, the referee's marks derived from
the props as the built-ins set them, one clear error per bad file, and a hand-written file driven closed loop."""

import json
from pathlib import Path

import pytest

from kartpilot.cli.main import main
from kartpilot.core.errors import ConfigError
from kartpilot.sim.scenarios import (
    SCENARIOS,
    derive_marks,
    load_scenario_file,
    scenario,
    scenario_or_file,
    write_scenario_file,
)
from kartpilot.sim.track import load_track_spec

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "scenarios"


@pytest.mark.parametrize("name", SCENARIOS)
def test_a_built_in_scenario_as_a_file_is_the_same_scenario(name, tmp_path):
    spec = load_track_spec("lelystad")
    for seed in (1, 4):
        plan = scenario(name, seed)
        assert derive_marks(plan, spec) == pytest.approx(plan.marks, abs=0.01)  # the event's lap, to 0.4 mm
        path = write_scenario_file(tmp_path / f"{name}-{seed}.yaml", plan)
        assert load_scenario_file(path) == plan
        assert scenario_or_file(str(path)) == plan and scenario_or_file(str(path), 9).seed == 9
    assert scenario_or_file(name, 4) == scenario(name, 4)


def test_the_example_files_read_and_their_marks_follow_their_props():
    rising = load_scenario_file(EXAMPLES / "rising-limit.yaml")
    assert rising.marks == {"start_s": 50.0, "sign_s": 64.0, "limit_kmh": 10.0, "limit_until_s": 121.0}
    late = load_scenario_file(EXAMPLES / "late-pedestrian.yaml")
    assert late.marks == {"start_s": 128.0, "zebra_s": 146.0}
    light = load_scenario_file(EXAMPLES / "red-light-then-green.yaml")
    assert light.marks == {"line_s": 30.0, "red_until_s": 12.0}


BAD = [
    ("props:\n  - {kind: tractor, s_m: 20}\n", r"scenario.props\[0\].kind' must be one of"),
    ("props:\n  - {kind: car, s_m: 900}\n", r"props\[0\] \(car\): s_m 900 is off the track"),
    ("props:\n  - {kind: car, s_m: 50, offset_m: 4}\n", r"props\[0\] \(car\): offset_m 4 is off the track"),
    ("props:\n  - {kind: speed_sign, s_m: 50, offset_m: -30}\n", "offset_m -30 is off the track"),
    ("props:\n  - {kind: traffic_light, s_m: 36, phases: [[red, 5], [red, 5], [green, 9]]}\n",
     "phases do not add up.*take turns"),
    ("duration_s: 10\nprops:\n  - {kind: traffic_light, s_m: 36, phases: [[red, 8], [green, 5], [red, 9]]}\n",
     "phases do not add up.*beyond the scenario's 10 s"),
    ("props:\n  - {kind: traffic_light, s_m: 36, phases: [[red, -1], [green, 5]]}\n", "each phase must last"),
    ("prop:\n  - {kind: car, s_m: 50}\n", "unknown config key 'scenario.prop'"),
    ("marks: {stop_line: 30}\n", "unknown config key 'scenario.marks.stop_line'"),
    ("marks: {line_s: .nan}\n", "scenario.marks.line_s' must be a finite number"),
    ("track: nowhere\n", "unknown track 'nowhere'"),
    ("duration_s: 0\n", "duration_s must be positive"),
]


@pytest.mark.parametrize(("text", "error"), BAD)
def test_a_bad_scenario_file_is_one_clear_error(text, error, tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=error):
        load_scenario_file(path)


def test_the_command_line_runs_a_file_and_refuses_a_bad_one_in_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("props:\n  - {kind: car, s_m: 900}\n")
    assert main(["sim", "--scenario", str(bad), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("kartpilot: ") and "off the track" in err and len(err.splitlines()) == 1
    assert main(["sim", "--scenario", "red-lite"]) == 1
    assert "give one of start-on-green" in capsys.readouterr().err


@pytest.mark.slow
def test_a_limit_on_signs_on_the_left_that_rises_again_is_kept_closed_loop(tmp_path, capsys):
    """Signs on the left of the venue's one-way course count: the kart slows to 10 km/h at the first and speeds
    up again at the 20 km/h one (the event's rule: the posted limit holds until a new sign), judged by the marks
    derived from the file; the run saved as a file reproduces the scenario. The limits are read from the result's
    rules' states (each change of state or limit), not from a recording of the drive: a scenario's recording is the
    red light's test, and recording the three cameras was a fifth of this one's time."""
    path = tmp_path / "left-signs.yaml"
    path.write_text("track: lelystad\nduration_s: 17\nmarks: {start_s: 50}\nprops:\n"
                    "  - {kind: speed_sign, s_m: 64, offset_m: 2.3, value_kmh: 10}\n"
                    "  - {kind: speed_sign, s_m: 90, offset_m: 2.3, value_kmh: 20}\n")
    saved = tmp_path / "saved.yaml"
    code = main(["sim", "--scenario", str(path), "--save-scenario", str(saved), "--result",
                 str(tmp_path / "result.json"), "--no-progress"])
    out = capsys.readouterr().out
    limits = [limit for _, _, limit in json.loads((tmp_path / "result.json").read_text())["scenarios"][0]["states"]]
    changes = [limit for k, limit in enumerate(limits) if k == 0 or limit != limits[k - 1]]
    print(out, changes)
    assert code == 0 and "passed" in out
    assert changes == [20, 10, 20]
    assert load_scenario_file(saved) == load_scenario_file(path)

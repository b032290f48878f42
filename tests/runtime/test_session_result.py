"""One result schema for every drive session: a simulated drive and a replay of its recording are checked
against it here, a live drive in test_live_drive.py. A result that breaks the schema is refused, naming the
field."""

import json

import pytest

from kartpilot.core.errors import ConfigError, DataError
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.replay import replay_recording
from kartpilot.runtime.session import SCHEMA_VERSION, SessionOutputs, SessionResult
from kartpilot.runtime.simulate import run_supervised_drive
from kartpilot.sim.simulator import SimConfig

SIM = SimConfig(track="sdc-assen", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=10.0, seed=1)


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    folder = tmp_path_factory.mktemp("session")
    drive = run_supervised_drive(SIM, "lanes", bus="virtual", duration_s=2.0,
                                 outputs=SessionOutputs(record_dir=folder / "drive"))
    replay = replay_recording(folder / "drive", "lanes", StackConfig(),
                              outputs=SessionOutputs(record_dir=folder / "replay"))
    return {"sim": json.loads((folder / "drive" / "result.json").read_text()), "sim_returned": drive.payload,
            "replay": json.loads((folder / "replay" / "replay.json").read_text()), "replay_returned": replay.to_json()}


def test_a_simulated_drive_and_its_replay_share_one_schema(results):
    sim, replay = SessionResult.from_json(results["sim"]), SessionResult.from_json(results["replay"])
    assert results["sim"] == results["sim_returned"] and results["replay"] == results["replay_returned"]
    assert (sim.backend, replay.backend) == ("sim", "replay")
    assert sim.schema_version == replay.schema_version == SCHEMA_VERSION
    assert sim.pipeline == replay.pipeline == "lanes" and sim.vehicle == replay.vehicle == "sdc-kart"
    assert sim.steps == replay.steps == 20  # the replay saw every set the drive recorded
    assert sim.final_state == "autonomous" and replay.final_state is None  # a replay is not supervised
    for session in (sim, replay):
        assert set(session.stage_ms) == {"source", "policy", "sinks"}
        assert all(s["p50"] <= s["p90"] <= s["p99"] <= s["max"] for s in session.stage_ms.values())
    assert "distance_m" in sim.details and sim.details["can"]["protocol"] == "rdw"
    assert replay.details["rate_hz"] == pytest.approx(10.0) and replay.details["unreadable_frames"] == 0


@pytest.mark.parametrize(("change", "message"), [
    ({"schema_version": 0}, "schema_version 0"),
    ({"steps": "20"}, "steps is str"),
    ({"final_state": 1}, "final_state is int"),
    ({"backend": "cloud"}, "backend 'cloud'"),
    ({"stage_ms": {"policy": {"p50": 1.0}}}, "stage_ms.policy must hold mean, p50, p90, p99, max"),
    ({"stage_ms": {"policy": {"mean": float("nan"), "p50": 1, "p90": 1, "p99": 1, "max": 1}}}, "finite"),
    ({"transitions": [{"state": "fault"}]}, "transitions\\[0\\]"),
])
def test_a_result_that_breaks_the_schema_is_refused_naming_the_field(results, change, message):
    with pytest.raises(DataError, match=message):
        SessionResult.from_json({**results["sim"], **change})


def test_a_missing_field_is_named(results):
    payload = dict(results["replay"])
    del payload["ended"]
    with pytest.raises(DataError, match="ended missing"):
        SessionResult.from_json(payload)


def test_details_may_not_shadow_a_common_field():
    with pytest.raises(ValueError, match="steps"):
        SessionResult("sim", "lanes", "sdc-kart", 1, "", None, None, 0, {}, details={"steps": 2}).to_json()


def test_an_output_that_could_only_fail_at_the_end_is_refused_before_the_drive(tmp_path, capsys):
    """A result path that is a folder (or under a file) used to fail after the whole drive; now nothing runs and
    nothing is half written."""
    from kartpilot.cli.main import main

    (tmp_path / "a_folder").mkdir()
    (tmp_path / "a_file").write_text("")
    for target, message in ((tmp_path / "a_folder", "is a folder, not a file to write"),
                            (tmp_path / "a_file" / "result.json", "is a file, not a folder")):
        assert main(["drive", "--sim", "sdc-assen", "--vehicle", "sdc-kart", "--pipeline", "lanes", "--duration",
                     "60", "--result", str(target), "--record", str(tmp_path / "rec"), "--no-progress"]) == 2
        error = capsys.readouterr().err
        assert error.startswith("kartpilot: ") and message in error and len(error.strip().splitlines()) == 1
        assert not (tmp_path / "rec").exists()
    with pytest.raises(ConfigError, match="the drive log would go to"):
        SessionOutputs(drive_log=tmp_path / "a_file" / "log.csv").check()

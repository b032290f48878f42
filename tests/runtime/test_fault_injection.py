"""Fault injection: for every kind, the stop command reaches the bus in time, the supervisor says why,
and the recording is intact. Simulated drives on python-can's virtual bus, lanes pipeline on sdc-assen
(centre camera) and stereo VO on straight20."""

import json

import can
import numpy as np
import pytest

from kartpilot.actuation.can_bus import decode, load_dbc
from kartpilot.cli.main import main
from kartpilot.planning.reference_path import PathConfig, build_reference_path
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.faults import BUS_OFF_S, parse_injection
from kartpilot.runtime.simulate import run_supervised_drive
from kartpilot.sim.simulator import SimConfig

RATE = 15.0
PERIOD = 1.0 / RATE
FAULT_AT = 1.0
LANES = SimConfig(track="sdc-assen", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=RATE, seed=1,
                  speed_mode_mps=15 / 3.6)

# kind -> (the longest the stop may take, words of the supervisor's reason)
EXPECTED = {
    "camera-freeze": (PERIOD, "camera center: frozen frame"),
    "black-frame": (PERIOD, "camera center: black frame"),
    "gamepad-unplug": (PERIOD, "operator link lost"),
    "stage-exception": (PERIOD, "the pipeline raised RuntimeError"),
    # the ECUs report every period; their status is missed after 2.5 periods, then the stop goes out
    "heartbeat-loss": (2.5 * PERIOD + 2 * PERIOD, "no status from the steer ECU"),
    # nothing can be sent while the controller is bus-off: the ECUs brake on their own after 2.5 periods
    "can-bus-off": (2.5 * PERIOD + PERIOD, "CAN transmit failed (bus-off"),
}


def _check_recording(folder, run) -> RecordingReader:
    reader = RecordingReader(folder)
    assert reader.closed
    assert len(reader.commands()) == run.payload["steps"]
    states = [row["state"] for row in reader.outputs("supervisor")]
    assert states[0] == "autonomous" and states[-1] == "fault"
    assert len(reader.can_frames()) > 0
    assert len(reader.frames("center")) == run.payload["steps"]
    return reader


@pytest.mark.parametrize("kind", list(EXPECTED))
def test_a_fault_stops_the_kart_in_time_with_its_reason_and_the_recording_intact(kind, tmp_path):
    limit_s, reason = EXPECTED[kind]
    run = run_supervised_drive(LANES, "lanes", bus="virtual", duration_s=4.0,
                               injections=[parse_injection(f"{kind}@{FAULT_AT}")], record_dir=tmp_path / "rec")
    payload = run.payload
    print(kind, payload["transitions"][-1], f"fault to stop {payload['fault_to_stop_s']} s by {payload['stop_by']}")
    assert payload["final_state"] == "fault" and reason in payload["transitions"][-1]["reason"]
    assert payload["fault_to_stop_s"] is not None and payload["fault_to_stop_s"] <= limit_s + 1e-6
    assert payload["transitions"][-1]["t_s"] >= FAULT_AT - 1e-6  # nothing before the fault
    reader = _check_recording(tmp_path / "rec", run)
    after = [c for c in reader.commands() if c.stamp_ns * 1e-9 > FAULT_AT + limit_s + 1e-6]
    assert after and all(c.brake == 1.0 and c.throttle == 0.0 for c in after)  # and the stop stays
    if kind == "stage-exception":
        assert run.error is not None and "RuntimeError" in (tmp_path / "rec" / "error.txt").read_text()
    if kind == "can-bus-off":
        assert payload["stop_by"] == "ecu-timeout" and payload["can"]["tx_errors"] > 0
        db = load_dbc()  # once the bus came back, it carried stops only
        brakes = [decode(db, can.Message(arbitration_id=i, data=d))[1]["Brake"]
                  for t, direction, i, d in reader.can_frames()
                  if direction == "tx" and i == 0x102 and t * 1e-9 >= FAULT_AT + BUS_OFF_S]
        assert brakes and all(b == 1.0 for b in brakes)


def test_a_vo_failure_stops_the_kart_once_the_localizer_gives_up(tmp_path):
    line = np.column_stack([np.linspace(0.0, 18.0, 181), np.zeros(181)])
    reference = build_reference_path(line, PathConfig(cruise_speed_mps=0.8))
    config = SimConfig(track="straight20", vehicle="rc-kart", cameras=("left", "right"), camera_rate_hz=10.0, seed=1)
    run = run_supervised_drive(config, "stereo-vo", bus="virtual", duration_s=4.0, reference=reference,
                               injections=[parse_injection(f"vo-failure@{FAULT_AT}")], record_dir=tmp_path / "rec")
    payload = run.payload
    print(payload["transitions"][-1], f"fault to stop {payload['fault_to_stop_s']} s")
    assert payload["final_state"] == "fault" and "localisation lost" in payload["transitions"][-1]["reason"]
    # by design a failed frame is bridged by the motion model for up to max_bridge_s (0.5 s), then lost
    assert payload["fault_to_stop_s"] <= 0.5 + 0.1 + 1e-6
    reader = RecordingReader(tmp_path / "rec")
    assert reader.closed and "bridged" in {row["status"] for row in reader.outputs("pose")}


def test_the_cli_exits_non_zero_after_a_stage_exception_with_the_result_and_recording_written(tmp_path, capsys):
    result = tmp_path / "r.json"
    code = main(["drive", "--sim", "sdc-assen", "--pipeline", "lanes", "--bus", "virtual", "--duration", "3",
                 "--rate", "15", "--inject", "stage-exception@0.5", "--result", str(result), "--record",
                 str(tmp_path / "rec"), "--no-progress", "--config", str(_centre_only(tmp_path))])
    captured = capsys.readouterr()
    assert code == 1
    assert captured.err.strip().splitlines()[-1].startswith("kartpilot: error: the pipeline failed (RuntimeError")
    assert "Traceback" not in captured.err
    data = json.loads(result.read_text())
    assert data["transitions"][-1]["state"] == "fault" and data["fault_to_stop_s"] <= PERIOD
    assert RecordingReader(tmp_path / "rec").closed
    assert main(["drive", "--sim", "sdc-assen", "--pipeline", "lanes", "--inject", "camera-melt@1"]) == 1
    assert "the kind is one of camera-freeze" in capsys.readouterr().err


def _centre_only(tmp_path):
    path = tmp_path / "centre.yaml"
    path.write_text("sim: {cameras: [center]}\n")
    return path

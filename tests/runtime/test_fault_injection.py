"""Fault injection: for every kind, the stop command reaches the kart in time, the supervisor says why,
and the recording is intact. Simulated drives on python-can's virtual bus with the simulated ECUs: the
lanes pipeline on sdc-assen (centre camera) on the RDW kart's protocol, the bus faults on our own
protocol too; stereo VO on straight20."""

import json

import can
import numpy as np
import pytest

from kartpilot.actuation.can_bus import CanConfig
from kartpilot.actuation.kartpilot_protocol import decode, load_dbc
from kartpilot.actuation.rdw_protocol import decode_rdw, load_rdw_dbc
from kartpilot.cli.main import main
from kartpilot.planning.reference_path import PathConfig, build_reference_path
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.faults import BUS_OFF_S, parse_injection
from kartpilot.runtime.pipelines import Route
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import BUS_STEP_S, run_supervised_drive
from kartpilot.sim.simulator import SimConfig

RATE = 15.0
PERIOD = 1.0 / RATE
FAULT_AT = 1.0
SEND_S = 1 / 25  # the actuator's period
LANES = SimConfig(track="sdc-assen", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=RATE, seed=1,
                  speed_mode_mps=15 / 3.6)
RDW, OURS = CanConfig(), CanConfig(protocol="kartpilot")
STATUS_S = OURS.status_timeout_s

# (protocol, kind) -> (the longest the stop may take, words of the supervisor's reason). A fault seen at a
# loop step stops the kart at once: it reaches the ECUs at the bus's next step.
EXPECTED = {
    ("rdw", "camera-freeze"): (PERIOD + BUS_STEP_S, "camera center: frozen frame"),
    ("rdw", "black-frame"): (PERIOD + BUS_STEP_S, "camera center: black frame"),
    ("rdw", "gamepad-unplug"): (PERIOD + BUS_STEP_S, "operator link lost"),
    ("rdw", "stage-exception"): (PERIOD + BUS_STEP_S, "the pipeline raised RuntimeError"),
    # the kart falls silent: the steering sensor's 0.2 s are the first to run out
    ("rdw", "heartbeat-loss"): (RDW.rdw.sensor_timeout_s + PERIOD + BUS_STEP_S, "no steering sensor (0x1e5)"),
    ("rdw", "steering-sensor-loss"): (RDW.rdw.sensor_timeout_s + PERIOD + BUS_STEP_S, "no steering sensor (0x1e5)"),
    ("rdw", "steering-sensor-range"): (0.01 + PERIOD + BUS_STEP_S, "steering sensor out of range"),
    ("rdw", "ecu-error"): (0.05 + PERIOD + BUS_STEP_S, "the steering ECU reports error 3"),
    # nothing can be sent while bus-off: the motor ECU idles after 200 ms; the brake comes when the bus is back
    ("rdw", "can-bus-off"): (BUS_OFF_S + PERIOD + BUS_STEP_S, "CAN transmit failed (bus-off"),
    ("kartpilot", "heartbeat-loss"): (STATUS_S + PERIOD + BUS_STEP_S, "no status from the steer ECU"),
    ("kartpilot", "ecu-error"): (0.02 + PERIOD + BUS_STEP_S, "the steer ECU reports actuator"),
    # nothing can be sent while bus-off: our ECUs brake on their own once the heartbeat is missing
    ("kartpilot", "can-bus-off"): (0.1 + SEND_S + BUS_STEP_S, "CAN transmit failed (bus-off"),
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


@pytest.mark.parametrize(("protocol", "kind"), list(EXPECTED))
def test_a_fault_stops_the_kart_in_time_with_its_reason_and_the_recording_intact(protocol, kind, tmp_path):
    limit_s, reason = EXPECTED[protocol, kind]
    run = run_supervised_drive(LANES, "lanes", StackConfig(can=CanConfig(protocol=protocol)), bus="virtual",
                               duration_s=3.0, injections=[parse_injection(f"{kind}@{FAULT_AT}")],
                               outputs=SessionOutputs(record_dir=tmp_path / "rec"))
    payload = run.payload
    print(protocol, kind, payload["transitions"][-1], f"fault to stop {payload['fault_to_stop_s']} s by "
          f"{payload['stop_by']}")
    assert payload["can"]["protocol"] == protocol
    assert payload["final_state"] == "fault" and reason in payload["transitions"][-1]["reason"]
    assert payload["fault_to_stop_s"] is not None and payload["fault_to_stop_s"] <= limit_s + 1e-6
    assert payload["transitions"][-1]["t_s"] >= FAULT_AT - 1e-6  # nothing before the fault
    reader = _check_recording(tmp_path / "rec", run)
    after = [c for c in reader.commands() if c.stamp_ns * 1e-9 > FAULT_AT + limit_s + 1e-6]
    assert after and all(c.brake == 1.0 and c.throttle == 0.0 for c in after)  # and the stop stays
    if kind == "stage-exception":
        assert run.error is not None and "RuntimeError" in (tmp_path / "rec" / "error.txt").read_text()
    if kind == "can-bus-off":
        assert payload["can"]["tx_errors"] > 0
        sent = [(t, i, d) for t, direction, i, d in reader.can_frames()
                if direction == "tx" and t * 1e-9 >= FAULT_AT + BUS_OFF_S]
        if protocol == "kartpilot":
            assert payload["stop_by"] == "ecu-timeout"
            db = load_dbc()  # once the bus came back, it carried stops only
            brakes = [decode(db, can.Message(arbitration_id=i, data=d))[1]["Brake"] for _, i, d in sent if i == 0x102]
            assert brakes and all(b == 1.0 for b in brakes)
        else:
            rdw = load_rdw_dbc()
            brakes = [decode_rdw(rdw, can.Message(arbitration_id=i, data=d))[1]["BrakePercent"]
                      for _, i, d in sent if i == 0x110]
            assert brakes and all(b == 100 for b in brakes)


def test_a_silent_loop_is_stopped_by_the_actuator_before_the_motor_ecu_idles(tmp_path):
    run = run_supervised_drive(LANES, "lanes", bus="virtual", duration_s=2.0,
                               injections=[parse_injection(f"loop-stall@{FAULT_AT}")],
                               outputs=SessionOutputs(record_dir=tmp_path / "rec"))
    payload = run.payload
    print(f"fault to stop {payload['fault_to_stop_s']} s by {payload['stop_by']}")
    assert payload["can"]["quiet_stops"] == 1 and payload["stop_by"] == "command"  # ours, not the motor ECU's idle
    assert payload["fault_to_stop_s"] <= RDW.command_timeout_s + 2 * BUS_STEP_S + 1e-6


def test_a_vo_failure_stops_the_kart_once_the_localizer_gives_up(tmp_path):
    line = np.column_stack([np.linspace(0.0, 18.0, 181), np.zeros(181)])
    reference = build_reference_path(line, PathConfig(cruise_speed_mps=0.8))
    config = SimConfig(track="straight20", vehicle="rc-kart", cameras=("left", "right"), camera_rate_hz=10.0, seed=1)
    run = run_supervised_drive(config, "stereo-vo", bus="virtual", duration_s=4.0, route=Route(reference),
                               injections=[parse_injection(f"vo-failure@{FAULT_AT}")],
                               outputs=SessionOutputs(record_dir=tmp_path / "rec"))
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

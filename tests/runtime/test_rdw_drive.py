"""The acceptance drive on the RDW kart's own protocol: `kartpilot drive --sim sdc-assen --vehicle sdc-kart
--pipeline lanes --speed-mode 15 --bus virtual --duration 20 --record DIR`. The commands go out at 25 Hz and
nothing else is sent, every frame the kart reports is heard, its speed is the simulator's within 0x440's
resolution, the referee has nothing to say, and `kartpilot can monitor` reads the recording back."""

import json

import can
import numpy as np
import pytest

from kartpilot.actuation.rdw_protocol import decode_rdw, load_rdw_dbc
from kartpilot.cli.main import main
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.config import load_stack_config
from kartpilot.runtime.replay import replay_recording

COMMANDS = {0x110, 0x220, 0x330}
REPORTS = {0x440, 0x1E5, 0x710, 0x720, 0x730}


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rdw") / "drive"
    code = main(["drive", "--sim", "sdc-assen", "--vehicle", "sdc-kart", "--pipeline", "lanes", "--speed-mode", "15",
                 "--bus", "virtual", "--duration", "12", "--rate", "15", "--record", str(folder), "--no-progress",
                 "--perfect-camera"])  # the protocol's test: the perfect camera, for the suite's time
    assert code == 0
    return folder


def test_only_the_three_commands_are_sent_and_each_at_25_hz(drive):
    frames = RecordingReader(drive).can_frames()
    sent = {}
    for stamp, direction, frame_id, _ in frames:
        if direction == "tx":
            sent.setdefault(frame_id, []).append(stamp)
    assert set(sent) == COMMANDS
    for frame_id, stamps in sent.items():
        gaps = np.diff(np.array(stamps[:-1])) * 1e-9  # the last is the stop sent at the close
        rate = len(gaps) / (stamps[-2] - stamps[0]) * 1e9
        print(f"{frame_id:#x}: {rate:.2f} Hz, gaps {gaps.min() * 1e3:.1f} to {gaps.max() * 1e3:.1f} ms")
        assert rate == pytest.approx(25.0, rel=0.10)
        assert np.mean(np.abs(1.0 / gaps - 25.0) <= 2.5) >= 0.99  # nearly every gap within 10 %


def test_every_report_of_the_kart_is_heard_and_its_speed_is_the_simulator_s(drive):
    frames = RecordingReader(drive).can_frames()
    heard = {frame_id for _, direction, frame_id, _ in frames if direction == "rx"}
    assert heard == REPORTS
    result = json.loads((drive / "result.json").read_text())
    print(result["reason"], result["distance_m"], result["can"])
    assert not result["disqualified"] and result["distance_m"] > 30.0  # 12 s from a standstill, up to 15 km/h
    assert result["can"]["protocol"] == "rdw" and result["can"]["speed_error_kmh_max"] <= 0.05 + 1e-9
    db = load_rdw_dbc()
    speeds = [decode_rdw(db, can.Message(arbitration_id=i, data=d))[1]["Speed"] for _, direction, i, d in frames
              if direction == "rx" and i == 0x440]
    assert result["can"]["speed_reports"] - 3 <= len(speeds) <= result["can"]["speed_reports"]  # the last unpolled
    assert 5.0 < max(speeds) <= 15.0 + 0.05  # it drove, never above the 15 km/h speed mode, as the kart measured
    kart = RecordingReader(drive).outputs("kart")
    assert kart and kart[-1]["Speed"] == pytest.approx(speeds[-1], abs=1.5) and kart[-1]["Idle"] == 0


def test_can_monitor_reads_the_drive_back(drive, tmp_path, capsys):
    assert main(["can", "monitor", "--recording", str(drive), "--json", str(tmp_path / "traffic.json")]) == 0
    out = capsys.readouterr().out
    print(out)
    assert "protocol rdw" in out and "SteeringSensor" in out
    rows = {(row["frame_id"], row["direction"]): row for row in json.loads((tmp_path / "traffic.json").read_text())}
    assert rows["0x220", "tx"]["rate_hz"] == pytest.approx(25.0, rel=0.05)
    assert rows["0x1e5", "rx"]["rate_hz"] == pytest.approx(100.0, rel=0.05)
    assert all(not row["faults"] for row in rows.values())


@pytest.mark.slow
def test_with_a_speed_the_lane_follower_holds_it_on_the_kart_s_measured_speed(tmp_path):
    """Closed-loop speed: the follower asks for 3 m/s on a straight and the kart's 0x440 says it holds it (the
    open-loop throttle of the drive above tops out wherever the kart's speed mode and the road put it). At 15 Hz,
    as the drive above: the speed loop runs at the camera's rate, on the kart's latest report."""
    config = tmp_path / "stack.yaml"
    config.write_text("lane_policy:\n  speed_mps: 3.0\n")
    folder = tmp_path / "drive"
    assert main(["drive", "--sim", "sdc-assen", "--vehicle", "sdc-kart", "--pipeline", "lanes", "--speed-mode", "15",
                 "--bus", "virtual", "--duration", "8", "--rate", "15", "--config", str(config), "--record",
                 str(folder), "--no-progress", "--perfect-camera"]) == 0
    kart = RecordingReader(folder).outputs("kart")
    settled = np.array([row["Speed"] for row in kart if row["stamp_ns"] > 4e9]) / 3.6
    print(f"measured speed after 4 s: {settled.mean():.2f} m/s (min {settled.min():.2f}, max {settled.max():.2f})")
    assert settled.mean() == pytest.approx(3.0, abs=0.15) and settled.max() < 3.4
    # replayed, the pipeline is told what the kart measured at each step, as it was live: the closed loop's
    # commands come out again (without it, the replay would give the open-loop throttle)
    replayed = replay_recording(folder, "lanes", load_stack_config(config)).commands
    driven = RecordingReader(folder).commands()
    assert len(replayed) == len(driven)
    assert max(abs(a.throttle - b.throttle) + abs(a.brake - b.brake) + abs(a.steer_rad - b.steer_rad)
               for a, b in zip(replayed, driven, strict=True)) < 1e-5  # the recording keeps 6 digits

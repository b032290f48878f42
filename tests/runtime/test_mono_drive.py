"""The mono-vo pipeline closed-loop in the simulator: the SDC kart's centre camera alone, monocular VO fused
with place fixes from a taught drive, through the supervisor and the CAN layer."""

from dataclasses import replace

import pytest

from kartpilot.cli.main import main
from kartpilot.odometry.places import build_places
from kartpilot.planning.reference_path import PathConfig
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.path_policy import DriveConfig
from kartpilot.runtime.pipelines import Route
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation, run_supervised_drive
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.render import RenderConfig
from kartpilot.sim.simulator import SimConfig

SIM = SimConfig(track="sdc-assen", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=10.0,
                render=RenderConfig(scenery_spacing_m=15.0))


@pytest.mark.slow
def test_one_camera_follows_the_taught_drive_through_the_bends_on_place_fixes(tmp_path):
    """Taught at 5 m/s on the centre line over 55 s, repeated for 50 s at 5 m/s: about 230 m of sdc-assen, through
    its first sharp bend and the hairpin, where monocular VO alone (even metric) would have left the track. The
    simulated clock waits for the pipeline, so a busy machine changes nothing here. The whole lap is measured by
    benchmarks/mono_drive.py."""
    run_simulation(replace(SIM, max_time_s=55.0, seed=1), "centerline",
                   driver_config=CenterlineDriverConfig(speed_mps=5.0),
                   outputs=SessionOutputs(record_dir=tmp_path / "teach"))
    teach = RecordingReader(tmp_path / "teach")
    places = build_places(teach.posed_frames("center", teach.camera_poses("center")), teach.cameras["center"],
                          "center")
    drive = DriveConfig(path=PathConfig(cruise_speed_mps=5.0, max_lateral_accel_mps2=2.0))
    stack = StackConfig(drive=drive)
    run = run_supervised_drive(replace(SIM, seed=2), "mono-vo", stack, bus="virtual", duration_s=50.0,
                               route=Route(places=places))
    payload = run.payload
    print(f"\nmono-vo: {payload['distance_m']:.1f} m, centre offset max {payload['max_center_offset_m']:.2f} m, "
          f"{payload['relocalised_frames']} place fixes used, {payload['bridged_frames']} bridged")
    assert run.error is None and not payload["disqualified"]
    assert payload["final_state"] == "autonomous"
    assert payload["distance_m"] > 200.0
    assert payload["relocalised_frames"] >= 150
    assert payload["max_center_offset_m"] < 0.5


def test_the_mono_pipeline_without_a_database_is_a_one_line_error(capsys):
    assert main(["drive", "--pipeline", "mono-vo", "--sim", "sdc-assen", "--vehicle", "sdc-kart"]) == 1
    assert "give --places" in capsys.readouterr().err

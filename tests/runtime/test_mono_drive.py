"""The mono-vo pipeline closed-loop in the simulator: the SDC kart's centre camera alone, monocular VO fused
with place fixes from a taught drive, through the supervisor and the CAN layer."""

from dataclasses import replace

import pytest
from tests.conftest import GreyFrames, track_starting_at

from kartpilot.cli.main import main
from kartpilot.core.vehicle import get_vehicle
from kartpilot.odometry.places import build_places
from kartpilot.planning.reference_path import PathConfig
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.path_policy import DriveConfig
from kartpilot.runtime.pipelines import Route
from kartpilot.runtime.simulate import run_simulation, run_supervised_drive
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.render import RenderConfig
from kartpilot.sim.simulator import SimConfig, perfect_camera

# the perfect camera: the place fixes' geometry is this test's (the real camera's VO: benchmarks/honest_camera.py)
SIM = SimConfig(track="sdc-assen", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=10.0,
                render=RenderConfig(scenery_spacing_m=15.0), effects=perfect_camera())


@pytest.mark.slow
def test_one_camera_follows_the_taught_drive_through_the_bends_on_place_fixes(tmp_path):
    """Taught at 5 m/s on the centre line, repeated at 5 m/s, both from 80 m along sdc-assen (the track as it is,
    its start moved): the straight into its first sharp bend, the bend (110 to 190 m, down to a 25 m radius), and
    out of it, where monocular VO alone (even metric) would leave the track. The straight before 80 m proves
    nothing the straight after the bend does not. The simulated clock waits for the pipeline, so a busy machine
    changes nothing here. The whole lap is measured by benchmarks/mono_drive.py."""
    sim = replace(SIM, track=track_starting_at(tmp_path, "sdc-assen", 80.0))
    frames = GreyFrames("center")  # the teach drive's frames as it draws them (a recording's: the CLI's teach test)
    teach = run_simulation(replace(sim, max_time_s=32.0, seed=1), "centerline",
                           driver_config=CenterlineDriverConfig(speed_mps=5.0), taps=(frames,))
    places = build_places(frames.posed(teach.ground_truth), get_vehicle("sdc-kart").camera("center"), "center")
    drive = DriveConfig(path=PathConfig(cruise_speed_mps=5.0, max_lateral_accel_mps2=2.0))
    stack = StackConfig(drive=drive)
    run = run_supervised_drive(replace(sim, seed=2), "mono-vo", stack, bus="virtual", duration_s=28.0,
                               route=Route(places=places))
    payload = run.payload
    print(f"\nmono-vo: {payload['distance_m']:.1f} m, centre offset max {payload['max_center_offset_m']:.2f} m, "
          f"{payload['relocalised_frames']} place fixes used, {payload['bridged_frames']} bridged")
    assert run.error is None and not payload["disqualified"]
    assert payload["final_state"] == "autonomous"
    assert payload["distance_m"] > 120.0  # past 200 m along the route: the bend behind it
    assert payload["relocalised_frames"] >= 84  # 0.3 of the 280 frames
    assert payload["max_center_offset_m"] < 0.5


def test_the_mono_pipeline_without_a_database_is_a_one_line_error(capsys):
    assert main(["drive", "--pipeline", "mono-vo", "--sim", "sdc-assen", "--vehicle", "sdc-kart"]) == 1
    assert "give --places" in capsys.readouterr().err

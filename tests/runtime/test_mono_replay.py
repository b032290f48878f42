"""The one-camera kart on a recording: places built from a first drive, a second drive replayed through the
mono-vo pipeline (`kartpilot replay --pipeline mono-vo --places DB`), its poses against the simulator's truth."""

import math
from dataclasses import replace

import numpy as np
import pytest

from kartpilot.cli.main import main
from kartpilot.odometry.mono_localizer import place_ground_poses
from kartpilot.odometry.places import build_places
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.render import RenderConfig
from kartpilot.sim.simulator import SimConfig

SIM = SimConfig(track="sdc-assen", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=10.0,
                render=RenderConfig(scenery_spacing_m=15.0))


@pytest.mark.slow
def test_a_second_drive_replayed_on_one_camera_stays_on_the_truth(tmp_path):
    """Taught over 45 s at 5 m/s on the centre line; the second drive (another seed, 4 m/s, weaving 0.3 m about
    the centre line) replayed through mono-vo: every pose within 0.3 m of the truth across the track."""
    run_simulation(replace(SIM, max_time_s=45.0, seed=1), "centerline",
                   driver_config=CenterlineDriverConfig(speed_mps=5.0),
                   outputs=SessionOutputs(record_dir=tmp_path / "teach"))
    teach = RecordingReader(tmp_path / "teach")
    database = build_places(teach.posed_frames("center", teach.camera_poses("center")), teach.cameras["center"],
                            "center")
    database.save(tmp_path / "places.npz")
    run_simulation(replace(SIM, max_time_s=35.0, seed=2), "centerline",
                   driver_config=CenterlineDriverConfig(speed_mps=4.0, weave_amplitude_m=0.3),
                   outputs=SessionOutputs(record_dir=tmp_path / "second"))
    assert main(["replay", str(tmp_path / "second"), "--pipeline", "mono-vo", "--places", str(tmp_path / "places.npz"),
                 "--out", str(tmp_path / "replayed")]) == 0

    second = RecordingReader(tmp_path / "second")
    truth = second.groundtruth()
    true = place_ground_poses(truth.poses, second.cameras["center"].pose_body_cam_array, database.poses_world_cam[0])
    poses = [row for row in RecordingReader(tmp_path / "replayed").outputs("pose") if row["status"] == "ok"]
    along, across = [], []
    for row in poses:
        i = int(np.argmin(np.abs(truth.stamps_s - int(row["stamp_ns"]) * 1e-9)))
        x, y, yaw = true[i]
        dx, dy = float(row["x_m"]) - x, float(row["y_m"]) - y
        along.append(abs(math.cos(yaw) * dx + math.sin(yaw) * dy))
        across.append(abs(-math.sin(yaw) * dx + math.cos(yaw) * dy))
    print(f"\nmono-vo replay: {len(poses)} poses over {len(truth.poses)} frames; across the track median "
          f"{np.median(across):.3f} m, max {np.max(across):.3f} m; along the track median {np.median(along):.3f} m, "
          f"max {np.max(along):.3f} m")
    assert len(poses) >= 0.9 * len(second.frames("center"))
    assert np.max(across) < 0.3  # what the steering depends on
    # along the track the place fixes are ambiguous on straights and nothing measures the distance driven (a
    # replay of a drive without the kart's speed sensor): up to 1.1 m here, not yet the 0.3 m the kart should hold
    assert np.max(along) < 1.5

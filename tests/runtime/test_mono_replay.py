"""The one-camera kart on a recording: places built from a first drive, a second drive replayed through the
mono-vo pipeline (`kartpilot replay --pipeline mono-vo --places DB`), its poses against the simulator's truth."""

import math
from dataclasses import replace

import numpy as np
import pytest

from kartpilot.cli.main import main
from kartpilot.core.trajectory import Trajectory
from kartpilot.odometry.mono_localizer import place_ground_poses
from kartpilot.odometry.places import build_places, load_places
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.render import RenderConfig
from kartpilot.sim.simulator import SimConfig, perfect_camera

# the centre camera behind a real lens: the recordings' calibration carries its coefficients, the images are bent
# (the perfect camera otherwise: the replay is the test, and the suite's time)
LENS = (-0.28, 0.08, 0.0005, -0.0005, 0.0)
SIM = SimConfig(track="sdc-assen", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=10.0,
                render=RenderConfig(scenery_spacing_m=15.0), effects=replace(perfect_camera(), lens_distortion=LENS))


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """Taught over 20 s at 5 m/s on the centre line (95 m); a second drive (another seed, 4 m/s, weaving 0.3 m about
    the centre line) over 10 s: 35 m, three of the weave's periods, all of it on the taught stretch with 60 m to
    spare (15 s and five periods proved no more, for half as much again of the module's time: two replays of it)."""
    folder = tmp_path_factory.mktemp("mono-replay")
    run_simulation(replace(SIM, max_time_s=20.0, seed=1), "centerline",
                   driver_config=CenterlineDriverConfig(speed_mps=5.0),
                   outputs=SessionOutputs(record_dir=folder / "teach"))
    run_simulation(replace(SIM, max_time_s=10.0, seed=2), "centerline",
                   driver_config=CenterlineDriverConfig(speed_mps=4.0, weave_amplitude_m=0.3),
                   outputs=SessionOutputs(record_dir=folder / "second"))
    return folder


@pytest.mark.slow
def test_a_second_drive_replayed_on_one_camera_stays_on_the_truth(drives, tmp_path):
    """The second drive replayed through mono-vo against places tagged with the teach drive's truth, its poses
    against the truth along and across the track. Both drives through the lens: the database and the pipeline
    undistort the images the same way."""
    teach = RecordingReader(drives / "teach")
    assert teach.cameras["center"].distortion == LENS
    database = build_places(teach.posed_frames("center", teach.camera_poses("center")), teach.cameras["center"],
                            "center")
    database.save(tmp_path / "places.npz")
    assert database.info["undistorted"] == list(LENS) and database.camera.distortion == ()
    # a replay can afford a place query on every frame until the position has settled
    (tmp_path / "stack.yaml").write_text("drive:\n  mono:\n    settle_at_start: true\n")
    assert main(["replay", str(drives / "second"), "--pipeline", "mono-vo", "--places", str(tmp_path / "places.npz"),
                 "--out", str(tmp_path / "replayed"), "--config", str(tmp_path / "stack.yaml")]) == 0

    second = RecordingReader(drives / "second")
    truth = second.groundtruth()
    true = place_ground_poses(truth.poses, second.cameras["center"].pose_body_cam_array, database.poses_world_cam[0])
    poses = [row for row in RecordingReader(tmp_path / "replayed").outputs("pose") if row["status"] == "ok"]
    along, across, driven = [], [], []
    for row in poses:
        i = int(np.argmin(np.abs(truth.stamps_s - int(row["stamp_ns"]) * 1e-9)))
        x, y, yaw = true[i]
        dx, dy = float(row["x_m"]) - x, float(row["y_m"]) - y
        along.append(abs(math.cos(yaw) * dx + math.sin(yaw) * dy))
        across.append(abs(-math.sin(yaw) * dx + math.cos(yaw) * dy))
        driven.append(math.hypot(x - true[0][0], y - true[0][1]))
    moved = np.array(driven) > database.config.spacing_m
    print(f"\nmono-vo replay: {len(poses)} poses over {len(truth.poses)} frames; across the track median "
          f"{np.median(across):.3f} m, max {np.max(across):.3f} m; along the track median {np.median(along):.3f} m, "
          f"max {np.max(along):.3f} m; {np.count_nonzero(~moved)} poses before the first metre, along the track "
          f"at most {np.max(np.array(along)[~moved], initial=0.0):.3f} m there")
    assert len(poses) >= 0.9 * len(second.frames("center"))
    assert np.median(across) < 0.03 and np.max(across) < 0.3
    # standing on the database's first place, the fixes are ambiguous along the track (no second place within
    # the road registration's reach agrees), and they say so; once the kart has moved, two places agree
    assert np.median(along) < 0.05 and np.max(np.array(along)[moved]) < 0.3


@pytest.mark.slow
def test_places_from_monocular_vo_need_no_ground_truth(drives, tmp_path, capsys):
    """A real drive has no ground truth: the teach drive's places tagged with monocular VO over the recording
    itself (the ground plane's scale), then the second drive replayed against them."""
    assert main(["places", "build", str(drives / "teach"), "--positions-from", "mono-vo", "--out",
                 str(tmp_path / "places.npz")]) == 0
    assert "positions from monocular VO over the recording" in capsys.readouterr().out
    database = load_places(tmp_path / "places.npz")
    truth = RecordingReader(drives / "teach").camera_poses("center")
    vo_length = Trajectory.from_poses(database.poses_world_cam).path_length_m
    true_length = Trajectory.from_poses(truth.poses[:: max(len(truth) // len(database), 1)]).path_length_m
    print(f"\nplaces from mono VO: {len(database)} over {vo_length:.1f} m (the truth: {true_length:.1f} m)")
    assert vo_length == pytest.approx(true_length, rel=0.1)
    # a replay can afford a place query on every frame until the position has settled
    (tmp_path / "stack.yaml").write_text("drive:\n  mono:\n    settle_at_start: true\n")
    assert main(["replay", str(drives / "second"), "--pipeline", "mono-vo", "--places", str(tmp_path / "places.npz"),
                 "--out", str(tmp_path / "replayed"), "--config", str(tmp_path / "stack.yaml")]) == 0
    poses = RecordingReader(tmp_path / "replayed").outputs("pose")
    ok = [row for row in poses if row["status"] == "ok"]
    print(f"replayed against them: {len(ok)} of {len(poses)} poses ok, {poses[-1]['relocalisations']} place fixes")
    assert len(ok) >= 0.9 * len(poses) and poses[-1]["relocalisations"] > 0.5 * len(poses) / 10


def test_a_database_of_another_lens_is_refused(drives, tmp_path, capsys):
    """Places built from pinhole images do not fit a camera with a lens: a one-line error, not a lost kart."""
    teach = RecordingReader(drives / "teach")
    pinhole = replace(teach.cameras["center"], distortion=())
    frames = list(teach.posed_frames("center", teach.camera_poses("center")))[:80]
    build_places(frames, pinhole, "center").save(tmp_path / "pinhole.npz")
    assert main(["replay", str(drives / "second"), "--pipeline", "mono-vo", "--places",
                 str(tmp_path / "pinhole.npz")]) == 1
    assert "lens coefficients []" in capsys.readouterr().err

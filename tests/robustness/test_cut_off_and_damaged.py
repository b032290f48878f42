"""Recordings cut off or damaged after the fact, and calibration images that cannot be paired: each opens as far
as it honestly can, or says exactly what is wrong."""

from __future__ import annotations

import json

import pytest

from kartpilot.calibration.board import pair_names
from kartpilot.cli.main import main
from kartpilot.core.errors import CalibrationError
from kartpilot.core.geometry import mount_pose
from kartpilot.record.convert import import_stereo_source
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource


@pytest.fixture
def recording(tmp_path):
    folder = tmp_path / "rec"
    import_stereo_source(SyntheticStereoSource(SyntheticStereoConfig(frames=8)), folder, mount_pose(z_m=1.0))
    return folder


def test_a_recording_cut_off_mid_line_still_opens(recording, tmp_path, capsys):
    truth = recording / "groundtruth.tum"
    text = truth.read_text()
    truth.write_text(text[: len(text) - 20])  # the writer was killed inside the last line
    assert main(["odometry", "recording", str(recording), "--out", str(tmp_path / "t.tum"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "end-point drift" in out  # scored against the ground truth that was written whole


def test_a_frame_whose_image_is_gone_is_bridged_and_counted(recording, tmp_path, capsys):
    (recording / "cameras" / "left" / sorted(p.name for p in (recording / "cameras" / "left").glob("*.png"))[3]
     ).unlink()
    assert main(["odometry", "recording", str(recording), "--out", str(tmp_path / "t.txt"), "--json",
                 str(tmp_path / "s.json"), "--no-progress"]) == 0
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["unreadable_frames"] == [3]
    assert len((tmp_path / "t.txt").read_text().splitlines()) == 8  # aligned with the frames


def test_garbage_in_the_commands_names_the_file_and_line(recording, capsys):
    (recording / "commands.csv").write_text("stamp_ns,steer_rad,throttle,brake\n10,0.1,0.2,0\nnan,x,,\n20,0,0,0\n")
    assert main(["recordings", "info", str(recording)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("kartpilot:") and "commands.csv:3" in err and len(err.splitlines()) == 1


def test_calibration_images_pair_by_name_or_order_or_say_why_not():
    assert pair_names(["imageL1.png", "imageL0.png"], ["imageR0.png", "imageR1.png"]) == [
        ("imageL1.png", "imageR1.png"), ("imageL0.png", "imageR0.png")]
    assert pair_names(["left03.jpg"], ["right03.jpg"]) == [("left03.jpg", "right03.jpg")]
    assert pair_names(["a.png", "b.png"], ["c.png", "d.png"]) == [("a.png", "c.png"), ("b.png", "d.png")]
    with pytest.raises(CalibrationError, match="13 left and 3 right images cannot be paired one to one"):
        pair_names([f"left{i:02d}.jpg" for i in range(13)], [f"right{i:02d}.jpg" for i in range(3)])


def test_positions_that_cover_part_of_the_drive_are_refused(recording, tmp_path, capsys):
    from kartpilot.core.trajectory import Trajectory, read_tum, write_tum

    truth = read_tum(recording / "groundtruth.tum")
    write_tum(tmp_path / "half.tum", Trajectory(truth.stamps_s[:4], truth.poses[:4]))
    assert main(["places", "build", str(recording), "--camera", "left", "--positions", str(tmp_path / "half.tum"),
                 "--out", str(tmp_path / "places.npz")]) == 1
    err = capsys.readouterr().err
    assert "a pose for 4 of the 8 frames" in err and not (tmp_path / "places.npz").exists()


def test_a_recording_needs_room_on_its_disk_and_stops_before_the_disk_is_full(tmp_path, monkeypatch, capsys):
    """Issue 56's bound on what is written: a recording starts only with 200 MB free on its disk (the command says
    so in one line and leaves nothing), and a drive whose disk fills stops recording before the disk is full, the
    manifest saying why, as a write that failed would."""
    import numpy as np

    import kartpilot.record.recording as recording
    from kartpilot.core.camera import PinholeCamera
    from kartpilot.core.errors import RecordingError
    from kartpilot.core.types import FrameSet

    monkeypatch.setattr(recording, "free_bytes", lambda path: 50 * 2**20)
    assert main(["sim", "--track", "straight20", "--record", str(tmp_path / "run"), "--cameras", "left"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "only 50 MB free" in err and not (tmp_path / "run").exists()

    free = [10 * 2**30]
    monkeypatch.setattr(recording, "free_bytes", lambda path: free[0])
    monkeypatch.setattr(recording.RecordingWriter, "MANIFEST_REFRESH_S", 0.0)
    camera = PinholeCamera(100.0, 100.0, 31.5, 23.5, 64, 48)
    writer = recording.RecordingWriter(tmp_path / "filling", {"center": camera})
    image = np.full((48, 64, 3), 90, np.uint8)
    writer.write_frames(FrameSet(0, 1, {"center": image}))
    free[0] = 100 * 2**20
    with pytest.raises(RecordingError, match="nearly full"):
        writer.write_frames(FrameSet(1, 2, {"center": image}))
    writer.close()
    reader = recording.RecordingReader(tmp_path / "filling")
    assert not reader.closed and "nearly full" in reader.manifest["write_error"] and len(reader.frames("center")) == 1

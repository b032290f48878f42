"""The Rerun view, read back with rerun's own reader: a simulated drive with --view writes the expected entities
with one row per step, and `kartpilot view` builds the same view from the drive's recording."""

from collections import Counter

import pytest
from rerun.chunk import RrdReader

from kartpilot.cli.main import main
from kartpilot.record.recording import RecordingReader


def rows(path) -> tuple[Counter, set]:
    """Rows per entity over time, and the entities logged once (static)."""
    counts: Counter = Counter()
    static = set()
    for chunk in RrdReader(str(path)).store().stream():
        if chunk.is_static:
            static.add(str(chunk.entity_path))
        else:
            counts[str(chunk.entity_path)] += chunk.num_rows
    return counts, static


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    folder = tmp_path_factory.mktemp("view")
    assert main(["drive", "--sim", "sdc-assen", "--vehicle", "sdc-kart", "--pipeline", "lanes", "--bus", "virtual",
                 "--duration", "3", "--rate", "10", "--record", str(folder / "rec"), "--view",
                 str(folder / "drive.rrd"), "--no-progress"]) == 0
    return folder


def test_a_drive_with_view_writes_every_stage_with_a_row_per_step(drive):
    counts, static = rows(drive / "drive.rrd")
    steps = len(RecordingReader(drive / "rec").commands())
    print(f"{steps} steps; rows per entity: {dict(sorted(counts.items()))}")
    assert steps >= 25
    for camera in ("center", "left", "right"):
        assert f"/cameras/{camera}" in static  # the pinhole
        assert steps - 2 <= counts[f"/cameras/{camera}"] <= steps  # a step's images may be dropped, not more
    for key in ("steer_rad", "throttle", "brake"):
        assert counts[f"/commands/{key}"] == steps
    assert counts["/cameras/center/lanes"] == steps and counts["/outputs/lanes/confidence"] == steps
    assert 1 <= counts["/events/supervisor"] < steps  # the supervisor's state changes, not a line per frame
    assert any(entity.startswith("/can/") and "/raw/" not in entity for entity in counts)  # decoded with the DBC
    assert "/world/truth" in static


def test_kartpilot_view_builds_the_same_view_from_the_recording(drive, capsys):
    assert main(["view", str(drive / "rec"), "--out", str(drive / "again.rrd")]) == 0
    assert "written to" in capsys.readouterr().out
    live, _ = rows(drive / "drive.rrd")
    again, static = rows(drive / "again.rrd")
    reader = RecordingReader(drive / "rec")
    assert again["/cameras/center"] == len(reader.frames("center"))  # a recording's view drops nothing
    same = ["/commands/steer_rad", "/cameras/center/lanes", "/outputs/lanes/confidence", "/events/supervisor"]
    assert {k: again[k] for k in same} == {k: live[k] for k in same}
    assert {e for e in again if e.startswith("/can/")} == {e for e in live if e.startswith("/can/")}
    assert "/world/truth" in static


def test_a_view_of_what_is_not_a_recording_leaves_no_file(tmp_path, capsys):
    assert main(["view", str(tmp_path), "--out", str(tmp_path / "x.rrd")]) == 1
    assert "not a kartpilot recording" in capsys.readouterr().err
    assert main(["view", str(tmp_path), "--out", str(tmp_path / "x.txt")]) == 2
    assert "give a .rrd file" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_odometry_with_view_shows_each_frame_its_estimate_inliers_points_and_the_truth(tmp_path):
    assert main(["odometry", "synthetic", "--frames", "12", "--out", str(tmp_path / "t.txt"), "--view",
                 str(tmp_path / "vo.rrd"), "--no-progress"]) == 0
    counts, static = rows(tmp_path / "vo.rrd")
    assert counts["/cameras/left"] == counts["/cameras/right"] == 12
    assert counts["/world/estimate"] == counts["/outputs/pose/inliers"] == counts["/outputs/vo/epipolar_ok"] == 12
    assert counts["/cameras/left/inliers"] == counts["/world/points"] == 11  # each step's, in the image before
    assert "/world/truth" in static


def test_a_drive_refused_before_it_starts_leaves_no_view_file_and_no_recording(tmp_path, capsys):
    assert main(["drive", "--sim", "straight20", "--vehicle", "rc-kart", "--pipeline", "lanes", "--duration", "3",
                 "--inject", "steering-sensor-loss@1", "--view", str(tmp_path / "x.rrd"), "--record",
                 str(tmp_path / "rec"), "--no-progress"]) == 1
    assert "cannot show it" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []

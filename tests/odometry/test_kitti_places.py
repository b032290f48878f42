"""The one-camera localiser on real footage: a KITTI sequence imported as a recording with the camera's mount,
a place database built from its even frames, and `kartpilot odometry kitti --mono --places DB` over every frame
(skipped with the reason when ../shared/data is absent)."""

import json

import numpy as np
import pytest
from tests.conftest import data_path

from kartpilot.cli.main import main
from kartpilot.odometry.places import PlacesConfig, build_places
from kartpilot.perception.birdseye import BirdseyeConfig
from kartpilot.record.recording import RecordingReader


@pytest.mark.slow
def test_kitti_imported_with_its_mount_localises_on_its_places(tmp_path, capsys):
    root = data_path("kitti-odometry")
    assert main(["recordings", "import-kitti", str(root), "--sequence", "06", "--out", str(tmp_path / "rec"),
                 "--camera-height", "1.65"]) == 0
    reader = RecordingReader(tmp_path / "rec")
    assert reader.stereo_pair == ("left", "right") and len(reader.frames("left")) == 51
    left, right = (reader.cameras[name].pose_body_cam_array for name in ("left", "right"))
    assert left[2, 3] == pytest.approx(1.65)
    assert np.linalg.norm(right[:3, 3] - left[:3, 3]) == pytest.approx(0.54, abs=0.01)
    truth = reader.camera_poses("left")
    assert truth is not None and len(truth) == 51

    # KITTI's camera sees the road from 4 camera heights ahead (the default patch starts at 3.5)
    config = PlacesConfig(road=BirdseyeConfig(near_heights=4.0))
    even = [frame for k, frame in enumerate(reader.posed_frames("left", truth)) if k % 2 == 0]
    build_places(even, reader.cameras["left"], "left", config).save(tmp_path / "places.npz")
    (tmp_path / "stack.yaml").write_text("places:\n  road:\n    near_heights: 4.0\n")
    capsys.readouterr()
    assert main(["odometry", "kitti", str(root), "--sequence", "06", "--mono", "--camera-height", "1.65", "--places",
                 str(tmp_path / "places.npz"), "--out", str(tmp_path / "t.txt"), "--json", str(tmp_path / "s.json"),
                 "--config", str(tmp_path / "stack.yaml"), "--no-progress"]) == 0
    print(capsys.readouterr().out)
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["mode"] == "mono+places" and summary["frames"] == 51
    assert len((tmp_path / "t.txt").read_text().splitlines()) == 51
    assert summary["placed_frames"] == 51 and summary["place_fixes"] > 10
    # the odd frames lie between the database's places: a check that the fixes place the camera, on the drive the
    # places came from, not a claim for another drive
    assert summary["metrics"]["ate_rmse_m"] < 0.5

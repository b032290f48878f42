import json

import pytest

from kartpilot.cli.commands import LANE_COLUMNS
from kartpilot.cli.main import main
from kartpilot.core.trajectory import read_kitti_poses
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.session import SessionResult


def test_odometry_on_synthetic_writes_trajectory_and_json(tmp_path, capsys) -> None:
    out, summary = tmp_path / "traj.txt", tmp_path / "summary.json"
    assert main(["odometry", "synthetic", "--frames", "12", "--out", str(out), "--json", str(summary),
                 "--no-progress", "--plot", str(tmp_path / "plot.png")]) == 0
    assert len(read_kitti_poses(out)) == 12
    data = json.loads(summary.read_text())
    assert data["metrics"]["end_drift_percent"] < 2.0
    assert (tmp_path / "plot.png").stat().st_size > 1000
    assert "end-point drift (%)" in capsys.readouterr().out


def test_eval_command(tmp_path, capsys) -> None:
    out = tmp_path / "traj.txt"
    main(["odometry", "synthetic", "--frames", "8", "--out", str(out), "--no-progress"])
    capsys.readouterr()
    assert main(["eval", "trajectory", "--gt", str(out), "--est", str(out), "--json", str(tmp_path / "m.json")]) == 0
    assert "ATE RMSE (m)" in capsys.readouterr().out
    assert json.loads((tmp_path / "m.json").read_text())["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["odometry", "kitti", "/does/not/exist", "--sequence", "06", "--out", "x.txt"], "KITTI root not found"),
        (["odometry", "euroc", "/does/not/exist", "--out", "x.tum"], "no EuRoC cam0/cam1"),
        (["odometry", "recording", "/does/not/exist", "--out", "x.txt"], "not a kartpilot recording"),
        (["eval", "trajectory", "--gt", "/does/not/exist.txt", "--est", "/nope.txt"], "trajectory file not found"),
        (["sim", "--track", "monza", "--no-render"], "unknown track 'monza'"),
        (["sim", "--track", "/does/not/exist.yaml", "--no-render"], "config file not found"),
        (["sim", "--driver", "commands", "--no-render"], "needs a recording"),
        (["sim", "--cameras", "rear", "--no-render"], "has no camera 'rear'"),
        (["sim", "--no-render", "--record", "out"], "--no-render cannot record"),
        (["lanes", "/does/not/exist.jpg", "--out", "x.txt"], "input not found"),
        (["drive", "--reference", "/does/not/exist.csv", "--sim", "straight20"], "no such reference path"),
        (["reference", "/does/not/exist", "--out", "x.csv"], "not a kartpilot recording"),
        (["places", "build", "/does/not/exist", "--out", "x.db"], "not a kartpilot recording"),
        (["places", "query", "/does/not/exist.db", "/does/not/exist"], "no place database"),
    ],
)
def test_user_mistakes_give_one_line_and_exit_1(argv: list[str], message: str, capsys, tmp_path) -> None:
    argv = [a if a not in ("x.txt", "x.tum") else str(tmp_path / a) for a in argv]
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("kartpilot: error:") and message in err
    assert "\n" not in err and "Traceback" not in err


def test_config_typo_names_the_key(tmp_path, capsys) -> None:
    config = tmp_path / "vo.yaml"
    config.write_text("stereo_vo:\n  pnp: {min_inlier: 10}\n")
    assert main(["odometry", "synthetic", "--frames", "3", "--out", str(tmp_path / "t.txt"),
                 "--config", str(config)]) == 1
    assert "stereo_vo.pnp.min_inlier" in capsys.readouterr().err


def test_sim_prints_the_referee_and_writes_the_result(tmp_path, capsys) -> None:
    result = tmp_path / "result.json"
    assert main(["sim", "--track", "straight20", "--vehicle", "rc-kart", "--no-render", "--speed", "2",
                 "--result", str(result), "--no-progress"]) == 0
    assert "finished" in capsys.readouterr().out
    data = json.loads(result.read_text())
    assert data["disqualified"] is False and data["distance_m"] == pytest.approx(20.0, abs=0.3)


def test_sim_config_file_is_merged_and_checked(tmp_path, capsys) -> None:
    config = tmp_path / "sim.yaml"
    config.write_text("sim:\n  referee: {laps: 1}\n  effects: {noise_sigmaa: 3}\n")
    assert main(["sim", "--no-render", "--config", str(config)]) == 1
    assert "sim.effects.noise_sigmaa" in capsys.readouterr().err


def test_lanes_writes_one_row_per_frame_with_the_documented_columns(tmp_path, capsys) -> None:
    import csv

    import cv2
    import numpy as np

    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(3):
        image = np.full((540, 960, 3), 80, np.uint8)
        cv2.line(image, (100, 539), (400, 260), (235, 235, 235), 8)  # toward a vanishing point near the
        cv2.line(image, (860, 539), (560, 260), (235, 235, 235), 8)  # kart preset's horizon (0.34 of the height)
        cv2.imwrite(str(folder / f"{k}.png"), image)
    out = tmp_path / "lanes.csv"
    assert main(["lanes", str(folder), "--out", str(out), "--overlay", str(tmp_path / "overlay")]) == 0
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 3 and tuple(rows[0]) == LANE_COLUMNS
    assert [r["file"] for r in rows] == ["0.png", "1.png", "2.png"]
    assert [r["new_scene"] for r in rows] == ["1", "0", "0"]  # one scene: the follower's state carries
    assert rows[0]["left_source"] == "detected" and abs(float(rows[0]["left_x1"]) - 100) < 15
    assert abs(float(rows[0]["left_x_at_100pct"]) - 100) < 15  # the curve, read at the last row
    assert len(list((tmp_path / "overlay").glob("*.png"))) == 3


def test_teach_reference_and_drive_it_in_the_simulator_and_on_the_replay(tmp_path, capsys) -> None:
    """The workflow by hand: record a short drive, build its reference and map, drive it twice."""
    config = tmp_path / "short.yaml"
    config.write_text("sim:\n  max_time_s: 4.0\n")
    record = tmp_path / "teach"
    assert main(["sim", "--track", "straight20", "--vehicle", "rc-kart", "--cameras", "left,right", "--rate", "10",
                 "--speed", "0.8", "--record", str(record), "--config", str(config), "--no-progress",
                 "--perfect-camera"]) == 0
    reference = tmp_path / "ref.csv"
    assert main(["reference", str(record), "--out", str(reference), "--speed", "0.8"]) == 0
    out = capsys.readouterr().out
    assert "visual map:" in out and (tmp_path / "ref.map.npz").is_file()
    log = tmp_path / "log.csv"
    assert main(["drive", "--reference", str(reference), "--replay", str(record), "--log", str(log)]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["steps"] == 40 and summary["relocalised_frames"] > 30
    assert len(log.read_text().splitlines()) == 41
    # the same pipeline through 'replay', twice: a new recording each time, and identical outputs
    for name in ("r1", "r2"):
        assert main(["replay", str(record), "--pipeline", "stereo-vo", "--reference", str(reference),
                     "--out", str(tmp_path / name)]) == 0
    assert "stereo-vo: 40 sets at 10.0 Hz" in capsys.readouterr().out
    for part in ("commands.csv", "outputs/pose.csv", "outputs/follow.csv"):
        assert (tmp_path / "r1" / part).read_bytes() == (tmp_path / "r2" / part).read_bytes(), part
    assert len((tmp_path / "r1" / "outputs" / "pose.csv").read_text().splitlines()) == 41
    stages = RecordingReader(tmp_path / "r1").outputs("vo")  # what each of VO's filter stages kept, per frame
    assert len(stages) == 40 and all(r["left_features"] >= r["stereo_matches"] >= r["epipolar_ok"] >= r["depth_ok"]
                                     for r in stages)
    assert sum(r["inliers"] > 0 for r in stages) >= 35
    assert main(["replay", str(record), "--pipeline", "stereo-vo"]) == 1
    assert "give --reference" in capsys.readouterr().err
    result = tmp_path / "drive.json"
    assert main(["drive", "--reference", str(reference), "--sim", "straight20", "--rate", "10", "--result",
                 str(result), "--no-progress"]) == 0
    data = json.loads(result.read_text())
    assert data["stop_reason"] == "reached the end of the reference" and not data["disqualified"]
    assert "localize.detect" in data["pipeline_stage_ms"] and "missed_deadlines" in data
    assert SessionResult.from_json(data).backend == "sim"
    assert set(data["stage_ms"]["policy"]) == {"mean", "p50", "p90", "p99", "max"}
    assert [t["state"] for t in data["transitions"]] == ["autonomous"] and data["bus"] == "virtual"
    assert main(["drive", "--reference", str(reference)]) == 1
    assert "needs --sim TRACK, --replay RECORDING or --live RIG" in capsys.readouterr().err


def test_monocular_odometry_on_kitti_says_where_its_scale_comes_from(tmp_path, capsys) -> None:
    from tests.conftest import data_path

    root = data_path("kitti-odometry")
    assert main(["odometry", "kitti", str(root), "--sequence", "06", "--mono", "--out", str(tmp_path / "t.txt")]) == 1
    assert "--mono needs --camera-height" in capsys.readouterr().err
    summary = tmp_path / "s.json"
    assert main(["odometry", "kitti", str(root), "--sequence", "06", "--mono", "--camera-height", "1.65", "--out",
                 str(tmp_path / "t.txt"), "--json", str(summary), "--no-progress"]) == 0
    assert "scale from the ground plane (camera 1.65 m above the road)" in capsys.readouterr().out
    data = json.loads(summary.read_text())
    assert data["mode"] == "mono" and data["scale_source"].startswith("ground plane")
    assert len((tmp_path / "t.txt").read_text().splitlines()) == 51


def test_places_build_and_query_a_recording_and_an_image(tmp_path, capsys) -> None:
    """A recording of distinct synthetic places with ground truth: build, query the recording (Recall printed),
    query one image; a recording without positions is a one-line error."""
    import cv2
    from tests.odometry.test_places import CAMERA, _place_image, _pose

    from kartpilot.core.trajectory import Trajectory
    from kartpilot.record.recording import RecordingWriter

    for name, with_truth in (("ref", True), ("bare", False)):
        with RecordingWriter(tmp_path / name, {"center": CAMERA}, metadata={"groundtruth_camera": "center"}) as w:
            for k in range(12):
                w.write_frame("center", k * 10**8, cv2.cvtColor(_place_image(k), cv2.COLOR_GRAY2BGR))
            if with_truth:
                w.write_groundtruth(Trajectory.from_poses([_pose(1.5 * k) for k in range(12)],
                                                          [k * 0.1 for k in range(12)]))
    config = tmp_path / "places.yaml"
    config.write_text("places: {vlad: {words: 16}}\n")
    db = tmp_path / "places.db"
    assert main(["places", "build", str(tmp_path / "ref"), "--out", str(db), "--config", str(config)]) == 0
    assert "12 places over 16 m of the center camera" in capsys.readouterr().out
    assert main(["places", "query", str(db), str(tmp_path / "ref"), "--out", str(tmp_path / "fixes.csv")]) == 0
    assert "Recall@1 (VLAD)      100.0 %" in capsys.readouterr().out
    assert len((tmp_path / "fixes.csv").read_text().splitlines()) == 13
    image = next((tmp_path / "ref" / "cameras" / "center").iterdir())
    assert main(["places", "query", str(db), str(image)]) == 0
    assert "best place" in capsys.readouterr().out
    assert main(["places", "build", str(tmp_path / "bare"), "--out", str(db)]) == 1
    err = capsys.readouterr().err
    assert "no ground truth" in err and "--positions" in err


def test_a_scenario_on_a_kart_that_is_not_the_sdc_kart_is_a_one_line_error(capsys):
    """--vehicle used to be taken and ignored by --scenario (it always drove the sdc-kart)."""
    assert main(["sim", "--scenario", "overtake", "--vehicle", "rc-kart"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "sdc-kart or sdc-kart-2026, not rc-kart" in err


@pytest.mark.parametrize("given", [["--track", "utrack"], ["--rate", "30"], ["--no-render"], ["--driver", "lanes"],
                                   ["--perfect-camera"]])
def test_a_sim_option_a_scenario_would_ignore_is_refused_by_name(given, capsys):
    """Issue 56's options accepted and ignored: with --scenario, the course, the driver and the camera are the
    scenario's; each of these was taken and silently dropped."""
    assert main(["sim", "--scenario", "overtake", *given]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{given[0]} would be ignored" in err


def test_a_scenario_takes_the_faults_of_what_the_kart_sees_and_refuses_the_others(capsys):
    assert main(["sim", "--scenario", "overtake", "--inject", "can-bus-off@3"]) == 1
    assert "--inject can-bus-off: a scenario takes the faults of what the kart sees" in capsys.readouterr().err
    assert main(["sim", "--track", "straight20", "--inject", "lidar-loss@1"]) == 1
    assert "works with --scenario" in capsys.readouterr().err


def test_the_experiment_drives_through_the_config_s_camera(tmp_path, monkeypatch, capsys) -> None:
    """`kartpilot experiment --config` with `sim.effects`: the teach-and-repeat takes the file's camera (it was
    accepted and ignored); without a file, the kart's real camera, the simulator's default."""
    import kartpilot.cli.drive_commands as commands
    from kartpilot.sim.simulator import CameraEffectsConfig

    taken = []
    monkeypatch.setattr(commands, "run_teach_repeat", lambda config, *a, **k: taken.append(config.effects) or {})
    monkeypatch.setattr(commands, "summary_line", lambda result: "")
    config = tmp_path / "perfect.yaml"
    config.write_text("sim:\n  effects:\n    jpeg_quality: 0\n    rolling_shutter_s: 0.0\n")
    for extra in ([], ["--config", str(config)]):
        assert main(["experiment", "teach-repeat", "--out", str(tmp_path / "exp"), *extra]) == 0
    assert taken[0] == CameraEffectsConfig()
    assert (taken[1].jpeg_quality, taken[1].rolling_shutter_s) == (0, 0.0)
    config.write_text("sim:\n  effects:\n    jpeg_qualty: 0\n")
    assert main(["experiment", "teach-repeat", "--out", str(tmp_path / "exp"), "--config", str(config)]) == 1
    assert "jpeg_qualty" in capsys.readouterr().err

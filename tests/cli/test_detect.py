"""kartpilot detect: one CSV row per object, a row for a frame with none, one-line errors."""

import csv

import cv2
import numpy as np
from tests.perception.test_objects import _sign, scene

from kartpilot.cli.main import main


def test_detect_writes_a_row_per_object_and_one_for_a_frame_with_none(tmp_path, capsys):
    folder = tmp_path / "frames"
    folder.mkdir()
    with_sign = scene()
    _sign(with_sign, (700, 90), 40, "20")
    cv2.imwrite(str(folder / "a.png"), with_sign)
    cv2.imwrite(str(folder / "b.png"), scene())
    out = tmp_path / "objects.csv"
    assert main(["detect", str(folder), "--out", str(out), "--no-people", "--overlay", str(tmp_path / "ov")]) == 0
    rows = list(csv.DictReader(out.open()))
    # the columns the event's brief asks for: class, the box as x1, y1, x2, y2, the value, the track id
    assert list(rows[0])[:10] == ["frame", "file", "class", "x1", "y1", "x2", "y2", "confidence", "value", "distance_m"]
    assert [(r["file"], r["class"], r["value"]) for r in rows] == [("a.png", "speed_sign", "20"), ("b.png", "", "")]
    assert float(rows[0]["distance_m"]) > 0 and rows[0]["track_id"] == "1"
    assert float(rows[0]["x1"]) < float(rows[0]["x2"]) and float(rows[0]["y1"]) < float(rows[0]["y2"])
    assert len(list((tmp_path / "ov").glob("*.png"))) == 2
    assert "1 speed_sign" in capsys.readouterr().out


def test_detect_errors_are_one_line_and_leave_no_file(tmp_path, capsys):
    image = tmp_path / "a.png"
    cv2.imwrite(str(image), np.full((48, 64, 3), 120, np.uint8))
    out = tmp_path / "objects.csv"
    assert main(["detect", str(image), "--out", str(out), "--detector", "onnx:team.onnx"]) == 1
    assert "--classes" in capsys.readouterr().err and not out.exists()
    classes = tmp_path / "classes.yaml"
    classes.write_text("classes:\n  0: person\n")
    assert main(["detect", str(image), "--out", str(out), "--detector", "onnx:missing.onnx", "--classes",
                 str(classes)]) == 1
    assert "no ONNX model" in capsys.readouterr().err and not out.exists()


def test_images_of_another_camera_s_shape_are_refused_until_its_rig_is_given(tmp_path, capsys):
    """Without --rig the SDC kart's 848x480 centre camera places the objects; a 160x120 image (a Donkey car's
    camera) read through its mount had its hood and the sky taken for the road: a person in 286 of 300 frames."""
    image = tmp_path / "donkey.png"
    cv2.imwrite(str(image), np.full((120, 160, 3), 120, np.uint8))
    out = tmp_path / "objects.csv"
    assert main(["detect", str(image), "--out", str(out), "--no-people"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "160x120" in err and "848x480" in err and "--rig" in err
    assert not out.exists()
    # a large image is named at its own size (the detectors that halve it first named the half: 621x187)
    cv2.imwrite(str(image), np.full((375, 1242, 3), 120, np.uint8))
    assert main(["detect", str(image), "--out", str(out), "--no-people"]) == 1
    assert "1242x375" in capsys.readouterr().err and not out.exists()
    # the kart's own camera at another resolution of the same shape is scaled, as before
    cv2.imwrite(str(image), np.full((240, 424, 3), 120, np.uint8))
    assert main(["detect", str(image), "--out", str(out), "--no-people"]) == 0 and out.exists()


def test_a_folder_s_images_that_cannot_be_used_are_left_out_and_named_and_the_rest_are_kept(tmp_path, capsys):
    """One bad file among a folder's photos (cut off in copying, empty, not an image, another camera's) does not
    lose the others: each is named on one line, the CSV holds the rest under their own frame numbers, and the exit
    status says something was left out. A folder with nothing usable writes nothing."""
    folder = tmp_path / "frames"
    folder.mkdir()
    with_sign = scene()
    _sign(with_sign, (700, 90), 40, "20")
    cv2.imwrite(str(folder / "a.png"), with_sign)
    good = cv2.imencode(".jpg", scene())[1].tobytes()
    (folder / "b_cut.jpg").write_bytes(good[: len(good) // 2])
    (folder / "c_empty.jpg").write_bytes(b"")
    (folder / "d_text.png").write_text("not an image")
    cv2.imwrite(str(folder / "e_small.png"), np.full((120, 160, 3), 120, np.uint8))
    (folder / "f.jpg").write_bytes(good)
    out = tmp_path / "objects.csv"
    assert main(["detect", str(folder), "--out", str(out), "--no-people"]) == 1
    err = capsys.readouterr().err.splitlines()
    print("\n".join(err))
    assert [line.split(":")[1].strip() for line in err[:-1]] == ["left out b_cut.jpg", "left out c_empty.jpg",
                                                                 "left out d_text.png", "left out e_small.png"]
    assert "cut off" in err[0] and "empty" in err[1] and "160x120" in err[3] and "4 image(s)" in err[-1]
    rows = list(csv.DictReader(out.open()))
    assert [(r["frame"], r["file"], r["class"]) for r in rows] == [("0", "a.png", "speed_sign"), ("5", "f.jpg", "")]
    for name in ("a.png", "f.jpg"):
        (folder / name).unlink()
    out.unlink()
    assert main(["detect", str(folder), "--out", str(out), "--no-people"]) == 1
    assert "no image" in capsys.readouterr().err and not out.exists()


def test_detect_takes_the_detector_s_settings_from_the_stack_s_yaml(tmp_path, capsys):
    """The same YAML a drive takes (lane_policy.detector): a team among 30 signs adds the value, which the
    default reader, knowing the event's 10, 15 and 20, does not read; a key misspelt is a one-line error naming
    it, and no CSV is written."""
    folder = tmp_path / "frames"
    folder.mkdir()
    image = scene()
    _sign(image, (700, 90), 40, "30")
    cv2.imwrite(str(folder / "a.png"), image)
    out = tmp_path / "objects.csv"
    assert main(["detect", str(folder), "--out", str(out), "--no-people"]) == 0
    assert [r["value"] for r in csv.DictReader(out.open())] != ["30"]
    config = tmp_path / "team.yaml"
    config.write_text("lane_policy:\n  detector:\n    signals: {values_kmh: [10, 15, 20, 30]}\n")
    assert main(["detect", str(folder), "--out", str(out), "--no-people", "--config", str(config)]) == 0
    assert [(r["class"], r["value"]) for r in csv.DictReader(out.open())] == [("speed_sign", "30")]
    capsys.readouterr()
    config.write_text("lane_policy:\n  detector:\n    signals: {values_kph: [30]}\n")
    other = tmp_path / "other.csv"
    assert main(["detect", str(folder), "--out", str(other), "--config", str(config)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("kartpilot:") and "values_kph" in err and len(err.strip().splitlines()) == 1
    assert not other.exists()

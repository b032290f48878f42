"""Scoring kartpilot on a team's own labelled frames: the label formats read alike, the matching and the act
windows count what they say, and ``kartpilot eval detect`` / ``eval lanes`` reproduce the docs' real-frame figures
on the shared labels."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from tests.conftest import data_path

from kartpilot.behaviour.events import ACTED_ON, BehaviourConfig, act_window
from kartpilot.cli.main import main
from kartpilot.core.errors import DataError
from kartpilot.core.vehicle import get_vehicle
from kartpilot.eval.detection import ClassScore, DetectionScore, Label, read_labels, score_detections
from kartpilot.eval.lanes import read_lane_labels
from kartpilot.perception.objects import Detection

ROOT = Path(__file__).resolve().parents[2]
KART = get_vehicle("sdc-kart").camera("center")
WINDOWS = {label: act_window(label, BehaviourConfig()) for label in ACTED_ON}


def _kartpilot_labels(tmp_path: Path) -> Path:
    path = tmp_path / "labels.json"
    path.write_text(json.dumps({"images": {
        "a.png": [{"label": "traffic_light", "box": [100, 20, 120, 60], "state": "red"},
                  {"label": "car", "box": [380, 300, 480, 380]}],
        "b.png": [{"label": "person", "box": [600, 250, 640, 380]}]}}))
    return path


def test_the_three_label_formats_read_alike(tmp_path: Path) -> None:
    """The same boxes as kartpilot JSON, COCO (left, top, width, height; the state as an attribute) and YOLO
    (centre and size as fractions of an 848x480 image, classes.txt beside them), with a team's class names mapped."""
    ours = read_labels(_kartpilot_labels(tmp_path))
    coco = {"images": [{"id": 1, "file_name": "a.png"}, {"id": 2, "file_name": "b.png"}],
            "categories": [{"id": 7, "name": "red_light"}, {"id": 8, "name": "vehicle"}, {"id": 9, "name": "walker"},
                           {"id": 10, "name": "cone"}],
            "annotations": [{"image_id": 1, "category_id": 7, "bbox": [100, 20, 20, 40],
                             "attributes": {"state": "red"}},
                            {"image_id": 1, "category_id": 8, "bbox": [380, 300, 100, 80]},
                            {"image_id": 1, "category_id": 10, "bbox": [10, 10, 5, 5]},
                            {"image_id": 2, "category_id": 9, "bbox": [600, 250, 40, 130]}]}
    (tmp_path / "coco.json").write_text(json.dumps(coco))
    team = {"red_light": "traffic_light", "vehicle": "car", "walker": "person", "cone": ""}
    from_coco = read_labels(tmp_path / "coco.json", class_map=team)
    assert from_coco == {name: [Label(o.label, o.box_px, o.state) for o in objects] for name, objects in ours.items()}
    yolo = tmp_path / "yolo"
    yolo.mkdir()
    (yolo / "classes.txt").write_text("vehicle\nwalker\nred_light\n")
    (yolo / "a.txt").write_text(f"2 {110 / 848} {40 / 480} {20 / 848} {40 / 480}\n0 {430 / 848} {340 / 480} "
                                f"{100 / 848} {80 / 480}\n")
    (yolo / "b.txt").write_text(f"1 {620 / 848} {315 / 480} {40 / 848} {130 / 480}\n")
    from_yolo = read_labels(yolo, lambda stem: (848, 480), team)
    for name in ("a", "b"):
        got, want = from_yolo[name], ours[f"{name}.png"]
        assert [o.label for o in got] == [o.label for o in want]
        assert np.allclose([o.box_px for o in got], [o.box_px for o in want], atol=1e-6)


@pytest.mark.parametrize(("content", "message"), [
    ({"images": {"a.png": [{"label": "unicorn", "box": [0, 0, 5, 5]}]}}, "unicorn"),
    ({"images": {"a.png": [{"label": "car", "box": [10, 0, 5, 5]}]}}, "left < right"),
    ({"images": {"a.png": [{"label": "car", "box": [0, 0, "x", 5]}]}}, "four numbers"),
    ({"images": {"a.png": [{"label": "car"}]}}, "'label' and 'box'"),
    ({"frames": {}}, "neither kartpilot labels"),
])
def test_a_bad_label_file_is_one_error_naming_the_file_and_the_object(tmp_path, content, message) -> None:
    path = tmp_path / "labels.json"
    path.write_text(json.dumps(content))
    with pytest.raises(DataError, match=message) as caught:
        read_labels(path)
    assert str(path) in str(caught.value)


def test_found_missed_false_alarms_and_what_concerns_the_kart() -> None:
    """A light found with its colour; a car in the kart's lane found; a small car far ahead (beyond where the kart
    acts on a car) missed, which is no fault of the kart's; a person reported where nobody is labelled."""
    # the SDC kart's centre camera: a box's foot at row 215 stands about 8 m ahead, at row 178 about 24 m
    labels = {"a": [Label("traffic_light", (100, 20, 120, 60), "red"), Label("car", (390, 170, 460, 215)),
                    Label("car", (420, 172, 428, 178))]}
    found = {"a": [Detection("traffic_light", (101, 22, 119, 58), 0.9, "red"),
                   Detection("car", (392, 172, 458, 214), 0.8), Detection("person", (700, 200, 720, 260), 0.5)]}
    score = score_detections(found, labels, lambda name: KART, WINDOWS)
    assert score.classes["traffic_light"] == ClassScore(labelled=1, concerning=1, found=1, found_concerning=1,
                                                        state_right=1)
    car = score.classes["car"]
    assert (car.labelled, car.concerning, car.found, car.found_concerning, car.false_alarms) == (2, 1, 1, 1, 0)
    assert [m["label"] for m in score.misses] == ["car"] and not score.misses[0]["concerns"]
    assert score.misses[0]["ahead_m"] > WINDOWS["car"][1]
    assert score.classes["person"].false_alarms == 1 and score.false_alarms[0]["label"] == "person"
    # the colour read wrong counts as found but not right
    wrong = {"a": [Detection("traffic_light", (101, 22, 119, 58), 0.9, "green")]}
    assert score_detections(wrong, {"a": labels["a"][:1]}, lambda name: KART, WINDOWS).classes[
        "traffic_light"].state_right == 0


def test_the_lane_label_csv_and_json_read_alike(tmp_path: Path) -> None:
    (tmp_path / "points.json").write_text(json.dumps({"frames": {"f.jpg": {"left": [[240, 233.5], [280, 93]],
                                                                          "right": [[240, 683]]}}}))
    (tmp_path / "points.csv").write_text("\ufeffimage,side,row,x\r\nf.jpg,left,240,233.5\r\nf.jpg,left,280,93\r\n"
                                         "f.jpg,Right,240,683\r\n")
    assert read_lane_labels(tmp_path / "points.csv") == read_lane_labels(tmp_path / "points.json")
    (tmp_path / "bad.csv").write_text("image,side,row,x\nf.jpg,middle,240,1\n")
    with pytest.raises(DataError, match=r"line 2.*middle"):
        read_lane_labels(tmp_path / "bad.csv")
    (tmp_path / "nan.csv").write_text("image,side,row,x\nf.jpg,left,240,nan\n")
    with pytest.raises(DataError, match="finite"):
        read_lane_labels(tmp_path / "nan.csv")


def test_eval_lanes_on_a_drawn_road_meets_the_points_on_its_lines(tmp_path: Path, capsys) -> None:
    """A grey road with two painted lines: points on the lines are met; points 60 px off them are not."""
    image = np.full((480, 848, 3), 95, np.uint8)
    image[:190] = (210, 180, 150)
    cv2.line(image, (380, 190), (60, 479), (240, 240, 240), 9)
    cv2.line(image, (470, 190), (800, 479), (240, 240, 240), 9)
    cv2.imwrite(str(tmp_path / "road.png"), image)
    on = [(row, 380 + (60 - 380) * (row - 190) / 289, 470 + (800 - 470) * (row - 190) / 289) for row in (300, 360, 420)]
    lines = ["image,side,row,x"] + [f"road.png,left,{r},{lx:.1f}\nroad.png,right,{r},{rx:.1f}" for r, lx, rx in on]
    (tmp_path / "on.csv").write_text("\n".join(lines) + "\n")
    assert main(["eval", "lanes", str(tmp_path), str(tmp_path / "on.csv"), "--json", str(tmp_path / "on.json")]) == 0
    on_score = json.loads((tmp_path / "on.json").read_text())
    lines = ["image,side,row,x"] + [f"road.png,left,{r},{lx + 60:.1f}" for r, lx, _ in on]
    (tmp_path / "off.csv").write_text("\n".join(lines) + "\n")
    assert main(["eval", "lanes", str(tmp_path), str(tmp_path / "off.csv"), "--json", str(tmp_path / "off.json")]) == 0
    off_score = json.loads((tmp_path / "off.json").read_text())
    print(capsys.readouterr().out)
    assert on_score["points"] == 6 and on_score["share_within"] == 1.0 and on_score["median_px"] < 10
    assert off_score["share_within"] == 0.0


def test_eval_lanes_reproduces_the_venue_figure_from_a_csv(tmp_path: Path, capsys) -> None:
    """The venue's hand-placed boundary points, written as a CSV, give the figure docs/real-kart.md shows for the
    paint finder (development data: the finder was built on these frames)."""
    frames = data_path("rdw-kart", "lelystad-2024", "frames")
    truth = json.loads((ROOT / "tests" / "data" / "rdw_lelystad_lane_truth.json").read_text())["frames"]
    rows = ["image,side,row,x"] + [f"{name},{side},{row},{x}" for name, sides in truth.items()
                                   for side, points in sides.items() for row, x in points]
    (tmp_path / "points.csv").write_text("\n".join(rows) + "\n")
    assert main(["eval", "lanes", str(frames), str(tmp_path / "points.csv"), "--json", str(tmp_path / "s.json"),
                 "--out", str(tmp_path / "table.md")]) == 0
    score = json.loads((tmp_path / "s.json").read_text())
    rows = json.loads((ROOT / "docs" / "results" / "real_kart.json").read_text())["rows"]
    docs = rows["paint (kart preset), 848x480"]
    print(capsys.readouterr().out)
    assert score["points"] == docs["truth_points"]
    assert 100 * score["share_within"] == pytest.approx(docs["truth_within_25px_percent"])
    assert score["median_px"] == pytest.approx(docs["truth_median_px"])
    assert "| all |" in (tmp_path / "table.md").read_text()


def _docs_table() -> str:
    classes = json.loads((ROOT / "docs" / "results" / "detect.json").read_text())["labelled"]["classes"]
    return DetectionScore(classes={k: ClassScore(**v) for k, v in classes.items()}).table()


def test_eval_detect_reproduces_the_docs_real_frame_table(tmp_path: Path, capsys) -> None:
    """The shared labels of the venue's scenes and the Hanze practice image, the Hanze camera placed by
    ``calibrate ground`` from its board (1.2 m ahead of the rear axle, as the SDC kart's): the table
    docs/detection.md shows (development data)."""
    kart = data_path("rdw-kart")
    hanze = kart / "hanze-calibration"
    assert main(["calibrate", "ground", *(f"--image={n}={hanze / f'{n}.jpg'}" for n in ("left", "center", "right")),
                 "--reference-x", "1.2", "--out", str(tmp_path / "hanze.yaml")]) == 0
    assert main(["eval", "detect", str(kart), str(ROOT / "tests" / "data" / "rdw_objects.json"), "--rig",
                 f"hanze-calibration/={tmp_path / 'hanze.yaml'}", "--out", str(tmp_path / "table.md"), "--json",
                 str(tmp_path / "score.json")]) == 0
    out = capsys.readouterr().out
    print(out)
    assert (tmp_path / "table.md").read_text().strip() == _docs_table().strip()
    assert "missed: stop_line in hanze-calibration/center.jpg" in out
    assert json.loads((tmp_path / "score.json").read_text())["false_alarms"] == []


def test_eval_detect_reads_coco_and_yolo_exports_of_the_same_labels(tmp_path: Path) -> None:
    """The venue scenes' labels exported as COCO and as YOLO score as the kartpilot file does."""
    kart = data_path("rdw-kart")
    scenes = {name: objects for name, objects in
              json.loads((ROOT / "tests" / "data" / "rdw_objects.json").read_text())["images"].items()
              if name.startswith("lelystad-2024/scenes/")}
    (tmp_path / "ours.json").write_text(json.dumps({"images": scenes}))
    names = sorted({o["label"] for objects in scenes.values() for o in objects})
    coco = {"images": [{"id": k, "file_name": name} for k, name in enumerate(scenes)],
            "categories": [{"id": k, "name": n} for k, n in enumerate(names)],
            "annotations": [{"image_id": k, "category_id": names.index(o["label"]),
                             "bbox": [o["box"][0], o["box"][1], o["box"][2] - o["box"][0], o["box"][3] - o["box"][1]],
                             "attributes": {"state": o.get("state", "")}}
                            for k, objects in enumerate(scenes.values()) for o in objects]}
    (tmp_path / "coco.json").write_text(json.dumps(coco))
    yolo = tmp_path / "yolo"
    yolo.mkdir()
    (yolo / "classes.txt").write_text("\n".join(names) + "\n")
    for name, objects in scenes.items():
        (yolo / f"{Path(name).stem}.txt").write_text("".join(
            f"{names.index(o['label'])} {(o['box'][0] + o['box'][2]) / 2 / 848} "
            f"{(o['box'][1] + o['box'][3]) / 2 / 480} {(o['box'][2] - o['box'][0]) / 848} "
            f"{(o['box'][3] - o['box'][1]) / 480}\n" for o in objects))
    scores = {}
    for kind, labels in (("ours", tmp_path / "ours.json"), ("coco", tmp_path / "coco.json"), ("yolo", yolo)):
        assert main(["eval", "detect", str(kart), str(labels), "--json", str(tmp_path / f"{kind}.out.json")]) == 0
        scores[kind] = json.loads((tmp_path / f"{kind}.out.json").read_text())["classes"]
    # YOLO carries no state: what it found is the same, the states read are not compared
    assert scores["coco"] == scores["ours"]
    assert {k: {**v, "state_right": 0} for k, v in scores["yolo"].items()} == \
        {k: {**v, "state_right": 0} for k, v in scores["ours"].items()}
    assert not math.isnan(sum(v["labelled"] for v in scores["ours"].values()))

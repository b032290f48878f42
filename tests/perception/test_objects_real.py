"""The event's objects on the real SDC kart's frames at the Lelystad venue (skipped with the reason when
../shared/data is absent): what the labels list near the kart is found, nothing of the classes the 119 frames
do not hold is reported (and a zebra only where the venue's crossing lies in them), and the people detector looks
where people stand. Development data: the detectors' thresholds were set looking at these frames
(``benchmarks/detect.py`` says so beside its figures)."""

import json
from pathlib import Path

import cv2
import pytest
from tests.conftest import data_path

from kartpilot.core.vehicle import get_vehicle
from kartpilot.perception.detect import DetectorConfig, ObjectDetector
from kartpilot.perception.objects import box_iou
from kartpilot.perception.obstacles import ObstacleConfig, detect_people, upright_things

CAMERA = get_vehicle("sdc-kart").camera("center")
LABELS = json.loads((Path(__file__).parents[1] / "data" / "rdw_objects.json").read_text())


def _scene(name: str):
    image = cv2.imread(str(data_path("rdw-kart", "lelystad-2024", "scenes", name)))
    assert image is not None
    return image


@pytest.mark.parametrize(("name", "label", "state"), [("scene_0.jpg", "car", ""),
                                                      ("scene_1.jpg", "traffic_light", "green"),
                                                      ("scene_1.jpg", "speed_sign", "20")])
def test_a_labelled_object_near_the_kart_is_found_with_its_state(name, label, state):
    """The sign 15 m ahead is 26 px across: found and its 20 read (its digits compared with two fonts, neither
    the sign's own; with one, it scored 0.41 as 20 and 0.42 as 30 and was reported with no value)."""
    found = ObjectDetector(DetectorConfig(), CAMERA)(_scene(name))
    box = next(o["box"] for o in LABELS["images"][f"lelystad-2024/scenes/{name}"] if o["label"] == label)
    hits = [d for d in found if d.label == label and box_iou(d.box_px, tuple(box)) > 0.3]
    print(name, label, [(d.state, round(d.distance_m, 1)) for d in hits])
    assert hits and hits[0].state == state


def test_no_light_sign_or_stop_line_in_the_venue_frames_and_a_zebra_only_where_the_venue_s_crossing_is():
    """The 119 frames hold no light, sign or stop line; the venue's zebra crossing lies far ahead to the left in
    all of them (the labels give its rows and least distance): a zebra reported anywhere else is a false alarm.
    Counted as the detect benchmark counts them (``venue_frames``)."""
    from tests.test_docs_numbers import _script

    frames = data_path("rdw-kart", "lelystad-2024", "frames")
    result = _script("detect").venue_frames(frames.parents[1].parent)
    print(result)
    assert result["frames"] == 119 and result["false_alarms_of_absent_classes"] == 0


def test_people_are_looked_for_where_they_stand_and_only_as_far_as_the_kart_acts():
    """HOG searches around upright things at a person's scale there: it finds the group of people 20 m ahead in
    scene 8 where they stand (their feet at row 177) when asked to look that far (``person_max_distance_m``, and
    ``foot_row_share``, which places a foot to a tenth only to 19 m here); by default (18 m) it reports
    neither them nor the spectators 20 m ahead beside the course in scene 1."""
    image = _scene("scene_8.jpg")
    things = upright_things(image, CAMERA)
    far = detect_people(image, CAMERA, ObstacleConfig(person_max_distance_m=25.0, foot_row_share=0.2), things)
    label = next(o["box"] for o in LABELS["images"]["lelystad-2024/scenes/scene_8.jpg"] if o["label"] == "person")
    mine = [d for d in far if box_iou(d.box_px, tuple(label)) > 0.2]
    print("scene 8 people:", [(round(d.distance_m, 1), round(d.box_px[3])) for d in mine])
    assert mine and all(16.0 <= d.distance_m <= 23.0 for d in mine)
    assert detect_people(image, CAMERA, ObstacleConfig(), things) == []
    assert detect_people(_scene("scene_1.jpg"), CAMERA) == []


def test_another_day_s_exposure_neither_adds_a_light_nor_loses_one_or_the_car():
    """Brightened by 1.4, the unlit red lamp of the venue's green light passed for lit and was a second light;
    darkened to 0.6, the green lamp fell under a fixed lit-lamp brightness and was lost, and the inflatable car
    7 m ahead split where its roof met the sky and was no car."""
    import numpy as np

    def gain(image, factor):
        return np.clip(image.astype(np.float32) * factor, 0, 255).astype(np.uint8)

    lights = [d for d in ObjectDetector(DetectorConfig(), CAMERA)(gain(_scene("scene_1.jpg"), 1.4))
              if d.label == "traffic_light"]
    assert [d.state for d in lights] == ["green"]
    darkened = [d for d in ObjectDetector(DetectorConfig(), CAMERA)(gain(_scene("scene_1.jpg"), 0.6))
                if d.label == "traffic_light"]
    assert [d.state for d in darkened] == ["green"]
    cars = [d for d in ObjectDetector(DetectorConfig(), CAMERA)(gain(_scene("scene_0.jpg"), 0.6)) if d.label == "car"]
    print("darkened car at", [round(d.distance_m, 1) for d in cars])
    assert len(cars) == 1 and 6.0 <= cars[0].distance_m <= 7.5


def test_the_venue_s_20_is_read_as_the_kart_nears_it_and_after_another_compression():
    """The sign in scene 1, enlarged about itself to twice its size (the kart nearing it, 15 to 8 m) and each view
    re-encoded at JPEG 90: read as 20 in every view, knowing the event's values. Knowing 30 and 50 as well (the
    default until 2026-11-26), 4 of these 12 views were left unread, their "2" read about as well as a "3"."""
    from tests.test_docs_numbers import _script

    object_view = _script("detect")._object_view
    image = _scene("scene_1.jpg")
    box = next(o["box"] for o in LABELS["images"]["lelystad-2024/scenes/scene_1.jpg"] if o["label"] == "speed_sign")
    read = []
    for size in (1.0, 1.2, 1.4, 1.6, 1.8, 2.0):
        view, camera, where = object_view(image, CAMERA, box, size)
        for quality in (None, 90):
            if quality is not None:
                view = cv2.imdecode(cv2.imencode(".jpg", view, [cv2.IMWRITE_JPEG_QUALITY, quality])[1],
                                    cv2.IMREAD_COLOR)
            found = [d for d in ObjectDetector(DetectorConfig(people=False), camera)(view)
                     if d.label == "speed_sign" and box_iou(d.box_px, tuple(where)) > 0.3]
            read.append((size, quality, [d.state for d in found]))
    print(read)
    assert all(states == ["20"] for _, _, states in read), read


def test_the_venue_s_signal_pole_is_no_person_as_the_kart_nears_it():
    """Enlarged a fifth and two fifths about itself (the kart nearer), the venue's signal in scene 1 stands on a
    pole whose thin middle breaks the column below its head: its lower part and the tripod's legs, as wide and
    tall as a person, were a person 17 m ahead. A thing under a light or a sign, up to two of its heights below
    it, is its pole."""
    from tests.test_docs_numbers import _script

    object_view = _script("detect")._object_view
    image = _scene("scene_1.jpg")
    box = next(o["box"] for o in LABELS["images"]["lelystad-2024/scenes/scene_1.jpg"] if o["label"] == "traffic_light")
    for size in (1.2, 1.4):
        view, camera, _ = object_view(image, CAMERA, box, size)
        found = ObjectDetector(DetectorConfig(), camera)(view)
        print(size, [(d.label, [round(v) for v in d.box_px]) for d in found])
        assert [d.state for d in found if d.label == "traffic_light"] == ["green"]
        assert not [d for d in found if d.label == "person"]

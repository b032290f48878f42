"""Lane-boundary detection on real road photos, against positions measured by hand, and on synthetic images."""

import cv2
import numpy as np
import pytest
from tests.conftest import data_path

from kartpilot.core.errors import PerceptionError
from kartpilot.perception.lanes import (
    LaneConfig,
    LaneStages,
    SideSearchConfig,
    detect_lanes,
    detect_side_boundary,
    draw_lanes,
    heading_deviation_rad,
)

# (file, side, [(row, column measured by hand on the photo), ...]); measured to about +-15 px
HAND_MEASURED = [
    ("udacity-p1/solidWhiteRight.jpg", "left", [(410, 335)]),
    ("udacity-p1/solidWhiteRight.jpg", "right", [(450, 700), (490, 755)]),
    ("udacity-p1/solidYellowLeft.jpg", "left", [(520, 170), (440, 275)]),
    ("udacity-p1/solidYellowLeft.jpg", "right", [(460, 720), (480, 750)]),
    ("udacity-advanced/straight_lines1.jpg", "left", [(670, 270), (590, 400), (510, 530)]),
    ("udacity-advanced/straight_lines1.jpg", "right", [(670, 1015), (510, 760)]),
    ("udacity-advanced/test1.jpg", "left", [(670, 305), (590, 410)]),  # yellow paint on light concrete
]


@pytest.mark.parametrize(("name", "side", "points"), HAND_MEASURED)
def test_boundaries_on_real_road_photos_match_hand_measurements(name, side, points):
    image = cv2.imread(str(data_path("road-lanes", name)))
    observation = detect_lanes(image)
    line = observation.left if side == "left" else observation.right
    assert (observation.left_source if side == "left" else observation.right_source) == "detected"
    tolerance = 0.03 * image.shape[1]
    for row, column in points:
        assert abs(line.x_at(row) - column) < tolerance, f"{name} {side} at row {row}: {line.x_at(row):.0f} vs {column}"


def test_every_road_photo_gives_both_boundaries_converging_ahead():
    folder = data_path("road-lanes")
    photos = sorted(folder.rglob("*.jpg"))
    assert len(photos) >= 10
    for path in photos:
        image = cv2.imread(str(path))
        h, w = image.shape[:2]
        observation = detect_lanes(image)
        assert observation.both_detected, path.name
        x, y = observation.intersection_px
        assert 0.3 * w < x < 0.7 * w and 0.4 * h < y < 0.7 * h, path.name
        assert observation.left.x_bottom < w / 2 < observation.right.x_bottom


def synthetic_road(shift_px: float = 0.0, w: int = 960, h: int = 540, left: bool = True, right: bool = True):
    """Grey tarmac with two white boundaries converging at (w/2 + shift, 0.55 h)."""
    image = np.full((h, w, 3), 80, np.uint8)
    vp = (int(w / 2 + shift_px), int(0.55 * h))
    if left:
        cv2.line(image, (int(0.1 * w + shift_px), h - 1), vp, (235, 235, 235), 8)
    if right:
        cv2.line(image, (int(0.9 * w + shift_px), h - 1), vp, (235, 235, 235), 8)
    cv2.rectangle(image, (0, 0), (w, int(0.55 * h)), (200, 170, 140), -1)
    return image


def test_heading_follows_the_intersection_and_a_missing_side_uses_the_extreme_column():
    centred = detect_lanes(synthetic_road())
    assert centred.both_detected
    assert abs(heading_deviation_rad(centred)) < 0.03
    right_turn = detect_lanes(synthetic_road(shift_px=120))
    assert heading_deviation_rad(right_turn) > 0.15  # the lanes bend right: steer right
    one_sided = detect_lanes(synthetic_road(right=False))
    assert one_sided.left_source == "detected" and one_sided.right_source == "extreme"
    assert one_sided.right.x_bottom == 959 and one_sided.confidence < centred.confidence
    empty = detect_lanes(np.full((540, 960, 3), 80, np.uint8))
    assert not empty.any_detected and empty.confidence == 0.0


def test_standard_hough_and_stages_for_the_figures():
    stages = LaneStages()
    observation = detect_lanes(synthetic_road(), LaneConfig(hough="standard"), stages)
    assert observation.both_detected
    assert stages.edges is not None and len(stages.raw) >= len(stages.after_slope) > 0
    canvas = draw_lanes(synthetic_road(), observation, 0.1, stages)
    assert canvas.shape == (540, 960, 3)


def test_side_camera_steer_grows_as_the_boundary_nears_and_ignores_dark_tyre_marks():
    def side_image(line_row: int, colour: int) -> np.ndarray:
        image = np.full((480, 640), 90, np.uint8)
        cv2.line(image, (0, line_row - 20), (639, line_row + 20), colour, 14)
        return image

    band = (200, 480)
    far = detect_side_boundary(side_image(260, 240), band, 320)
    near = detect_side_boundary(side_image(420, 240), band, 320)
    assert 0.0 < far.steer < near.steer <= 1.0
    assert detect_side_boundary(side_image(420, 20), band, 320).steer == 0.0  # a tyre mark, darker than tarmac
    assert detect_side_boundary(np.full((480, 640), 90, np.uint8), band, 320).steer == 0.0
    with pytest.raises(PerceptionError):
        detect_side_boundary(side_image(300, 240), (478, 480), 320, SideSearchConfig())


def test_empty_frame_is_a_clear_error():
    with pytest.raises(PerceptionError, match="empty"):
        detect_lanes(np.zeros((0, 0, 3), np.uint8))

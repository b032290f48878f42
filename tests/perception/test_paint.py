"""The paint finder (perception/paint.py) on synthetic views of painted ground through the real kart's camera
model: curves fitted where the paint is, upright stripes and paint across the lane left out, the aim row."""

import cv2
import numpy as np
import pytest

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.geometry import invert_pose, transform_points
from kartpilot.core.vehicle import camera_pose_on_body
from kartpilot.perception.lanes import LaneConfig, detect_lanes
from kartpilot.perception.paint import PaintConfig, fit_curve

CAMERA = PinholeCamera(640.0, 640.0, 423.5, 239.5, 848, 480, (),
                       camera_pose_on_body(0.0, 0.0, 0.56, pitch_down_deg=6.8))
CONFIG = LaneConfig(method="paint", roi_top_width=1.0, min_abs_slope=0.1,
                    curves=PaintConfig(horizon=0.5 - np.tan(np.radians(6.8)) * 640 / 480))


def _to_image(points_xyz: np.ndarray) -> np.ndarray:
    cam = transform_points(invert_pose(CAMERA.pose_body_cam_array), points_xyz)
    return CAMERA.project(cam)


def ground_view(curvature: float = 0.0, lateral_m: float = 0.0, width_m: float = 3.0, seed: int = 0):
    """Asphalt with two 0.10 m lines of a lane ``width_m`` wide bending at ``curvature`` (1/m), the camera
    ``lateral_m`` left of the lane's centre; and the lines' true columns at some rows."""
    rng = np.random.default_rng(seed)
    image = np.clip(rng.normal(125, 14, (480, 848, 3)), 0, 255).astype(np.uint8)
    image[:150] = 235  # an overcast sky
    d = np.linspace(0.8, 40.0, 600)
    truth = {}
    for side, offset in (("left", width_m / 2), ("right", -width_m / 2)):
        centre = offset - lateral_m + 0.5 * curvature * d ** 2
        strip = np.vstack([np.column_stack([d, centre + 0.05, np.zeros_like(d)]),
                           np.column_stack([d[::-1], centre[::-1] - 0.05, np.zeros_like(d)])])
        cv2.fillPoly(image, [np.round(_to_image(strip) * 16).astype(np.int32)], (245, 245, 245), cv2.LINE_AA, 4)
        px = _to_image(np.column_stack([d, centre, np.zeros_like(d)]))
        truth[side] = px
    return image, truth


def _column_at(px: np.ndarray, row: float) -> float:
    order = np.argsort(px[:, 1])
    return float(np.interp(row, px[order, 1], px[order, 0]))


@pytest.mark.parametrize("curvature", [0.0, 0.08, -0.08])
def test_curves_follow_the_painted_lines_straight_and_bending(curvature):
    image, truth = ground_view(curvature)
    observation = detect_lanes(image, CONFIG)
    assert observation.both_detected
    for side in ("left", "right"):
        curve = getattr(observation, f"{side}_curve")
        for row in (300.0, 360.0, 420.0):
            expected = _column_at(truth[side], row)
            if 0 <= expected < 848:
                assert abs(float(curve.x_at(row)) - expected) < 6.0, (side, row)
    # the aim: the lane's centre on the aim row, toward the bend
    x_aim, y_aim = observation.intersection_px
    horizon = CONFIG.curves.horizon * 480
    assert y_aim == pytest.approx(horizon + CONFIG.aim_below_horizon * (479 - horizon), abs=0.5)
    if curvature > 0:
        assert x_aim < 423.5 - 10  # the lane bends left
    elif curvature < 0:
        assert x_aim > 423.5 + 10
    else:
        assert abs(x_aim - 423.5) < 5


def test_upright_white_stripes_and_paint_across_the_lane_are_not_boundaries():
    image, truth = ground_view(seed=1)
    # a red-and-white barrier standing in front of the kart, right of centre: vertical white stripes
    for k in range(4):
        x0 = 470 + 16 * k
        image[200:260, x0:x0 + 8] = (235, 235, 235)
        image[200:260, x0 + 8:x0 + 16] = (40, 40, 200)
    # a stop line across the lane 6 m ahead
    bar = np.array([[6.0, -1.5, 0], [6.3, -1.5, 0], [6.3, 1.5, 0], [6.0, 1.5, 0]])
    cv2.fillPoly(image, [np.round(_to_image(bar)).astype(np.int32)], (245, 245, 245))
    observation = detect_lanes(image, CONFIG)
    assert observation.both_detected
    for side in ("left", "right"):
        curve = getattr(observation, f"{side}_curve")
        rows = [row for row in (240.0, 270.0, 300.0, 420.0) if 0 <= _column_at(truth[side], row) < 848]
        assert rows
        for row in rows:
            assert abs(float(curve.x_at(row)) - _column_at(truth[side], row)) < 6.0, (side, row)


def test_a_zebra_s_bars_along_the_road_are_not_boundaries():
    """A zebra's bars run along the road as a boundary does, 0.5 m wide: the ridge kernel of a band of rows, sized
    at its nearest row, let them through whole at its far rows, and a kart moving off just before a crossing (sweep
    event 10369) took two bars for the lane's boundaries and touched its line. What passes wider than its own row's
    kernel is not paint of a line."""
    image, truth = ground_view(seed=2)
    for middle in (-1.0, 0.0, 1.0):  # three bars, 0.5 m wide and 3 m long, from 2.5 m ahead
        bar = np.array([[2.5, middle - 0.25, 0], [5.5, middle - 0.25, 0], [5.5, middle + 0.25, 0],
                        [2.5, middle + 0.25, 0]])
        cv2.fillPoly(image, [np.round(_to_image(bar)).astype(np.int32)], (245, 245, 245))
    observation = detect_lanes(image, CONFIG)
    assert observation.both_detected
    for side in ("left", "right"):
        curve = getattr(observation, f"{side}_curve")
        rows = [row for row in (300.0, 360.0, 420.0) if 0 <= _column_at(truth[side], row) < 848]
        for row in rows:
            assert abs(float(curve.x_at(row)) - _column_at(truth[side], row)) < 6.0, (side, row)


def test_a_short_stretch_of_rows_gives_a_straight_line_not_a_curve():
    ys = np.linspace(300, 320, 10)
    coef = fit_curve(100 + 2.0 * (ys - 163), ys, 163.0)
    assert coef is not None and coef[2] == 0.0 and coef[1] == pytest.approx(2.0)

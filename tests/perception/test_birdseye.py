"""The road's top view and the planar pose between two of them, on a flat textured road seen by the kart's
camera from known poses."""

import math

import numpy as np
import pytest
from tests.conftest import KART, road_texture, road_view

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.perception.birdseye import (
    BirdseyeConfig,
    birdseye,
    birdseye_grid,
    planar_transform,
    register_birdseye,
    road_grids,
)

CONFIG = BirdseyeConfig()


def _body(x_m: float, y_m: float, yaw_deg: float) -> np.ndarray:
    pose = np.eye(4)
    pose[[0, 0, 1, 1], [0, 1, 0, 1]] = planar_transform(0.0, 0.0, math.radians(yaw_deg))[:2, :2].ravel()
    pose[:2, 3] = x_m, y_m
    return pose


def _register(texture: np.ndarray, query_pose: np.ndarray, yaw_guess_deg: float = 0.0, gain: float = 1.0,
              offset: float = 0.0):
    reference_grid, query_grid = road_grids(KART, CONFIG)
    reference = birdseye(road_view(texture, np.eye(4), 0.01), reference_grid)
    image = np.clip(road_view(texture, query_pose, 0.01) * gain + offset, 0, 255).astype(np.uint8)
    return register_birdseye(reference, birdseye(image, query_grid), reference_grid, query_grid,
                             math.radians(yaw_guess_deg), CONFIG)


def test_a_ground_point_lands_on_its_top_view_pixel():
    grid = birdseye_grid(KART, 3.0, 8.0, 1.0, 0.05)
    assert grid.mask.all()
    point = np.array([5.0, -0.5, 0.0, 1.0])  # 5 m ahead of the rear axle, 0.5 m to the right
    column, row, _ = grid.pixel_from_body @ [point[0], point[1], 1.0]
    pixel = KART.project((np.linalg.inv(KART.pose_body_cam_array) @ point)[None, :3])[0]
    at = round(row), round(column)
    assert (grid.map_x[at], grid.map_y[at]) == pytest.approx(pixel, abs=0.5)
    assert column > grid.shape[1] / 2 and row > 0  # right of the middle, below the far edge


@pytest.mark.parametrize(("x_m", "y_m", "yaw_deg"), [(0.0, 0.0, 0.0), (0.45, -0.3, 2.0), (-0.4, 0.6, -3.5),
                                                      (0.2, 0.9, 4.0)])
def test_the_query_s_pose_relative_to_the_reference_is_found(x_m, y_m, yaw_deg):
    found = _register(road_texture(5), _body(x_m, y_m, yaw_deg), yaw_guess_deg=yaw_deg + 1.5)
    assert found is not None
    print(f"true {x_m:+.2f} {y_m:+.2f} m {yaw_deg:+.1f} deg; found {found.x_m:+.3f} {found.y_m:+.3f} m "
          f"{math.degrees(found.yaw_rad):+.2f} deg, correlation {found.correlation:.2f}")
    assert (found.x_m, found.y_m) == pytest.approx((x_m, y_m), abs=0.02)
    assert math.degrees(found.yaw_rad) == pytest.approx(yaw_deg, abs=0.2)


def test_a_change_of_light_does_not_move_the_registration():
    found = _register(road_texture(6), _body(0.3, -0.4, 1.0), gain=0.45, offset=30.0)
    assert found is not None
    assert (found.x_m, found.y_m) == pytest.approx((0.3, -0.4), abs=0.02)
    assert math.degrees(found.yaw_rad) == pytest.approx(1.0, abs=0.2)


def test_no_pose_from_a_blank_road_or_an_offset_beyond_the_search():
    assert _register(np.full((4000, 4000), 120, np.uint8), _body(0.2, 0.0, 0.0)) is None
    # 2 m to the side: beyond the 1.2 m margin (two camera heights), so the best match lies on the edge
    assert _register(road_texture(7), _body(0.0, 2.0, 0.0)) is None


def test_the_road_patch_needs_a_mount_and_a_view_of_the_road():
    with pytest.raises(ConfigError, match="mount"):
        road_grids(PinholeCamera(480.0, 480.0, 319.5, 239.5, 640, 480), CONFIG)
    with pytest.raises(ConfigError, match="far_heights"):
        BirdseyeConfig(near_heights=5.0, far_heights=4.0)

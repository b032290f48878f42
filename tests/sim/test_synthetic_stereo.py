import numpy as np

from kartpilot.perception.stereo import triangulate_rectified
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource


def test_rendering_is_deterministic_and_textured() -> None:
    first = SyntheticStereoSource(SyntheticStereoConfig(frames=3, seed=4)).frame(1)
    again = SyntheticStereoSource(SyntheticStereoConfig(frames=3, seed=4)).frame(1)
    np.testing.assert_array_equal(first.left, again.left)
    assert first.left.std() > 20


def test_ground_point_lands_where_the_camera_model_projects_it() -> None:
    source = SyntheticStereoSource(SyntheticStereoConfig(frames=1, yaw_rate_dps=0.0))
    config = source.config
    # the ground is the plane y = camera height; a point 6 m ahead on it, seen by both cameras
    point = np.array([[0.3, config.camera_height_m, 6.0]])
    left = source.rig.camera.project(point)
    right = source.rig.camera.project(point - [config.baseline_m, 0, 0])
    np.testing.assert_allclose(triangulate_rectified(source.rig, left, right), point, atol=1e-9)
    frame = source.frame(0)
    row = round(left[0, 1])
    assert row > config.height_px / 2  # the ground is below the horizon
    assert frame.left[row, int(left[0, 0])] != frame.left[0, 0]  # ground, not sky

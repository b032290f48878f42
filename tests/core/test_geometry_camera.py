import numpy as np
import pytest

from kartpilot.core.camera import PinholeCamera, StereoRig
from kartpilot.core.errors import CalibrationError
from kartpilot.core.geometry import (
    invert_pose,
    pose_from_quaternion,
    pose_from_rotvec,
    quaternion_xyzw_from_pose,
    relative_pose,
    rotation_angle_rad,
    transform_points,
)


def test_pose_inverse_and_relative() -> None:
    pose = pose_from_rotvec(np.array([0.1, -0.2, 0.3]), np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(pose @ invert_pose(pose), np.eye(4), atol=1e-12)
    other = pose_from_rotvec(np.array([0.0, 0.5, 0.0]), np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(pose @ relative_pose(pose, other), other, atol=1e-12)
    assert rotation_angle_rad(other) == pytest.approx(0.5)


def test_quaternion_round_trip_and_points() -> None:
    pose = pose_from_rotvec(np.array([0.3, 0.2, -0.1]), np.array([0.5, 0.0, -1.0]))
    back = pose_from_quaternion(quaternion_xyzw_from_pose(pose), pose[:3, 3])
    np.testing.assert_allclose(back, pose, atol=1e-12)
    points = np.array([[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(transform_points(invert_pose(pose), transform_points(pose, points)), points)


def test_rig_from_kitti_projections() -> None:
    P0 = np.array([[707.0912, 0, 601.8873, 0], [0, 707.0912, 183.1104, 0], [0, 0, 1, 0]])
    P1 = P0.copy()
    P1[0, 3] = -379.8145
    rig = StereoRig.from_projections(P0, P1, (1226, 370))
    assert rig.baseline_m == pytest.approx(0.53716, abs=1e-5)
    np.testing.assert_allclose(rig.P1, P1, atol=1e-9)
    assert rig.depth_from_disparity(np.array([rig.camera.fx_px * rig.baseline_m / 10.0]))[0] == pytest.approx(10.0)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"fx_px": -1.0},
        {"cx_px": 5000.0},
        {"width_px": 0},
        {"distortion": (0.1, 0.2, 0.3)},
    ],
)
def test_implausible_calibration_is_rejected(kwargs: dict) -> None:
    values = {"fx_px": 500.0, "fy_px": 500.0, "cx_px": 320.0, "cy_px": 240.0, "width_px": 640, "height_px": 480}
    values.update(kwargs)
    with pytest.raises(CalibrationError):
        PinholeCamera(**values)


def test_rig_rejects_swapped_cameras_and_mismatched_k() -> None:
    camera = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    with pytest.raises(CalibrationError, match="baseline"):
        StereoRig(camera, -0.1)
    P0 = np.hstack([camera.matrix, np.zeros((3, 1))])
    P1 = P0.copy()
    P1[0, 0] = 510.0
    with pytest.raises(CalibrationError, match="share"):
        StereoRig.from_projections(P0, P1, (640, 480))

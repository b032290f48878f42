"""A lens's distortion rendered and taken out again: points land where OpenCV's lens model puts them."""

import cv2
import numpy as np
import pytest

from kartpilot.calibration.lens import lens_distortion, undistortion
from kartpilot.core.camera import PinholeCamera

# a wide-angle kart camera: strong barrel distortion
CAMERA = PinholeCamera(320.0, 320.0, 322.0, 238.0, 640, 480, distortion=(-0.30, 0.09, 0.001, -0.001, 0.0))


def _dots(camera: PinholeCamera, points: np.ndarray, distorted: bool) -> np.ndarray:
    pixels, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera.matrix,
                                  np.asarray(camera.distortion if distorted else (), float))
    return pixels.reshape(-1, 2)


def _centroids(image: np.ndarray, near: np.ndarray) -> np.ndarray:
    found = []
    for u, v in near:
        x0, y0 = int(u) - 12, int(v) - 12
        patch = image[y0:y0 + 25, x0:x0 + 25].astype(float)
        ys, xs = np.nonzero(patch > 40)
        weights = patch[ys, xs]
        found.append((x0 + np.average(xs, weights=weights), y0 + np.average(ys, weights=weights)))
    return np.array(found)


def test_a_rendered_lens_bends_points_as_the_model_says_and_undistortion_takes_it_out():
    points = np.array([[x, y, 4.0] for x in (-3.0, -1.5, 0.0, 1.5, 3.0) for y in (-2.0, 0.0, 2.0)])
    pinhole_px = _dots(CAMERA, points, distorted=False)
    pinhole = np.zeros((480, 640), np.uint8)
    for u, v in pinhole_px:
        cv2.circle(pinhole, (round(u * 16), round(v * 16)), 3 * 16, 255, -1, cv2.LINE_AA, shift=4)
    bend = lens_distortion(CAMERA)
    straighten = undistortion(CAMERA)
    assert bend is not None and straighten is not None and straighten.pinhole.distortion == ()
    distorted = bend(pinhole)
    expected = _dots(CAMERA, points, distorted=True)
    error = np.linalg.norm(_centroids(distorted, expected) - expected, axis=1)
    print(f"rendered lens: dots {np.max(np.linalg.norm(expected - pinhole_px, axis=1)):.1f} px bent, "
          f"{error.max():.2f} px from OpenCV's model")
    assert np.max(np.linalg.norm(expected - pinhole_px, axis=1)) > 20  # the lens does bend them
    assert error.max() < 0.5
    back = _centroids(straighten(distorted), pinhole_px)
    assert np.linalg.norm(back - pinhole_px, axis=1).max() < 0.6


def test_a_camera_without_distortion_needs_no_remap():
    camera = PinholeCamera(320.0, 320.0, 320.0, 240.0, 640, 480)
    assert undistortion(camera) is None and lens_distortion(camera) is None
    assert undistortion(PinholeCamera(320.0, 320.0, 320.0, 240.0, 640, 480, distortion=(0.0, 0.0, 0.0, 0.0))) is None


@pytest.mark.parametrize("size", [(640, 480), (160, 120)])
def test_the_maps_have_the_camera_s_size(size):
    camera = PinholeCamera(size[0] / 2, size[0] / 2, size[0] / 2, size[1] / 2, *size, distortion=(-0.2, 0.05, 0, 0))
    for remap in (undistortion(camera), lens_distortion(camera)):
        assert remap is not None and remap(np.zeros((size[1], size[0], 3), np.uint8)).shape == (size[1], size[0], 3)

"""One camera's lens: undistortion for the pipelines that take images as a pinhole's, and distortion for the
simulator to render a real lens.

Monocular VO, the road's top view and VLAD's geometric check all assume a pinhole camera. A real lens bends
straight lines (a kart's wide-angle lens a lot), so its images are undistorted once, on the way into the
pipeline, to a pinhole camera with the same camera matrix (:func:`undistortion`). The place database
records the pinhole camera it was built with, and a query checks it (:mod:`kartpilot.odometry.places`).
:func:`lens_distortion` is the opposite remapping: the simulator renders a pinhole image and bends it the
way the rig's coefficients say.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.types import Image

__all__ = ["LensRemap", "lens_distortion", "undistortion"]


@dataclass(frozen=True)
class LensRemap:
    """A remapping between a camera with a lens and its pinhole twin (the same camera matrix, no distortion).

    Attributes:
        camera: the real camera, with its distortion coefficients.
        pinhole: the same camera without them: what the remapped images are.
        maps: cv2.remap's tables.
    """

    camera: PinholeCamera
    pinhole: PinholeCamera
    maps: tuple[np.ndarray, np.ndarray]

    def __call__(self, image: Image) -> Image:
        return cv2.remap(image, self.maps[0], self.maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def undistortion(camera: PinholeCamera) -> LensRemap | None:
    """The remapping from ``camera``'s images to a pinhole's with the same camera matrix; None for a camera
    without distortion."""
    if not any(camera.distortion):
        return None
    pinhole = replace(camera, distortion=())
    maps = cv2.initUndistortRectifyMap(camera.matrix, np.asarray(camera.distortion, float), None, camera.matrix,
                                       camera.size_wh, cv2.CV_32FC1)
    return LensRemap(camera, pinhole, (maps[0], maps[1]))


def lens_distortion(camera: PinholeCamera) -> LensRemap | None:
    """The remapping from a pinhole rendering to what ``camera``'s lens shows (the inverse of
    :func:`undistortion`): each distorted pixel looks up where its ray lands on the pinhole image. None for a
    camera without distortion."""
    if not any(camera.distortion):
        return None
    w, h = camera.size_wh
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1).reshape(-1, 1, 2)
    pinhole_px = cv2.undistortPointsIter(grid, camera.matrix, np.asarray(camera.distortion, float), None,
                                         camera.matrix, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-6))
    table = pinhole_px.reshape(h, w, 2).astype(np.float32)
    return LensRemap(camera, replace(camera, distortion=()), (table[..., 0].copy(), table[..., 1].copy()))

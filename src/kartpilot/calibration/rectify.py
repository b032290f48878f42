"""Stereo rectification of two calibrated cameras (Bouguet's method, via OpenCV).

Given each camera's intrinsics and distortion and the rigid transform from the
left to the right camera, compute rotations that make epipolar lines horizontal,
a shared rectified camera matrix, and the remap tables that turn raw images into
rectified ones. The maps are computed once and reused for every frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from kartpilot.core.camera import PinholeCamera, StereoRig
from kartpilot.core.errors import CalibrationError
from kartpilot.core.geometry import Array
from kartpilot.core.types import Image

__all__ = ["StereoRectification", "rectify_stereo"]


@dataclass(frozen=True)
class StereoRectification:
    """Remap tables and the rectified rig they produce.

    Attributes:
        rig: the rectified stereo rig (shared K, baseline in metres).
        rotation_rect_left, rotation_rect_right: 3x3 rotations from each raw camera frame to its
            rectified frame.
    """

    rig: StereoRig
    rotation_rect_left: Array
    left_maps: tuple[np.ndarray, np.ndarray]
    right_maps: tuple[np.ndarray, np.ndarray]
    rotation_rect_right: Array = field(default_factory=lambda: np.eye(3))

    def rectify(self, left: Image, right: Image) -> tuple[Image, Image]:
        """Rectify a raw pair (bilinear interpolation)."""
        left_rect = cv2.remap(left, *self.left_maps, interpolation=cv2.INTER_LINEAR)
        right_rect = cv2.remap(right, *self.right_maps, interpolation=cv2.INTER_LINEAR)
        return left_rect, right_rect


def rectify_stereo(left: PinholeCamera, right: PinholeCamera, pose_right_left: Array) -> StereoRectification:
    """Compute the rectification of a calibrated pair.

    Args:
        left, right: intrinsics and distortion of the raw cameras (same image size).
        pose_right_left: 4x4 transform taking points from the left camera frame to the right one.

    Raises:
        CalibrationError: when the sizes differ or the right camera is not to the right.
    """
    if left.size_wh != right.size_wh:
        raise CalibrationError(f"stereo cameras differ in size: {left.size_wh} vs {right.size_wh}")
    pose = np.asarray(pose_right_left, dtype=np.float64)
    rotation, translation = pose[:3, :3], pose[:3, 3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4):
        raise CalibrationError("the stereo extrinsic rotation is not orthonormal")
    if translation[0] >= 0:
        raise CalibrationError(
            "the right camera must lie to the right of the left one (t_x < 0 in the right camera frame); "
            "are the cameras swapped?"
        )
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        left.matrix, left.distortion_array, right.matrix, right.distortion_array,
        left.size_wh, rotation, translation, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
    )
    left_maps = cv2.initUndistortRectifyMap(
        left.matrix, left.distortion_array, R1, P1, left.size_wh, cv2.CV_16SC2)
    right_maps = cv2.initUndistortRectifyMap(
        right.matrix, right.distortion_array, R2, P2, right.size_wh, cv2.CV_16SC2)
    rig = StereoRig.from_projections(P1, P2, left.size_wh)
    return StereoRectification(rig, np.asarray(R1, dtype=np.float64), left_maps, right_maps,
                               np.asarray(R2, dtype=np.float64))

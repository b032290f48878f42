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
from kartpilot.core.geometry import Array, invert_pose
from kartpilot.core.types import Image

__all__ = ["StereoRectification", "StereoSetup", "rectify_stereo", "stereo_setup"]


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


@dataclass(frozen=True)
class StereoSetup:
    """A calibrated pair ready for the stereo pipeline: the rectified rig, the remapping (None when the
    cameras are already rectified) and the rectified left camera's pose on the kart."""

    rig: StereoRig
    rectification: StereoRectification | None
    pose_body_left: Array

    def rectify(self, left: Image, right: Image) -> tuple[Image, Image]:
        return (left, right) if self.rectification is None else self.rectification.rectify(left, right)


def stereo_setup(left: PinholeCamera, right: PinholeCamera) -> StereoSetup:
    """The stereo pipeline's view of two cameras calibrated on the kart (their poses give the extrinsics)."""
    pose_right_left = invert_pose(right.pose_body_cam_array) @ left.pose_body_cam_array
    if not left.distortion and not right.distortion and np.allclose(pose_right_left[:3, :3], np.eye(3)):
        if left.size_wh != right.size_wh or not np.allclose(left.matrix, right.matrix, atol=1e-6):
            raise CalibrationError("unrectified stereo cameras with different intrinsics need a rectification")
        return StereoSetup(StereoRig(left, float(-pose_right_left[0, 3])), None, left.pose_body_cam_array)
    rectification = rectify_stereo(left, right, pose_right_left)
    rect_raw = np.eye(4)
    rect_raw[:3, :3] = rectification.rotation_rect_left.T  # rectified axes in the raw camera frame
    return StereoSetup(rectification.rig, rectification, left.pose_body_cam_array @ rect_raw)

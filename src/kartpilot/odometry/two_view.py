"""Two-view motion from features: the thesis's monocular front end, one frame pair at a time.

The first part of the thesis compared ORB and SIFT features, brute-force and FLANN matching and KLT
tracking, and ratio thresholds from 0.6 to 0.9, before the essential matrix and ``recoverPose``. This
is that front end as a pure function, so the comparison can be run on any frame pair with known motion
(``kartpilot study run detectors``). The metric scale is not part of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from kartpilot.core.geometry import Array
from kartpilot.core.types import Image
from kartpilot.odometry.mono_vo import relative_pose
from kartpilot.perception.features import FeatureConfig, create_detector, detect_features
from kartpilot.perception.matching import MatchConfig, match_descriptors
from kartpilot.perception.tracking import KltConfig, track_klt

__all__ = ["TwoViewMotion", "rotation_angle_deg", "two_view_motion"]


@dataclass(frozen=True)
class TwoViewMotion:
    """Attributes:
        matches: correspondences found (descriptor matches after the ratio test, or KLT tracks kept).
        inliers: the essential matrix's RANSAC inliers.
        rotation: (3, 3) taking points from the first camera's frame to the second's (None: no motion found).
        direction: the unit translation in the second camera's frame (None: no motion found).
    """

    matches: int
    inliers: int
    rotation: Array | None
    direction: Array | None


def rotation_angle_deg(rotation: Array) -> float:
    return math.degrees(math.acos(float(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0))))


def two_view_motion(image_a: Image, image_b: Image, camera_matrix: Array, features: FeatureConfig,
                    matching: MatchConfig, correspondence: Literal["descriptor", "klt"], klt: KltConfig,
                    ransac_px: float = 1.0) -> TwoViewMotion:
    """Features in ``image_a``, found again in ``image_b`` by descriptor matching or KLT, then the essential
    matrix with RANSAC and ``recoverPose``."""
    detector, binary = create_detector(features)
    first = detect_features(image_a, detector, binary, features)
    if correspondence == "klt":
        tracked, ok = track_klt(image_a, image_b, first.points_px, klt)
        p0, p1 = first.points_px[ok], tracked[ok]
    else:
        second = detect_features(image_b, detector, binary, features)
        found = match_descriptors(first.descriptors, second.descriptors, binary, matching)
        p0, p1 = first.points_px[found.index_a], second.points_px[found.index_b]
    motion = relative_pose(np.ascontiguousarray(p0, np.float64), np.ascontiguousarray(p1, np.float64),
                           camera_matrix, ransac_px, 0.999)
    if motion is None:
        return TwoViewMotion(len(p0), 0, None, None)
    rotation, direction, mask = motion
    return TwoViewMotion(len(p0), int(mask.sum()), rotation, direction / max(float(np.linalg.norm(direction)), 1e-12))

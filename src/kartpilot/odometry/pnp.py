"""Frame-to-frame motion from 2D-3D correspondences: PnP in RANSAC, then
Levenberg-Marquardt refinement of the reprojection error on the inliers.

Fischler and Bolles, "Random sample consensus", CACM 1981; the minimal solver is
Ke and Roumeliotis' AP3P (CVPR 2017); refinement minimises
``sum ||u_i - pi(K (R X_i + t))||^2`` (Madsen et al., "Methods for non-linear
least squares problems", 2004).

Frames: ``X_i`` are points in the previous left camera frame, ``u_i`` their pixels
in the current left image; the result ``pose_cur_prev`` maps previous-camera
points into the current camera (``X_cur = T X_prev``). The camera's own motion is
its inverse.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array, cross_matrix, pose_from_rt, projection_jacobian

__all__ = [
    "AttitudePrior",
    "MotionEstimate",
    "PnpConfig",
    "estimate_motion_from_prior",
    "estimate_motion_pnp",
    "refine_translation",
    "refine_translation_near",
    "refine_with_attitude_prior",
    "reprojection_errors",
]


@dataclass(frozen=True)
class PnpConfig:
    """Motion estimation settings.

    Attributes:
        reprojection_px: RANSAC inlier threshold.
        iterations: RANSAC iterations.
        confidence: RANSAC confidence.
        min_inliers: fewest inliers accepted (the thesis required 8 to 10).
        refine_lm: refine the RANSAC pose with Levenberg-Marquardt on the inliers.
        translation_min_disparity_px: after the full refinement, re-estimate the translation
            (rotation fixed) from inliers with at least this disparity. Depth from a small
            disparity is biased long (E[1/d] > 1/E[d]), which inflates the translation;
            far points still fix the rotation. 0 disables the step.
        translation_min_points: fewest near inliers needed for that step.
    """

    reprojection_px: float = 1.5
    iterations: int = 300
    confidence: float = 0.999
    min_inliers: int = 8
    refine_lm: bool = True
    translation_min_disparity_px: float = 20.0
    translation_min_points: int = 12

    def __post_init__(self) -> None:
        if self.min_inliers < 6:
            raise ConfigError(f"pnp.min_inliers must be at least 6 (a pose has 6 DoF), got {self.min_inliers}")
        if self.reprojection_px <= 0:
            raise ConfigError("pnp.reprojection_px must be positive")


@dataclass(frozen=True)
class MotionEstimate:
    """Result of one PnP solve.

    Attributes:
        pose_cur_prev: 4x4 transform of points from the previous to the current camera frame.
        inliers: indices of the correspondences that agree with the pose.
        reprojection_rmse_px: RMS reprojection error over the inliers.
        ok: False when no acceptable pose was found; ``reason`` says why.
    """

    pose_cur_prev: Array
    inliers: NDArray[np.intp]
    reprojection_rmse_px: float
    ok: bool
    reason: str = ""


@dataclass(frozen=True)
class AttitudePrior:
    """A ground vehicle's roll and pitch stay near its mount's: the current camera's up direction, in its own
    frame, is expected near ``up_mount`` (the body's up seen from the camera on its mount), within
    ``sigma_rad``. ``up_prev`` is the previous camera's up as the estimate so far has it. Yaw is free."""

    up_prev: Array
    up_mount: Array
    sigma_rad: float


def refine_with_attitude_prior(pose_cur_prev: Array, points_prev_m: Array, pixels_cur: Array, camera_matrix: Array,
                               prior: AttitudePrior, pixel_sigma_px: float = 1.0, iterations: int = 5) -> Array:
    """Gauss-Newton on the whole motion with the reprojection errors (``pixel_sigma_px`` each) and the attitude
    prior: ``R up_prev - up_mount`` over ``prior.sigma_rad``, a residual in the camera's roll and pitch only.

    It is a prior, not a clamp: where the points say the camera tilted (a ramp, a kerb) and they are many, they
    win; where few points leave the roll poorly measured (a bend's far side), the prior holds it, and the
    roll that frame-to-frame VO otherwise builds up by a fraction of a degree a frame does not grow."""
    pose = np.asarray(pose_cur_prev, dtype=np.float64).copy()
    points = np.asarray(points_prev_m, dtype=np.float64)
    pixels = np.asarray(pixels_cur, dtype=np.float64)
    fx, fy, cx, cy = camera_matrix[0, 0], camera_matrix[1, 1], camera_matrix[0, 2], camera_matrix[1, 2]
    up_prev, up_mount = np.asarray(prior.up_prev, np.float64), np.asarray(prior.up_mount, np.float64)
    for _ in range(iterations):
        moved = points @ pose[:3, :3].T + pose[:3, 3]
        z = moved[:, 2]
        if np.any(z <= 1e-6):
            return np.asarray(pose_cur_prev, dtype=np.float64)
        residual = np.concatenate([(fx * moved[:, 0] / z + cx - pixels[:, 0]) / pixel_sigma_px,
                                   (fy * moved[:, 1] / z + cy - pixels[:, 1]) / pixel_sigma_px])
        d_point = projection_jacobian(moved, fx, fy) / pixel_sigma_px  # (N, 2, 3)
        d_trans = d_point.transpose(1, 0, 2).reshape(-1, 3)  # the u rows, then the v rows
        # a small rotation w applied on the left moves each point by w x X = -[X]x w
        d_rot = -(d_point @ cross_matrix(moved)).transpose(1, 0, 2).reshape(-1, 3)
        up = pose[:3, :3] @ up_prev
        prior_residual = (up - up_mount) / prior.sigma_rad
        prior_rot = -cross_matrix(up) / prior.sigma_rad
        jacobian = np.vstack([np.hstack([d_rot, d_trans]), np.hstack([prior_rot, np.zeros((3, 3))])])
        step = np.linalg.lstsq(jacobian, -np.concatenate([residual, prior_residual]), rcond=None)[0]
        update = np.eye(4)
        update[:3, :3] = cv2.Rodrigues(step[:3])[0]
        pose = update @ pose
        pose[:3, 3] += step[3:]
        if np.linalg.norm(step) < 1e-10:
            break
    return pose


def refine_translation_near(pose_cur_prev: Array, points_prev_m: Array, pixels_cur: Array, camera_matrix: Array,
                            inliers: NDArray[np.intp], disparities_px: Array | None, config: PnpConfig) -> Array:
    """The translation estimated again from the inliers nearer than ``translation_min_disparity_px`` (far points'
    stereo depths are biased long), where there are ``translation_min_points`` of them; else the pose as it is."""
    if disparities_px is None or config.translation_min_disparity_px <= 0:
        return pose_cur_prev
    near = inliers[np.asarray(disparities_px)[inliers] >= config.translation_min_disparity_px]
    if len(near) < config.translation_min_points:
        return pose_cur_prev
    return refine_translation(pose_cur_prev, points_prev_m[near], pixels_cur[near], camera_matrix)


def _failure(reason: str) -> MotionEstimate:
    return MotionEstimate(np.eye(4), np.zeros(0, np.intp), float("nan"), False, reason)


def reprojection_errors(pose_cur_prev: Array, points_prev_m: Array, pixels_cur: Array, camera_matrix: Array) -> Array:
    """Per-point reprojection error (px); points behind the camera get ``inf``."""
    points = points_prev_m @ pose_cur_prev[:3, :3].T + pose_cur_prev[:3, 3]
    projected = points @ camera_matrix.T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = projected[:, :2] / projected[:, 2:3]
    errors = np.linalg.norm(uv - pixels_cur, axis=1)
    return np.where(points[:, 2] > 1e-6, errors, np.inf)


def refine_translation(pose_cur_prev: Array, points_prev_m: Array, pixels_cur: Array, camera_matrix: Array,
                       iterations: int = 5) -> Array:
    """Gauss-Newton on the translation only, rotation held fixed, minimising reprojection error."""
    pose = pose_cur_prev.copy()
    fx, fy = camera_matrix[0, 0], camera_matrix[1, 1]
    rotated = points_prev_m @ pose[:3, :3].T
    for _ in range(iterations):
        points = rotated + pose[:3, 3]
        z = points[:, 2]
        if np.any(z <= 1e-6):
            return pose_cur_prev
        u = fx * points[:, 0] / z + camera_matrix[0, 2]
        v = fy * points[:, 1] / z + camera_matrix[1, 2]
        residual = np.concatenate([u - pixels_cur[:, 0], v - pixels_cur[:, 1]])
        jacobian = projection_jacobian(points, fx, fy).transpose(1, 0, 2).reshape(-1, 3)  # u rows, then v rows
        step = np.linalg.lstsq(jacobian, -residual, rcond=None)[0]
        pose[:3, 3] += step
        if np.linalg.norm(step) < 1e-9:
            break
    return pose


def estimate_motion_pnp(
    points_prev_m: Array, pixels_cur: Array, camera_matrix: Array, config: PnpConfig,
    disparities_px: Array | None = None,
    vet: Callable[[NDArray[np.intp]], NDArray[np.bool_]] | None = None,
) -> MotionEstimate:
    """Estimate ``pose_cur_prev`` from (N, 3) previous-frame points and their (N, 2) current pixels.

    ``disparities_px`` (N,), when given, enables the near-point translation step. ``vet``, when given,
    is asked once about RANSAC's inliers (their indices) and returns which to trust; the refinement then
    works on those alone. It is for checks too costly to run on every correspondence.
    """
    points = np.ascontiguousarray(points_prev_m, dtype=np.float64).reshape(-1, 3)
    pixels = np.ascontiguousarray(pixels_cur, dtype=np.float64).reshape(-1, 2)
    if len(points) < config.min_inliers:
        return _failure(f"only {len(points)} 2D-3D correspondences (need {config.min_inliers})")
    K = np.asarray(camera_matrix, dtype=np.float64)
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        points, pixels, K, None, iterationsCount=config.iterations,
        reprojectionError=config.reprojection_px, confidence=config.confidence, flags=cv2.SOLVEPNP_AP3P)
    if not found or inliers is None or len(inliers) < config.min_inliers:
        count = 0 if inliers is None else len(inliers)
        return _failure(f"RANSAC found {count} inliers (need {config.min_inliers})")
    inlier_index = inliers.ravel().astype(np.intp)
    usable = np.ones(len(points), dtype=bool)
    if vet is not None:  # the refinement may then only drop inliers: it cannot vet new ones
        inlier_index = inlier_index[np.asarray(vet(inlier_index), dtype=bool)]
        usable[:] = False
        usable[inlier_index] = True
        if len(inlier_index) < config.min_inliers:
            return _failure(f"{len(inlier_index)} of RANSAC's inliers passed the check (need {config.min_inliers})")
    return _refine(points, pixels, K, config, rvec, tvec, inlier_index, usable, disparities_px)


def estimate_motion_from_prior(
    points_prev_m: Array, pixels_cur: Array, camera_matrix: Array, config: PnpConfig, prior_cur_prev: Array,
    disparities_px: Array | None = None, gate_px: float = 4.0,
) -> MotionEstimate:
    """Estimate ``pose_cur_prev`` starting from a predicted motion instead of RANSAC.

    The correspondences that the prediction reprojects within ``gate_px`` start the same refinement as
    :func:`estimate_motion_pnp`. For the frames where RANSAC settles on a consensus the vehicle cannot
    have (a car ahead moving with the kart, a repeated structure), the prediction picks the scene's.
    """
    points = np.ascontiguousarray(points_prev_m, dtype=np.float64).reshape(-1, 3)
    pixels = np.ascontiguousarray(pixels_cur, dtype=np.float64).reshape(-1, 2)
    K = np.asarray(camera_matrix, dtype=np.float64)
    inlier_index = np.flatnonzero(reprojection_errors(prior_cur_prev, points, pixels, K) < gate_px)
    if len(inlier_index) < config.min_inliers:
        return _failure(f"{len(inlier_index)} correspondences agree with the predicted motion "
                        f"(need {config.min_inliers})")
    rvec = cv2.Rodrigues(np.ascontiguousarray(prior_cur_prev[:3, :3]))[0]
    tvec = np.ascontiguousarray(prior_cur_prev[:3, 3]).reshape(3, 1)
    return _refine(points, pixels, K, replace(config, refine_lm=True), rvec, tvec, inlier_index,
                   np.ones(len(points), dtype=bool), disparities_px)


def _refine(points: Array, pixels: Array, K: Array, config: PnpConfig, rvec: Array, tvec: Array,
            inlier_index: NDArray[np.intp], usable: NDArray[np.bool_], disparities_px: Array | None
            ) -> MotionEstimate:
    """Levenberg-Marquardt on the inliers, re-selecting them (among the usable) until they settle, then the
    near-point translation step."""
    if config.refine_lm:
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 1e-10)
        for _ in range(2):
            rvec, tvec = cv2.solvePnPRefineLM(points[inlier_index], pixels[inlier_index], K, None,
                                              rvec, tvec, criteria=criteria)
            pose = pose_from_rt(cv2.Rodrigues(rvec)[0], tvec)
            errors = reprojection_errors(pose, points, pixels, K)
            refined = np.flatnonzero((errors < config.reprojection_px) & usable)
            if len(refined) < config.min_inliers or np.array_equal(refined, inlier_index):
                break
            inlier_index = refined
    pose = refine_translation_near(pose_from_rt(cv2.Rodrigues(rvec)[0], tvec), points, pixels, K, inlier_index,
                                   disparities_px, config)
    errors = reprojection_errors(pose, points[inlier_index], pixels[inlier_index], K)
    rmse = float(np.sqrt(np.mean(errors**2)))
    return MotionEstimate(pose, inlier_index, rmse, True)

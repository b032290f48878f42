"""Joint refinement of the frame-to-frame pose and each point's inverse depth.

PnP treats triangulated depth as exact. It is not: stereo noise lives in the
disparity, and depth ``Z = f b / d`` is a convex function of it, so low-disparity
points are biased long and tilt the estimated rotation, which on road scenes
trades against forward translation (a scale error). Here each point keeps its
previous-frame bearing but its inverse depth ``rho`` becomes a variable, observed
through the previous disparity ``d = f b rho``; the current left pixel observes
the moved point. This is a two-view bundle adjustment restricted to depth along
the ray, solved by Gauss-Newton with the Schur complement on the per-point
scalars (Triggs et al., "Bundle adjustment: a modern synthesis", 2000) and
Huber weights.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kartpilot.core.geometry import Array, cross_matrix, projection_jacobian

__all__ = ["refine_pose_and_depths"]


def _huber_weights(residual_norm: Array, threshold: float) -> Array:
    return np.where(residual_norm <= threshold, 1.0, threshold / np.maximum(residual_norm, 1e-12))


def refine_pose_and_depths(
    pose_cur_prev: Array, pixels_prev: Array, disparities_px: Array, pixels_cur: Array,
    camera_matrix: Array, baseline_m: float, iterations: int = 6, huber_px: float = 1.0,
) -> Array:
    """Refine ``pose_cur_prev`` with per-point inverse depths as free variables.

    Args:
        pose_cur_prev: initial 4x4 transform from previous to current camera.
        pixels_prev: (N, 2) points in the previous left image (their bearings).
        disparities_px: (N,) their measured disparities in the previous pair.
        pixels_cur: (N, 2) the same points in the current left image.

    Returns:
        The refined 4x4 pose (the input pose when the problem is degenerate).
    """
    fx, fy, cx, cy = camera_matrix[0, 0], camera_matrix[1, 1], camera_matrix[0, 2], camera_matrix[1, 2]
    focal_baseline = fx * baseline_m
    rays = np.stack([(pixels_prev[:, 0] - cx) / fx, (pixels_prev[:, 1] - cy) / fy,
                     np.ones(len(pixels_prev))], axis=1)
    rho = np.asarray(disparities_px, dtype=np.float64) / focal_baseline
    rotation = pose_cur_prev[:3, :3].copy()
    translation = pose_cur_prev[:3, 3].copy()
    if len(rho) < 6:
        return pose_cur_prev
    for _ in range(iterations):
        points_prev = rays / rho[:, None]
        rotated = points_prev @ rotation.T
        points = rotated + translation
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        if np.any(z <= 1e-6) or np.any(rho <= 0):
            return pose_cur_prev
        residual_uv = np.stack([fx * x / z + cx - pixels_cur[:, 0], fy * y / z + cy - pixels_cur[:, 1]], axis=1)
        residual_d = focal_baseline * rho - disparities_px
        w_uv = _huber_weights(np.linalg.norm(residual_uv, axis=1), huber_px)
        w_d = _huber_weights(np.abs(residual_d), huber_px)
        d_uv_d_point = projection_jacobian(points, fx, fy)  # d(u, v)/dP, (N, 2, 3)
        # dP/d(omega, t) with R <- exp(omega) R: dP/domega = -[R X]_x, dP/dt = I
        skew = -cross_matrix(rotated)
        d_point_d_pose = np.concatenate([skew, np.broadcast_to(np.eye(3), skew.shape)], axis=2)
        J_pose = d_uv_d_point @ d_point_d_pose  # (N, 2, 6)
        d_point_d_rho = -rotated / rho[:, None]  # (N, 3)
        J_rho_uv = np.einsum("nij,nj->ni", d_uv_d_point, d_point_d_rho)  # (N, 2)
        J_rho_d = focal_baseline
        # normal equations with the per-point scalar eliminated (Schur complement)
        H_pp = np.einsum("n,nij,nik->jk", w_uv, J_pose, J_pose)
        g_p = np.einsum("n,nij,ni->j", w_uv, J_pose, residual_uv)
        h_p_rho = np.einsum("n,nij,ni->nj", w_uv, J_pose, J_rho_uv)  # (N, 6)
        h_rho = w_uv * np.einsum("ni,ni->n", J_rho_uv, J_rho_uv) + w_d * J_rho_d**2
        g_rho = w_uv * np.einsum("ni,ni->n", J_rho_uv, residual_uv) + w_d * J_rho_d * residual_d
        reduced = H_pp - np.einsum("ni,nj,n->ij", h_p_rho, h_p_rho, 1.0 / h_rho)
        rhs = g_p - np.einsum("ni,n->i", h_p_rho, g_rho / h_rho)
        try:
            step = -np.linalg.solve(reduced + 1e-9 * np.eye(6), rhs)
        except np.linalg.LinAlgError:
            return pose_cur_prev
        step_rho = -(g_rho + h_p_rho @ step) / h_rho
        rotation = Rotation.from_rotvec(step[:3]).as_matrix() @ rotation
        translation = translation + step[3:]
        rho = np.maximum(rho + step_rho, 1e-6)
        if np.linalg.norm(step) < 1e-10:
            break
    refined = np.eye(4)
    refined[:3, :3], refined[:3, 3] = rotation, translation
    return refined

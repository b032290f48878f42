"""Windowed bundle adjustment for stereo VO: the last few frames' poses and the points tracked through them,
refined together.

Frame-to-frame VO (PnP on the previous frame's triangulated points) treats each point's depth as exact and
forgets it after one step, so the noise of every step adds up. Keeping the points tracked over the last
``frames`` frames and refining the poses and points together, against every observation (the left pixel,
and where the frame's stereo match saw the point, its disparity), is what separates the odometry of
ORB-SLAM2 (about 1.15 % on KITTI) from frame-to-frame methods (VISO2-S about 2.4 %). See Triggs et al.,
"Bundle adjustment: a modern synthesis" (2000).

The problem is solved with SciPy's ``least_squares`` (trust region reflective) with the robust ``soft_l1``
loss on pixels (SciPy's ``huber`` stalled on a step-length error of a few per cent: its curvature is zero
beyond the scale) and the Jacobian in closed form, as a sparse matrix (:func:`window_jacobian`: each observation
depends on its frame's six pose parameters and its point's three; finite differences over the sparsity pattern
took half the solver's time). The oldest frame of the window is held fixed (the gauge); the scale is the stereo
baseline's, through the disparities.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array, invert_pose

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

__all__ = ["WindowBAConfig", "WindowObservations", "bundle_adjust_window", "window_jacobian", "window_residuals"]


@dataclass(frozen=True)
class WindowBAConfig:
    """Attributes:
        enabled: refine each frame's pose in a window with the frames before it (off: frame to frame only).
        frames: the window's length, in frames (the oldest is held fixed).
        loss_scale_px: the robust loss's scale, in pixels (residuals well beyond it count as outliers).
        max_evaluations: the solver's budget of residual evaluations per frame.
        min_observations: a point must be seen in at least this many of the window's frames.
    """

    enabled: bool = False
    frames: int = 5
    loss_scale_px: float = 1.0
    max_evaluations: int = 60
    min_observations: int = 2

    def __post_init__(self) -> None:
        if self.frames < 2 or self.min_observations < 2 or self.max_evaluations < 1:
            raise ConfigError("stereo_vo.window_ba.frames and min_observations must be at least 2, and "
                              "max_evaluations at least 1")
        if not self.loss_scale_px > 0:
            raise ConfigError("stereo_vo.window_ba.loss_scale_px must be positive")


@dataclass(frozen=True)
class WindowObservations:
    """Every observation in the window: observation ``m`` saw point ``point[m]`` in frame ``frame[m]`` at the
    left pixel ``pixels_px[m]``, with disparity ``disparities_px[m]`` (NaN where the frame's stereo match did
    not see it)."""

    frame: NDArray[np.intp]
    point: NDArray[np.intp]
    pixels_px: Array
    disparities_px: Array


def _unpack(params: Array, fixed_cam_world: Array, frames: int, points: int) -> tuple[Array, Array, Array, Array]:
    """The window's rotations ``(F, 3, 3)``, translations ``(F, 3)`` (camera from world; the first the fixed one's),
    the free frames' rotation vectors ``(F - 1, 3)`` and the points ``(P, 3)``."""
    free = frames - 1
    poses = params[:free * 6].reshape(free, 6)
    rotation = np.concatenate([fixed_cam_world[None, :3, :3], Rotation.from_rotvec(poses[:, :3]).as_matrix()])
    translation = np.concatenate([fixed_cam_world[None, :3, 3], poses[:, 3:]])
    return rotation, translation, poses[:, :3], params[free * 6:].reshape(points, 3)


def window_residuals(params: Array, fixed_cam_world: Array, frames: int, points: int, obs: WindowObservations,
                     k: Array, baseline_m: float) -> Array:
    """Each observation's (u, v, disparity) residual in pixels (the disparity's 0 where the frame's stereo match
    did not see the point), for ``params``: the free frames' (rotation vector, translation) of the camera from
    the world, then the points."""
    rotation, translation, _, world = _unpack(params, fixed_cam_world, frames, points)
    cam = np.einsum("mij,mj->mi", rotation[obs.frame], world[obs.point]) + translation[obs.frame]
    z = np.maximum(cam[:, 2], 1e-3)
    u = k[0, 0] * cam[:, 0] / z + k[0, 2]
    v = k[1, 1] * cam[:, 1] / z + k[1, 2]
    seen = np.isfinite(obs.disparities_px)
    disparity = np.where(seen, k[0, 0] * baseline_m / z - np.nan_to_num(obs.disparities_px), 0.0)
    return np.column_stack([u - obs.pixels_px[:, 0], v - obs.pixels_px[:, 1], disparity]).ravel()


def _skew(vectors: Array) -> Array:
    """The cross-product matrices ``[v]x`` of ``(N, 3)`` vectors, ``(N, 3, 3)``."""
    out = np.zeros((len(vectors), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -vectors[:, 2], vectors[:, 1], -vectors[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = vectors[:, 2], -vectors[:, 1], vectors[:, 0]
    return out


def _right_jacobian(rotvecs: Array) -> Array:
    """SO(3)'s right Jacobian at each rotation vector: ``d exp(w) = exp(w) [J_r(w) dw]x`` (Chirikjian; Barfoot,
    "State estimation for robotics", 7.1.5), ``(N, 3, 3)``; its Taylor series near zero."""
    theta = np.linalg.norm(rotvecs, axis=1)
    small = theta < 1e-5
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta ** 2 / 24.0, (1.0 - np.cos(t)) / t ** 2)
    b = np.where(small, 1.0 / 6.0 - theta ** 2 / 120.0, (t - np.sin(t)) / t ** 3)
    w = _skew(rotvecs)
    return np.eye(3) - a[:, None, None] * w + b[:, None, None] * (w @ w)


def window_jacobian(params: Array, fixed_cam_world: Array, frames: int, points: int, obs: WindowObservations,
                    k: Array, baseline_m: float) -> csr_matrix:
    """The Jacobian of :func:`window_residuals` in closed form, sparse: each observation's three rows depend on its
    point's three parameters and, unless its frame is the fixed one, its frame's six. A camera point
    ``c = R(w) X + t``: ``dc/dX = R``, ``dc/dt = I``, ``dc/dw = -R [X]x J_r(w)``; the pinhole's and the
    disparity's derivatives in ``c`` follow (nothing where the depth is cut at 1 mm, as the residual is)."""
    from scipy.sparse import coo_matrix

    rotation, translation, rotvecs, world = _unpack(params, fixed_cam_world, frames, points)
    r, x = rotation[obs.frame], world[obs.point]
    cam = np.einsum("mij,mj->mi", r, x) + translation[obs.frame]
    z = cam[:, 2]
    live = z > 1e-3
    zs = np.where(live, z, 1.0)
    fx, fy = k[0, 0], k[1, 1]
    seen = np.isfinite(obs.disparities_px)
    d_cam = np.zeros((len(z), 3, 3))  # d(u, v, disparity) / d(camera point)
    d_cam[:, 0, 0] = fx / zs
    d_cam[:, 0, 2] = -fx * cam[:, 0] / zs ** 2
    d_cam[:, 1, 1] = fy / zs
    d_cam[:, 1, 2] = -fy * cam[:, 1] / zs ** 2
    d_cam[:, 2, 2] = np.where(seen, -fx * baseline_m / zs ** 2, 0.0)
    d_cam[~live, :, 2] = 0.0
    d_point = d_cam @ r  # (M, 3, 3)
    free = frames - 1
    m = len(z)
    rows = 3 * np.arange(m)[:, None] + np.arange(3)[None, :]  # (M, 3)
    point_cols = free * 6 + 3 * obs.point[:, None] + np.arange(3)[None, :]  # (M, 3)
    values = [d_point.ravel()]
    row_index = [np.repeat(rows, 3, axis=1).ravel()]
    col_index = [np.tile(point_cols, (1, 3)).ravel()]
    moving = obs.frame > 0
    if free and moving.any():
        jr = _right_jacobian(rotvecs)[obs.frame[moving] - 1]
        d_rot = -(d_point[moving] @ _skew(x[moving])) @ jr  # d residual / d rotation vector
        d_pose = np.concatenate([d_rot, d_cam[moving]], axis=2)  # (moving, 3, 6)
        pose_cols = 6 * (obs.frame[moving] - 1)[:, None] + np.arange(6)[None, :]
        values.append(d_pose.ravel())
        row_index.append(np.repeat(rows[moving], 6, axis=1).ravel())
        col_index.append(np.tile(pose_cols, (1, 3)).ravel())
    return coo_matrix((np.concatenate(values), (np.concatenate(row_index), np.concatenate(col_index))),
                      shape=(3 * m, free * 6 + points * 3)).tocsr()


def bundle_adjust_window(poses_world_cam: Array, points_world_m: Array, obs: WindowObservations,
                         camera_matrix: Array, baseline_m: float, config: WindowBAConfig) -> tuple[Array, Array]:
    """Refine the window's left-camera poses ``(F, 4, 4)`` (the first held fixed) and its points ``(P, 3)``
    against ``obs``; returns both, refined. The inputs are the starting point (VO's poses, the points
    triangulated where first seen)."""
    frames, points = len(poses_world_cam), len(points_world_m)
    cam_world = np.array([invert_pose(p) for p in poses_world_cam])
    start = np.concatenate([
        np.column_stack([Rotation.from_matrix(cam_world[1:, :3, :3]).as_rotvec(), cam_world[1:, :3, 3]]).ravel(),
        np.asarray(points_world_m, float).ravel()])
    k = np.asarray(camera_matrix, float)
    from scipy.optimize import least_squares  # here: scipy.optimize costs every command a tenth of a second

    solution = least_squares(window_residuals, start, jac=window_jacobian, method="trf", tr_solver="lsmr",
                             loss="soft_l1", f_scale=config.loss_scale_px, x_scale="jac",
                             max_nfev=config.max_evaluations, args=(cam_world[0], frames, points, obs, k, baseline_m))
    free = solution.x[:(frames - 1) * 6].reshape(frames - 1, 6)
    refined = poses_world_cam.copy()
    for f in range(1, frames):
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_rotvec(free[f - 1, :3]).as_matrix()
        pose[:3, 3] = free[f - 1, 3:]
        refined[f] = invert_pose(pose)
    return refined, solution.x[(frames - 1) * 6:].reshape(points, 3)

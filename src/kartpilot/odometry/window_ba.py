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
beyond the scale) and the Jacobian's sparsity pattern given, so its finite differences cost a few dozen evaluations
regardless of the number of points. The oldest frame of the window is held fixed (the gauge); the scale is
the stereo baseline's, through the disparities.
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
    from scipy.sparse import lil_matrix

__all__ = ["WindowBAConfig", "WindowObservations", "bundle_adjust_window"]


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


def _residuals(params: Array, fixed_cam_world: Array, frames: int, points: int, obs: WindowObservations,
               k: Array, baseline_m: float) -> Array:
    free = frames - 1
    rotvecs = params[:free * 6].reshape(free, 6)
    rotation = np.concatenate([fixed_cam_world[None, :3, :3], Rotation.from_rotvec(rotvecs[:, :3]).as_matrix()])
    translation = np.concatenate([fixed_cam_world[None, :3, 3], rotvecs[:, 3:]])
    world = params[free * 6:].reshape(points, 3)
    cam = np.einsum("mij,mj->mi", rotation[obs.frame], world[obs.point]) + translation[obs.frame]
    z = np.maximum(cam[:, 2], 1e-3)
    u = k[0, 0] * cam[:, 0] / z + k[0, 2]
    v = k[1, 1] * cam[:, 1] / z + k[1, 2]
    seen = np.isfinite(obs.disparities_px)
    disparity = np.where(seen, k[0, 0] * baseline_m / z - np.nan_to_num(obs.disparities_px), 0.0)
    return np.column_stack([u - obs.pixels_px[:, 0], v - obs.pixels_px[:, 1], disparity]).ravel()


def _sparsity(frames: int, points: int, obs: WindowObservations) -> lil_matrix:
    from scipy.sparse import lil_matrix

    free = frames - 1
    pattern = lil_matrix((3 * len(obs.frame), free * 6 + points * 3), dtype=np.int8)
    rows = np.arange(len(obs.frame))
    for r in range(3):
        for c in range(3):
            pattern[3 * rows + r, free * 6 + 3 * obs.point + c] = 1
        moving = obs.frame > 0
        for c in range(6):
            pattern[3 * rows[moving] + r, 6 * (obs.frame[moving] - 1) + c] = 1
    return pattern


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

    solution = least_squares(_residuals, start, jac_sparsity=_sparsity(frames, points, obs), method="trf",
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

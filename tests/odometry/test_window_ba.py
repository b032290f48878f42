"""Windowed bundle adjustment: noisy poses and points, refined against stereo observations."""

import numpy as np
import pytest

from kartpilot.core.camera import PinholeCamera, StereoRig
from kartpilot.core.geometry import invert_pose, pose_from_rotvec
from kartpilot.odometry.window_ba import WindowBAConfig, WindowObservations, bundle_adjust_window

RIG = StereoRig(PinholeCamera(fx_px=700.0, fy_px=700.0, cx_px=640.0, cy_px=360.0, width_px=1280, height_px=720),
                0.5)


def _observe(poses: np.ndarray, points: np.ndarray, rng: np.random.Generator, noise_px: float
             ) -> WindowObservations:
    k = RIG.camera.matrix
    frames, ids, pixels, disparities = [], [], [], []
    for f, pose in enumerate(poses):
        cam = (invert_pose(pose) @ np.c_[points, np.ones(len(points))].T).T[:, :3]
        seen = np.flatnonzero(cam[:, 2] > 1.0)
        uv = (k @ (cam[seen] / cam[seen, 2:3]).T).T[:, :2] + rng.normal(0, noise_px, (len(seen), 2))
        d = k[0, 0] * RIG.baseline_m / cam[seen, 2] + rng.normal(0, noise_px, len(seen))
        frames.append(np.full(len(seen), f))
        ids.append(seen)
        pixels.append(uv)
        disparities.append(d)
    return WindowObservations(np.concatenate(frames), np.concatenate(ids), np.concatenate(pixels),
                              np.concatenate(disparities))


def test_the_window_pulls_perturbed_poses_back_to_the_truth():
    rng = np.random.default_rng(3)
    truth = np.array([pose_from_rotvec(np.array([0.0, 0.02 * f, 0.0]), np.array([0.0, 0.0, 1.0 * f]))
                      for f in range(5)])
    points = np.column_stack([rng.uniform(-10, 10, 300), rng.uniform(-3, 1.5, 300), rng.uniform(6, 40, 300)])
    obs = _observe(truth, points, rng, 0.3)
    # VO's estimate: every step 4 % too long and slightly turned; points 5 % too far
    start = truth.copy()
    for f in range(1, 5):
        start[f] = start[f - 1] @ pose_from_rotvec(np.array([0.0, 0.004, 0.0]),
                                                   1.04 * (invert_pose(truth[f - 1]) @ truth[f])[:3, 3])
    refined, refined_points = bundle_adjust_window(start, points * 1.05, obs, RIG.camera.matrix, RIG.baseline_m,
                                                   WindowBAConfig(enabled=True, max_evaluations=100))
    before = np.linalg.norm(start[1:, :3, 3] - truth[1:, :3, 3], axis=1)
    after = np.linalg.norm(refined[1:, :3, 3] - truth[1:, :3, 3], axis=1)
    print(f"position error per frame before {np.round(before, 3)} m, after {np.round(after, 3)} m")
    np.testing.assert_allclose(refined[0], start[0])  # the gauge stays put
    assert after.max() < 0.1 * before.max()
    assert np.median(np.linalg.norm(refined_points - points, axis=1)) < 0.2


def test_the_window_settings_are_checked():
    with pytest.raises(Exception, match="window_ba"):
        WindowBAConfig(frames=1)
    with pytest.raises(Exception, match="loss_scale_px"):
        WindowBAConfig(loss_scale_px=float("nan"))


def test_the_closed_form_jacobian_is_the_residuals_derivative():
    """:func:`window_jacobian` against central differences of :func:`window_residuals`, on a window with turned
    frames (a rotation vector near zero, one of 0.3 rad), points the stereo match did not see (no disparity row) and
    observations in the fixed frame (no pose columns)."""
    from kartpilot.odometry.window_ba import window_jacobian, window_residuals

    rng = np.random.default_rng(5)
    truth = np.array([pose_from_rotvec(np.array([0.0, w, 0.01 * f]), np.array([0.1 * f, 0.0, 1.0 * f]))
                      for f, w in enumerate([0.0, 1e-7, 0.02, 0.3])])
    points = np.column_stack([rng.uniform(-10, 10, 40), rng.uniform(-3, 1.5, 40), rng.uniform(6, 40, 40)])
    obs = _observe(truth, points, rng, 0.3)
    obs.disparities_px[::3] = np.nan
    cam_world = np.array([invert_pose(p) for p in truth])
    from scipy.spatial.transform import Rotation

    params = np.concatenate([np.column_stack([Rotation.from_matrix(cam_world[1:, :3, :3]).as_rotvec(),
                                              cam_world[1:, :3, 3]]).ravel(), points.ravel()])
    args = (cam_world[0], len(truth), len(points), obs, RIG.camera.matrix, RIG.baseline_m)
    closed = window_jacobian(params, *args).toarray()
    step = 1e-6 * np.maximum(1.0, np.abs(params))
    numeric = np.column_stack([(window_residuals(params + h, *args) - window_residuals(params - h, *args)) / (2 * h[j])
                               for j, h in enumerate(np.diag(step))])
    print(f"largest difference {np.abs(closed - numeric).max():.2e} of entries up to {np.abs(numeric).max():.1f}")
    np.testing.assert_allclose(closed, numeric, rtol=1e-5, atol=1e-3)
    assert np.count_nonzero(closed) <= 27 * len(obs.frame)

import numpy as np
import pytest

from kartpilot.core.camera import StereoRig
from kartpilot.core.geometry import invert_pose, pose_from_rotvec, relative_pose, rotation_angle_rad
from kartpilot.odometry.pnp import PnpConfig, check_motion, estimate_motion_pnp
from kartpilot.odometry.stereo_refine import refine_pose_and_depths


def _true_motion() -> np.ndarray:
    # the kart moves 0.5 m forward, slightly left, turning 2 degrees: points move the other way
    return invert_pose(pose_from_rotvec(np.radians([0.3, 2.0, -0.2]), np.array([0.05, -0.01, 0.5])))


def _observe(rig: StereoRig, points: np.ndarray, pose_cur_prev: np.ndarray, noise_px: float, seed: int) -> np.ndarray:
    moved = points @ pose_cur_prev[:3, :3].T + pose_cur_prev[:3, 3]
    rng = np.random.default_rng(seed)
    return rig.camera.project(moved) + rng.normal(0.0, noise_px, (len(points), 2))


def _errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    error = relative_pose(truth, estimate)
    return float(np.linalg.norm(error[:3, 3])), float(np.degrees(rotation_angle_rad(error)))


def test_motion_recovered_within_1mm_and_0_01_degrees(rig: StereoRig, scene_points: np.ndarray) -> None:
    truth = _true_motion()
    pixels = _observe(rig, scene_points, truth, noise_px=0.05, seed=1)
    motion = estimate_motion_pnp(scene_points, pixels, rig.camera.matrix, PnpConfig())
    assert motion.ok
    translation_m, rotation_deg = _errors(motion.pose_cur_prev, truth)
    print(f"synthetic PnP: translation error {translation_m * 1e3:.3f} mm, rotation error {rotation_deg:.5f} deg")
    assert translation_m < 1e-3
    assert rotation_deg < 0.01


def test_planted_outliers_are_rejected(rig: StereoRig, scene_points: np.ndarray) -> None:
    truth = _true_motion()
    pixels = _observe(rig, scene_points, truth, noise_px=0.05, seed=2)
    rng = np.random.default_rng(3)
    outliers = rng.choice(len(pixels), 90, replace=False)  # 30 % wrong matches
    pixels[outliers] += rng.uniform(-60, 60, (90, 2)) + 5.0
    motion = estimate_motion_pnp(scene_points, pixels, rig.camera.matrix, PnpConfig())
    assert motion.ok
    assert not set(outliers.tolist()) & set(motion.inliers.tolist())
    translation_m, rotation_deg = _errors(motion.pose_cur_prev, truth)
    assert translation_m < 1e-3 and rotation_deg < 0.01


def test_too_few_points_fail_with_a_reason(rig: StereoRig, scene_points: np.ndarray) -> None:
    pixels = _observe(rig, scene_points[:5], _true_motion(), 0.0, 0)
    motion = estimate_motion_pnp(scene_points[:5], pixels, rig.camera.matrix, PnpConfig(min_inliers=8))
    assert not motion.ok
    assert "need 8" in motion.reason


def test_joint_depth_refinement_removes_disparity_noise_bias(rig: StereoRig, scene_points: np.ndarray) -> None:
    truth = _true_motion()
    pixels_prev = rig.camera.project(scene_points)
    disparity = rig.camera.fx_px * rig.baseline_m / scene_points[:, 2]
    noisy = disparity + np.random.default_rng(4).normal(0, 0.3, len(disparity))
    pixels_cur = _observe(rig, scene_points, truth, 0.05, 5)
    refined = refine_pose_and_depths(np.eye(4), pixels_prev, noisy, pixels_cur, rig.camera.matrix, rig.baseline_m,
                                     iterations=15)
    translation_m, rotation_deg = _errors(refined, truth)
    assert translation_m < 0.02
    assert rotation_deg < 0.05


@pytest.mark.parametrize(
    ("motion", "reason"),
    [
        (pose_from_rotvec(np.zeros(3), np.array([0.0, 0.0, 5.0])), "speed"),
        (pose_from_rotvec(np.radians([0.0, 30.0, 0.0]), np.zeros(3)), "rotation"),
    ],
)
def test_motion_sanity_check(motion: np.ndarray, reason: str) -> None:
    assert reason in check_motion(invert_pose(motion), 0.1, max_speed_mps=20.0, max_yaw_rate_dps=180.0)
    assert check_motion(invert_pose(motion), 10.0, max_speed_mps=20.0, max_yaw_rate_dps=180.0) == ""

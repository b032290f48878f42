import numpy as np
import pytest

from kartpilot.core.camera import StereoRig
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import invert_pose, pose_from_rotvec, relative_pose, rotation_angle_rad
from kartpilot.odometry.motion_check import MotionLimits, StepVelocity, check_motion
from kartpilot.odometry.pnp import PnpConfig, estimate_motion_from_prior, estimate_motion_pnp
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


def test_the_prediction_finds_the_scene_where_ransac_takes_a_moving_majority(rig: StereoRig,
                                                                          scene_points: np.ndarray) -> None:
    """Two thirds of the points ride on a car ahead that moves with the kart: RANSAC's largest consensus
    is the car's (no motion). Started from the kart's predicted motion, the estimate keeps the scene's."""
    truth = _true_motion()
    count = len(scene_points)
    riding = np.arange(count) < 2 * count // 3
    pixels = _observe(rig, scene_points, truth, noise_px=0.05, seed=7)
    pixels[riding] = _observe(rig, scene_points[riding], np.eye(4), noise_px=0.05, seed=8)
    ransac = estimate_motion_pnp(scene_points, pixels, rig.camera.matrix, PnpConfig())
    assert ransac.ok and _errors(ransac.pose_cur_prev, truth)[0] > 0.3  # the car's consensus
    # a prediction 3 cm and 0.2 degrees off the truth, as constant velocity gives
    predicted = pose_from_rotvec(np.radians([0.0, 0.2, 0.0]), np.array([0.0, 0.0, 0.03])) @ truth
    motion = estimate_motion_from_prior(scene_points, pixels, rig.camera.matrix, PnpConfig(), predicted)
    translation_m, rotation_deg = _errors(motion.pose_cur_prev, truth)
    assert motion.ok and translation_m < 2e-3 and rotation_deg < 0.02
    assert not riding[motion.inliers].any()


def test_vetted_inliers_leave_the_refinement(rig: StereoRig, scene_points: np.ndarray) -> None:
    """Points a costly check distrusts (here: a third whose depth is 30 % long, which RANSAC's 1.5 px still
    accepts) are neither refined on nor reported as inliers."""
    truth = _true_motion()
    pixels = _observe(rig, scene_points, truth, noise_px=0.05, seed=9)
    wrong = np.arange(len(scene_points)) % 3 == 0
    stretched = scene_points.copy()
    stretched[wrong] *= 1.3
    plain = estimate_motion_pnp(stretched, pixels, rig.camera.matrix, PnpConfig())
    vetted = estimate_motion_pnp(stretched, pixels, rig.camera.matrix, PnpConfig(), vet=lambda index: ~wrong[index])
    assert vetted.ok and not wrong[vetted.inliers].any()
    assert _errors(vetted.pose_cur_prev, truth)[0] < 1e-3 < _errors(plain.pose_cur_prev, truth)[0]


def _step(motion: np.ndarray, dt_s: float, start_s: float = 0.0) -> StepVelocity:
    start_ns = int(start_s * 1e9)
    return StepVelocity.of_step(invert_pose(motion), start_ns, start_ns + int(dt_s * 1e9))


@pytest.mark.parametrize(
    ("motion", "reason"),
    [
        (pose_from_rotvec(np.zeros(3), np.array([0.0, 0.0, 5.0])), "speed"),
        (pose_from_rotvec(np.radians([0.0, 30.0, 0.0]), np.zeros(3)), "rotation"),
    ],
)
def test_motion_check_bounds_speed_and_rotation_rate(motion: np.ndarray, reason: str) -> None:
    limits = MotionLimits(max_speed_mps=20.0, max_yaw_rate_dps=180.0)
    assert reason in check_motion(_step(motion, 0.1), limits)
    assert check_motion(_step(motion, 10.0), limits) == ""


def test_motion_check_rejects_a_step_inconsistent_with_the_recent_motion() -> None:
    """At 10 m/s and 10 Hz, a step 0.66 or 1.5 times too long, or one that turns 3 degrees more than the
    last, cannot be: the kart brakes or corners at 1 g at most. After bridged frames, more change is allowed."""
    limits = MotionLimits(max_accel_mps2=10.0, max_angular_accel_dps2=200.0)
    forward = pose_from_rotvec(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    recent = _step(forward, 0.1)
    assert check_motion(_step(forward, 0.1, 0.1), limits, recent) == ""
    slightly = pose_from_rotvec(np.radians([0.0, 0.5, 0.0]), np.array([0.0, 0.0, 1.05]))
    assert check_motion(_step(slightly, 0.1, 0.1), limits, recent) == ""
    for factor in (0.66, 1.5):
        wrong = pose_from_rotvec(np.zeros(3), np.array([0.0, 0.0, factor]))
        assert "velocity changed" in check_motion(_step(wrong, 0.1, 0.1), limits, recent)
    turned = pose_from_rotvec(np.radians([0.0, 3.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    assert "rotation rate changed" in check_motion(_step(turned, 0.1, 0.1), limits, recent)
    # the same slower step half a second after the last accepted one is possible
    slower = pose_from_rotvec(np.zeros(3), np.array([0.0, 0.0, 0.66]))
    assert check_motion(_step(slower, 0.1, 0.5), limits, recent) == ""


def test_motion_limits_refuse_non_positive_values() -> None:
    with pytest.raises(ConfigError, match="max_accel_mps2"):
        MotionLimits(max_accel_mps2=0.0)
    with pytest.raises(ConfigError, match="speed_tolerance_mps"):
        MotionLimits(speed_tolerance_mps=float("nan"))

"""Stereo VO as a ground vehicle's (issue 37): the roll and pitch prior, keyframe selection, and the motion
model's prediction."""

import itertools

import cv2
import numpy as np
import pytest

from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import pose_from_rt
from kartpilot.odometry.pnp import AttitudePrior, refine_with_attitude_prior
from kartpilot.odometry.stereo_vo import StereoVO, StereoVOConfig
from kartpilot.odometry.window_ba import WindowBAConfig
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
UP = np.array([0.0, -1.0, 0.0])  # a level camera's up: its -y


def _project(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    moved = points @ pose[:3, :3].T + pose[:3, 3]
    return moved[:, :2] / moved[:, 2:3] * 500.0 + [320.0, 240.0]


def _roll_deg(pose: np.ndarray) -> float:
    return float(np.degrees(cv2.Rodrigues(pose[:3, :3])[0][2, 0]))


def _yaw_deg(pose: np.ndarray) -> float:
    return float(np.degrees(cv2.Rodrigues(pose[:3, :3])[0][1, 0]))


def test_the_attitude_prior_keeps_a_biased_roll_out_and_leaves_yaw_and_translation() -> None:
    """A few far points tracked with a small rotational bias about the image centre (what a tracker's
    sub-pixel bias on a bend's far side does): alone, the step rolls; with the prior it does not, and the
    yaw and the step's length stay right."""
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(-6, 6, 14), rng.uniform(-2.5, 0.4, 14), rng.uniform(6, 30, 14)])
    truth = pose_from_rt(cv2.Rodrigues(np.array([0.0, 0.03, 0.0]))[0], np.array([0.0, 0.0, -0.4]))
    pixels = _project(points, truth)
    bias = cv2.getRotationMatrix2D((320.0, 240.0), 0.4, 1.0)  # the image turned by 0.4 deg
    pixels = pixels @ bias[:, :2].T + bias[:, 2] + rng.normal(0, 0.2, pixels.shape)
    free = refine_with_attitude_prior(np.eye(4), points, pixels, K, AttitudePrior(UP, UP, np.radians(90.0)))
    held = refine_with_attitude_prior(np.eye(4), points, pixels, K, AttitudePrior(UP, UP, np.radians(0.05)))
    print(f"roll free {_roll_deg(free):.3f} deg, with the prior {_roll_deg(held):.3f} deg")
    assert abs(_roll_deg(free)) > 0.3
    assert abs(_roll_deg(held)) < 0.1
    assert _yaw_deg(held) == pytest.approx(np.degrees(0.03), abs=0.05)
    assert np.linalg.norm(held[:3, 3]) == pytest.approx(0.4, rel=0.05)


def test_the_attitude_prior_is_not_a_clamp_where_many_points_see_a_real_roll() -> None:
    rng = np.random.default_rng(4)
    points = np.column_stack([rng.uniform(-6, 6, 200), rng.uniform(-2.5, 0.4, 200), rng.uniform(3, 30, 200)])
    truth = pose_from_rt(cv2.Rodrigues(np.array([0.0, 0.0, np.radians(2.0)]))[0], np.array([0.0, 0.0, -0.4]))
    pixels = _project(points, truth) + rng.normal(0, 0.3, (200, 2))
    held = refine_with_attitude_prior(np.eye(4), points, pixels, K, AttitudePrior(UP, UP, np.radians(1.0)))
    assert _roll_deg(held) == pytest.approx(2.0, abs=0.1)
    # and the prior is on the attitude, not the step: where the estimate so far has the camera rolled by 2
    # degrees, a strong prior turns the step most of the way back to level, against the points
    rolled_up = cv2.Rodrigues(np.array([0.0, 0.0, np.radians(-2.0)]))[0] @ UP
    level = _project(points, np.eye(4)) + rng.normal(0, 0.3, (200, 2))
    back = refine_with_attitude_prior(np.eye(4), points, level, K, AttitudePrior(rolled_up, UP, np.radians(0.01)))
    assert 1.0 < _roll_deg(back) <= 2.05


@pytest.fixture(scope="module")
def source() -> SyntheticStereoSource:
    return SyntheticStereoSource(SyntheticStereoConfig(frames=30, speed_mps=2.0))


def _keyframes(source: SyntheticStereoSource, config: StereoVOConfig) -> tuple[list[int], list]:
    vo = StereoVO(source.rig, config)
    estimates = [vo.process(source.frame(i).as_frame_set()) for i in range(len(source))]
    vo.close()
    # stereo runs on keyframes only: they are the frames with left features
    return [e.index for e in estimates if e.diagnostics.left_features > 0], estimates


def test_a_new_keyframe_once_the_kart_is_far_enough_from_the_last(source: SyntheticStereoSource) -> None:
    keyframes, estimates = _keyframes(source, StereoVOConfig(keyframe_max_distance_m=1.0))
    assert keyframes[0] == 0 and all(e.status != "bridged" for e in estimates)
    truth = source.ground_truth().poses[:, :3, 3]
    gaps = [float(np.linalg.norm(truth[b] - truth[a])) for a, b in itertools.pairwise(keyframes)]
    print("keyframes", keyframes, "gaps", np.round(gaps, 2))
    # 0.2 m a frame: a keyframe on the first frame beyond 1 m, not on every frame
    assert all(0.95 <= g <= 1.25 for g in gaps)
    assert 5 <= len(keyframes) <= 7


def test_a_new_keyframe_when_its_points_are_lost(source: SyntheticStereoSource) -> None:
    """Asking for 95 % of the keyframe's points to stay inliers makes one far more often than distance does."""
    often, _ = _keyframes(source, StereoVOConfig(keyframe_max_distance_m=50.0, keyframe_min_share=0.95))
    rarely, _ = _keyframes(source, StereoVOConfig(keyframe_max_distance_m=50.0, keyframe_min_share=0.05,
                                                  keyframe_min_inliers=6))
    assert len(often) > 2 * len(rarely)


def test_the_motion_model_predicts_the_step_over_a_missed_frame(source: SyntheticStereoSource) -> None:
    """Constant velocity, scaled to the time since the last frame: with a frame missing, the prediction is
    twice the step, and VO tracks on from it without a bridged frame."""
    vo = StereoVO(source.rig)
    for i in range(6):
        vo.process(source.frame(i).as_frame_set())
    step = np.linalg.norm(vo._predicted(0.1)[:3, 3])
    assert np.linalg.norm(vo._predicted(0.2)[:3, 3]) == pytest.approx(2 * step, rel=1e-6)
    assert step == pytest.approx(0.2, rel=0.05)  # 2 m/s at 10 Hz
    after = vo.process(source.frame(7).as_frame_set())  # frame 6 missed
    vo.close()
    assert after.status == "ok"
    truth = source.ground_truth().poses[7]
    assert np.linalg.norm(after.pose_world_cam[:3, 3] - truth[:3, 3]) < 0.05


def test_keyframes_need_klt_and_frame_to_frame_refinements_need_no_keyframes() -> None:
    with pytest.raises(ConfigError, match="keyframes needs temporal_matching: klt"):
        StereoVOConfig(temporal_matching="descriptor")
    with pytest.raises(ConfigError, match="window_ba"):
        StereoVOConfig(window_ba=WindowBAConfig(enabled=True))
    with pytest.raises(ConfigError, match="attitude_prior_deg"):
        StereoVOConfig(attitude_prior_deg=-1.0)


def test_frame_to_frame_matches_descriptors_unless_told_and_keyframes_track_with_klt() -> None:
    """``auto``: KLT with keyframes, descriptors from frame to frame (KLT there drifted more on KITTI 06)."""
    assert StereoVOConfig().temporal == "klt"
    assert StereoVOConfig(keyframes=False).temporal == "descriptor"
    assert StereoVOConfig(keyframes=False, temporal_matching="klt").temporal == "klt"
    assert StereoVOConfig(keyframes=False, window_ba=WindowBAConfig(enabled=True)).window_ba.enabled


def test_the_attitude_prior_is_off_by_default_and_never_given_to_a_rig_without_a_mount(
        source: SyntheticStereoSource, caplog: pytest.LogCaptureFixture) -> None:
    """A dataset's rig (no mount: EuRoC's is carried by hand) does not get the ground vehicle's prior even when it
    is asked for, and the log says so; a rig on a vehicle gets it when asked for."""
    from dataclasses import replace

    from kartpilot.core.geometry import mount_pose

    asked = StereoVOConfig(attitude_prior_deg=1.0)
    mounted = replace(source.rig, camera=source.rig.camera.on_body(mount_pose(z_m=0.19)))
    with caplog.at_level("INFO", logger="kartpilot.odometry.stereo_vo"):
        vos = [StereoVO(source.rig), StereoVO(source.rig, asked), StereoVO(mounted, asked)]
    assert [vo.attitude_prior for vo in vos] == [False, False, True]
    assert caplog.text.count("without the attitude prior") == 1
    for vo in vos:
        vo.close()


def test_the_motion_model_moves_at_the_kart_s_measured_speed_while_it_is_fresh(source: SyntheticStereoSource) -> None:
    """The SDC kart reports its wheel speed (0x440): the prediction keeps the last motion's direction and takes
    the measured speed; a stale or NaN measurement leaves constant velocity."""
    vo = StereoVO(source.rig)
    for i in range(6):
        vo.process(source.frame(i).as_frame_set())
    stamp = source.frame(5).stamp_ns
    direction = vo._predicted(0.1)[:3, 3] / np.linalg.norm(vo._predicted(0.1)[:3, 3])
    vo.observe_speed(stamp, float("nan"))
    assert np.linalg.norm(vo._predicted(0.1)[:3, 3]) == pytest.approx(0.2, rel=0.05)
    vo.observe_speed(stamp, 1.0)  # braking: half the speed VO last measured
    predicted = vo._predicted(0.1)[:3, 3]
    assert np.linalg.norm(predicted) == pytest.approx(0.1, rel=1e-6)
    assert predicted / np.linalg.norm(predicted) == pytest.approx(direction)
    vo.observe_speed(stamp - 2_000_000_000, 1.0)  # two seconds old: not used
    assert np.linalg.norm(vo._predicted(0.1)[:3, 3]) == pytest.approx(0.2, rel=0.05)
    vo.close()

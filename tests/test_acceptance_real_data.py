"""Acceptance figures on real data (skipped with a reason when ../shared/data is absent)."""

import numpy as np

from kartpilot.eval.trajectory_metrics import evaluate_trajectory
from kartpilot.odometry.run import run_vo
from kartpilot.odometry.stereo_vo import StereoVO
from kartpilot.sensors.euroc import EurocSource
from kartpilot.sensors.kitti import KittiOdometrySource
from tests.conftest import data_path


def test_kitti_06_end_point_drift_at_most_1_percent() -> None:
    source = KittiOdometrySource(data_path("kitti-odometry"), "06")
    run = run_vo(source.frame_sets(), StereoVO(source.rig), source.name)
    truth = source.ground_truth()
    assert truth is not None
    metrics = evaluate_trajectory(truth, run.trajectory)
    print("\nKITTI 06 stereo VO (default configuration)\n" + metrics.table() + "\n" + run.summary())
    assert run.bridged_frames == 0
    assert metrics.end_drift_percent <= 1.0
    assert metrics.ate_rmse_m < 0.3


def test_euroc_static_platform_stays_within_5_cm() -> None:
    source = EurocSource(data_path("euroc-v101-static"))
    run = run_vo(source.frame_sets(), StereoVO(source.rig), source.name)
    excursion = float(np.linalg.norm(run.trajectory.positions, axis=1).max())
    print(f"\nEuRoC V1_01 static: largest distance from the start {excursion * 100:.2f} cm over {len(source)} frames")
    assert excursion < 0.05


def test_kitti_06_monocular_vo_with_ground_plane_scale_drifts_at_most_3_percent() -> None:
    from kartpilot.odometry.mono_vo import GroundConfig, MonoVO, MonoVOConfig

    source = KittiOdometrySource(data_path("kitti-odometry"), "06")
    vo = MonoVO(source.rig.camera, MonoVOConfig(ground=GroundConfig(camera_height_m=1.65)))
    run = run_vo(source.frame_sets(), vo, source.name)
    truth = source.ground_truth()
    assert truth is not None
    metrics = evaluate_trajectory(truth, run.trajectory)
    print("\nKITTI 06 monocular VO, scale from the ground plane (camera 1.65 m)\n" + metrics.table() + "\n"
          + run.summary())
    assert run.scale_source.startswith("ground plane")
    assert run.bridged_frames == 0
    assert metrics.end_drift_percent <= 3.0


def test_kitti_raw_city_stereo_and_monocular_distances_agree_within_3_percent() -> None:
    """No poses on this drive: the baseline and the camera's height are independent sources of scale, so
    their distances must agree. Neither was tuned on this drive."""
    from kartpilot.odometry.mono_vo import GroundConfig, MonoVO, MonoVOConfig

    source = KittiOdometrySource(data_path("kitti-raw-city"), "91")
    stereo = run_vo(source.frame_sets(), StereoVO(source.rig), source.name)
    mono_vo = MonoVO(source.rig.camera, MonoVOConfig(ground=GroundConfig(camera_height_m=1.65)))
    mono = run_vo(source.frame_sets(), mono_vo, source.name)

    def length_m(positions: np.ndarray) -> float:
        return float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())

    stereo_m, mono_m = length_m(stereo.trajectory.positions), length_m(mono.trajectory.positions)
    print(f"\nkitti-raw-city: stereo {stereo_m:.2f} m, monocular {mono_m:.2f} m, ratio {stereo_m / mono_m:.4f}\n"
          + stereo.summary() + "\n" + mono.summary())
    assert stereo.bridged_frames == 0 and mono.bridged_frames == 0
    assert abs(stereo_m / mono_m - 1.0) <= 0.03

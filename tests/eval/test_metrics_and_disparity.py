import numpy as np
import pytest
from tests.conftest import data_path

from kartpilot.core.geometry import pose_from_rotvec
from kartpilot.core.trajectory import Trajectory
from kartpilot.eval.disparity import bad_pixel_rate, disparity_search_range_px, load_middlebury_pair
from kartpilot.eval.trajectory_metrics import evaluate_trajectory
from kartpilot.perception.stereo import BlockMatchConfig, compute_disparity


def _straight(count: int, step_m: float) -> Trajectory:
    poses = [pose_from_rotvec(np.zeros(3), np.array([0.0, 0.0, i * step_m])) for i in range(count)]
    return Trajectory.from_poses(poses, np.arange(count) * 0.1)


def test_identical_trajectories_have_zero_error() -> None:
    truth = _straight(60, 0.5)
    metrics = evaluate_trajectory(truth, truth)
    assert metrics.ate_rmse_m == pytest.approx(0.0, abs=1e-9)
    assert metrics.end_drift_percent == pytest.approx(0.0, abs=1e-9)
    assert metrics.rpe[0].translation_percent == pytest.approx(0.0, abs=1e-9)


def test_scale_error_shows_in_drift_and_rpe() -> None:
    truth = _straight(60, 0.5)
    estimate = _straight(60, 0.51)  # 2 % too long
    metrics = evaluate_trajectory(truth, estimate)
    assert metrics.end_drift_percent == pytest.approx(2.0, rel=1e-6)
    assert metrics.rpe[0].translation_percent == pytest.approx(2.0, rel=0.05)
    assert metrics.rpe[1].translation_percent == pytest.approx(2.0, rel=0.05)
    assert metrics.ate_rmse_m > 0


def test_a_heading_that_creeps_shows_in_the_end_rotation() -> None:
    """The estimate turns 0.01 degrees a frame about the vertical (a camera's y axis) where the truth goes
    straight: 0.59 degrees at the end of 29.5 m."""
    truth = _straight(60, 0.5)
    step = np.radians(0.01)
    poses = [pose_from_rotvec(np.array([0.0, i * step, 0.0]), np.array([0.0, 0.0, i * 0.5])) for i in range(60)]
    metrics = evaluate_trajectory(truth, Trajectory.from_poses(poses, np.arange(60) * 0.1))
    print(metrics.table())
    assert metrics.end_rotation_deg == pytest.approx(0.59, abs=1e-6)
    assert metrics.end_rotation_deg_per_m == pytest.approx(0.59 / 29.5, rel=1e-6)
    assert evaluate_trajectory(truth, truth).end_rotation_deg == pytest.approx(0.0, abs=1e-6)


def test_bad_pixel_rate_counts_missing_as_bad() -> None:
    truth = np.full((10, 10), 20.0, np.float32)
    truth[0] = np.nan  # unknown row
    estimate = truth + 1.0
    estimate[1, :5] = 30.0  # 5 bad
    estimate[2, :5] = np.nan  # 5 missing
    score = bad_pixel_rate(estimate, truth, 2.0)
    assert score.pixels_with_truth == 90
    assert score.bad_percent == pytest.approx(100 * 10 / 90)
    assert score.invalid_percent == pytest.approx(100 * 5 / 90)


@pytest.mark.parametrize("pair", ["middlebury-motorcycle", "middlebury-aloe"])
def test_middlebury_block_matchers(pair: str) -> None:
    left, right, truth = load_middlebury_pair(data_path("stereo-pairs", pair))
    span = disparity_search_range_px(truth)
    scores = {}
    for name, config in {"bm": BlockMatchConfig(method="bm", num_disparities=span, block_size=15),
                         "sgbm": BlockMatchConfig(method="sgbm", num_disparities=span),
                         "sgbm+wls": BlockMatchConfig(method="sgbm", num_disparities=span, wls=True)}.items():
        scores[name] = bad_pixel_rate(compute_disparity(left, right, config), truth).bad_percent
    print(f"{pair} bad-2.0 (%): " + ", ".join(f"{k} {v:.1f}" for k, v in scores.items()))
    assert scores["sgbm"] < scores["bm"]  # the semi-global matcher beats local block matching
    assert scores["sgbm"] < 40.0

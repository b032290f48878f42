"""Acceptance: stereo VO on a simulated straight20 drive, with and without the cones (the thesis's RQ)."""

import numpy as np
import pytest

from kartpilot.eval.trajectory_metrics import evaluate_trajectory
from kartpilot.odometry.run import run_vo
from kartpilot.odometry.stereo_vo import StereoVO
from kartpilot.record.recording import RecordingStereoSource
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.simulator import SimConfig


def near_points_per_frame(run, max_depth_m: float = 3.0) -> float:
    counts = [int(np.sum(e.diagnostics.inlier_depths_m < max_depth_m)) for e in run.estimates if e.diagnostics]
    return float(np.mean(counts))


@pytest.mark.slow
def test_stereo_vo_on_a_recorded_straight20_drive(tmp_path):
    """Two recorded drives of straight20 at 2 m/s, 10 Hz (20 cm a frame): stereo VO over the one with cones keeps
    its drift under 2 %, and the bare track gives it almost no points within 3 m (the thesis's question of what
    the cones are for)."""
    results = {}
    for cones in (True, False):
        config = SimConfig(track="straight20", vehicle="rc-kart", cameras=("left", "right"), camera_rate_hz=10.0,
                           show_cones=cones, seed=1)
        folder = tmp_path / ("cones" if cones else "bare")
        drive = run_simulation(config, driver_config=CenterlineDriverConfig(speed_mps=2.0),
                               outputs=SessionOutputs(record_dir=folder))
        assert drive.result.finished and not drive.result.disqualified
        source = RecordingStereoSource(folder)
        results[cones] = (source, run_vo(source.frame_sets(), StereoVO(source.rig), source.name))
    source, run = results[True]
    metrics = evaluate_trajectory(source.ground_truth(), run.trajectory)
    print(f"straight20 with cones: end-point drift {metrics.end_drift_percent:.2f} % "
          f"({metrics.end_drift_m:.3f} m over {metrics.path_length_m:.1f} m), ATE {metrics.ate_rmse_m:.3f} m")
    assert metrics.end_drift_percent < 2.0
    with_cones, without = near_points_per_frame(results[True][1]), near_points_per_frame(results[False][1])
    print(f"valid points nearer than 3 m per frame: {with_cones:.1f} with cones, {without:.1f} without")
    assert without < 0.25 * with_cones

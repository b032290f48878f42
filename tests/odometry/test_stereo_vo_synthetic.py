import numpy as np
import pytest

from kartpilot.core.errors import DataError, PerceptionError
from kartpilot.core.types import FrameSet, StereoFrame
from kartpilot.eval.trajectory_metrics import evaluate_trajectory
from kartpilot.odometry.run import run_vo
from kartpilot.odometry.stereo_vo import StereoVO, StereoVOConfig
from kartpilot.sensors.base import StereoSource
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource


@pytest.fixture(scope="module")
def source() -> SyntheticStereoSource:
    return SyntheticStereoSource(SyntheticStereoConfig(frames=25))


def test_vo_follows_the_synthetic_drive(source: SyntheticStereoSource) -> None:
    run = run_vo(source.frame_sets(), StereoVO(source.rig), source.name)
    metrics = evaluate_trajectory(source.ground_truth(), run.trajectory)
    print(metrics.table())
    assert run.bridged_frames == 0
    assert metrics.end_drift_percent < 1.0
    assert metrics.ate_rmse_m < 0.03


FRAME_TO_FRAME = {"keyframes": False}


@pytest.mark.parametrize("overrides", [{"temporal_matching": "descriptor", **FRAME_TO_FRAME},
                                       {"temporal_matching": "klt", **FRAME_TO_FRAME},
                                       {"joint_depth_refinement": True, "temporal_matching": "descriptor",
                                        **FRAME_TO_FRAME},
                                       {"attitude_prior_deg": 0.0}, {"keyframe_retrack": False},
                                       {"features": {"detector": "akaze"}}, {"stereo_matching": "dense"},
                                       {"window_ba": {"enabled": True}, "temporal_matching": "descriptor",
                                        **FRAME_TO_FRAME},
                                       {"stereo_matching": "dense", "block_match": {"method": "bm"}}])
def test_alternative_configurations_also_track(source: SyntheticStereoSource, overrides: dict) -> None:
    from kartpilot.core.config import merge_config

    run = run_vo(source.frame_sets(), StereoVO(source.rig, merge_config(StereoVOConfig(), overrides)), source.name)
    metrics = evaluate_trajectory(source.ground_truth(), run.trajectory)
    assert metrics.end_drift_percent < 2.0, overrides


def test_black_frame_is_bridged_not_fatal(source: SyntheticStereoSource) -> None:
    vo = StereoVO(source.rig)
    estimates = []
    for index in range(8):
        frame = source.frame(index)
        if index == 4:
            black = np.zeros_like(frame.left)
            frame = StereoFrame(frame.index, frame.stamp_ns, black, black)
        estimates.append(vo.process(frame.as_frame_set()))
    vo.close()
    assert estimates[4].status == "bridged"
    assert "correspondences" in estimates[4].reason or "inliers" in estimates[4].reason
    # the constant-velocity bridge keeps the pose close to the truth
    truth = source.ground_truth().poses[4]
    assert np.linalg.norm(estimates[4].pose_world_cam[:3, 3] - truth[:3, 3]) < 0.05


def test_a_missing_camera_is_a_clear_error(source: SyntheticStereoSource) -> None:
    vo = StereoVO(source.rig)
    frame = source.frame(0)
    with pytest.raises(PerceptionError, match="right camera delivered nothing"):
        vo.process(FrameSet(0, 0, {"left": frame.left}))
    vo.close()


def test_wrong_image_size_is_a_clear_error(source: SyntheticStereoSource) -> None:
    vo = StereoVO(source.rig)
    small = np.zeros((10, 10), np.uint8)
    with pytest.raises(PerceptionError, match="rig expects"):
        vo.process(StereoFrame(0, 0, small, small).as_frame_set())
    vo.close()


class _BrokenSource(StereoSource):
    def __init__(self, inner: StereoSource, unreadable: set[int]) -> None:
        self.inner, self.unreadable, self.name = inner, unreadable, "broken"

    @property
    def rig(self):  # type: ignore[no-untyped-def]
        return self.inner.rig

    def __len__(self) -> int:
        return 6

    def frame(self, index: int) -> StereoFrame:
        if index in self.unreadable:
            raise DataError(f"frame {index} is corrupt")
        return self.inner.frame(index)


def test_unreadable_frames_are_skipped_and_counted(source: SyntheticStereoSource) -> None:
    broken = _BrokenSource(source, {2})
    run = run_vo(broken.frame_sets(), StereoVO(broken.rig), broken.name)
    assert run.unreadable_frames == (2,)
    # the trajectory stays aligned with the frames: the unreadable one is bridged, at its own time
    truth = source.ground_truth()
    assert len(run.trajectory) == 6
    np.testing.assert_allclose(run.trajectory.stamps_s, truth.stamps_s[:6], atol=1e-6)
    error = np.linalg.norm(run.trajectory.positions - truth.positions[:6], axis=1)
    print(f"position error per frame, frame 2 unreadable: {np.round(error, 4)} m")
    assert error.max() < 0.03
    with pytest.raises(DataError, match="none of the 6 frames"):
        run_vo(_BrokenSource(source, set(range(6))).frame_sets(), StereoVO(source.rig), "broken")

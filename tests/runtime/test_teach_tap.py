"""The teach drive's frames to VO as they come (``runtime.experiment``): the same reference as VO over a source,
and a VO that fails stops the drive with its error rather than leaving it waiting."""

from __future__ import annotations

import numpy as np
import pytest

from kartpilot.core.errors import DataError
from kartpilot.core.types import ActuatorCommand, FrameSet
from kartpilot.core.vehicle import camera_pose_on_body
from kartpilot.odometry.run import run_teach
from kartpilot.odometry.stereo_vo import StereoVOConfig
from kartpilot.odometry.visual_map import MapConfig
from kartpilot.runtime.experiment import _TeachTap
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource

BODY_CAM = np.array(camera_pose_on_body(0.0, 0.0, 0.6))


def test_frames_as_they_come_give_what_vo_over_the_source_gives() -> None:
    source = SyntheticStereoSource(SyntheticStereoConfig(frames=20, speed_mps=2.0, yaw_rate_dps=6.0))
    expected, expected_map = run_teach(source, BODY_CAM)
    tap = _TeachTap(("cam_l", "cam_r"), source.rig, BODY_CAM, StereoVOConfig(), MapConfig())
    for index in range(len(source)):
        frame = source.frame(index)
        tap.write_frames(FrameSet(index, frame.stamp_ns, {"cam_l": frame.left, "cam_r": frame.right}))
        tap.send(ActuatorCommand(frame.stamp_ns, 0.01 * index, 0.2, 0.0))
    run, visual_map = tap.finish()
    assert np.allclose(run.trajectory.poses, expected.trajectory.poses)
    assert len(visual_map) == len(expected_map) > 0
    assert [c.steer_rad for c in tap.commands] == pytest.approx([0.01 * i for i in range(len(source))])
    dropped = _TeachTap(("cam_l", "cam_r"), source.rig, BODY_CAM, StereoVOConfig(), MapConfig())
    for index in range(len(source)):  # a camera that dropped a frame: VO bridges it, as over a source
        frame = source.frame(index)
        images = {"cam_l": frame.left} if index == 7 else {"cam_l": frame.left, "cam_r": frame.right}
        dropped.write_frames(FrameSet(index, frame.stamp_ns, images))
    bridged, _ = dropped.finish()
    assert bridged.unreadable_frames == (7,) and len(bridged.trajectory) == len(source)


def test_a_vo_that_fails_ends_the_drive_with_its_error() -> None:
    source = SyntheticStereoSource(SyntheticStereoConfig(frames=3))
    tap = _TeachTap(("left", "right"), source.rig, BODY_CAM, StereoVOConfig(), MapConfig())
    broken = np.zeros((4, 4, 7), np.float64)  # no camera's image: VO's grey conversion raises in its thread
    with pytest.raises(Exception) as raised:
        for index in range(100):  # more frames than the queue holds: the drive is told, not left blocked
            tap.write_frames(FrameSet(index, index * 10**8, {"left": broken, "right": broken}))
    with pytest.raises(type(raised.value)):
        tap.finish()


def test_a_drive_that_never_started_leaves_vo_with_nothing_and_ends():
    """The teach drive could not start (its track was not there): abandoned with no frames, VO ends at once and
    says there was nothing to teach from, rather than waiting for a drive that will never come (the experiment
    hung so)."""
    source = SyntheticStereoSource(SyntheticStereoConfig(frames=3))
    tap = _TeachTap(("left", "right"), source.rig, BODY_CAM, StereoVOConfig(), MapConfig())
    tap.abandon()
    with pytest.raises(DataError):
        tap.finish()

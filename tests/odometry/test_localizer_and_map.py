"""The localizer (VO poses to kart poses, bridging, lost) and the visual map of a taught drive."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kartpilot.core.errors import PlanningError
from kartpilot.core.geometry import between_2d, compose_2d, ground_poses, vo_ground_pose
from kartpilot.core.types import FrameSet
from kartpilot.core.vehicle import camera_pose_on_body
from kartpilot.odometry.localizer import LocalizerConfig, StereoVOLocalizer
from kartpilot.odometry.run import run_teach
from kartpilot.odometry.visual_map import RelocConfig, load_visual_map, map_path_for, relocalize
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource

# the synthetic rig's camera looks straight ahead from 0.6 m up, at the rear axle
BODY_CAM = np.array(camera_pose_on_body(0.0, 0.0, 0.6))


@pytest.fixture(scope="module")
def source() -> SyntheticStereoSource:
    return SyntheticStereoSource(SyntheticStereoConfig(frames=30, speed_mps=2.0, yaw_rate_dps=6.0))


def test_camera_poses_become_kart_poses_on_the_road(source: SyntheticStereoSource) -> None:
    truth = ground_poses(source.ground_truth().poses, BODY_CAM)
    step = np.diff(truth[:, :2], axis=0)
    assert np.allclose(np.hypot(step[:, 0], step[:, 1]), 2.0 / 10.0, rtol=1e-3)  # 2 m/s at 10 Hz
    assert truth[0].tolist() == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
    assert abs(truth[-1, 2]) == pytest.approx(math.radians(6.0) * 2.9, rel=1e-3)
    assert np.sign(truth[-1, 1]) == np.sign(truth[-1, 2])  # turning left (yaw up) moves the kart left (y up)
    assert vo_ground_pose(source.ground_truth().poses[5], BODY_CAM) == pytest.approx(tuple(truth[5]), abs=1e-9)
    a, b = (1.0, 2.0, 0.3), (0.5, -0.2, 0.1)
    assert between_2d(a, compose_2d(a, b)) == pytest.approx(b)


def frames_of(source: SyntheticStereoSource, index: int, drop: bool = False) -> FrameSet:
    frame = source.frame(index)
    return FrameSet(index, frame.stamp_ns, {} if drop else {"left": frame.left, "right": frame.right})


def test_the_localizer_tracks_bridges_a_gap_and_reports_lost(source: SyntheticStereoSource) -> None:
    truth = ground_poses(source.ground_truth().poses, BODY_CAM)
    localizer = StereoVOLocalizer(source.rig, BODY_CAM, config=LocalizerConfig(max_bridge_s=0.25))
    try:
        poses = [localizer.update(frames_of(source, i)) for i in range(12)]
        assert all(p.status == "ok" for p in poses)
        assert np.hypot(poses[-1].x_m - truth[11, 0], poses[-1].y_m - truth[11, 1]) < 0.05
        assert poses[-1].speed_mps == pytest.approx(2.0, rel=0.1)
        gap = [localizer.update(frames_of(source, i, drop=True)) for i in range(12, 16)]
        assert [p.status for p in gap] == ["bridged", "bridged", "lost", "lost"]  # 0.1 s per frame
        assert "left camera delivered nothing" in gap[0].reason
        assert gap[1].x_m > poses[-1].x_m + 0.3  # the motion model carries it on
        black = FrameSet(16, source.frame(16).stamp_ns, {"left": np.zeros_like(source.frame(16).left),
                                                          "right": source.frame(16).right})
        assert "left camera's frame is black" in localizer.update(black).reason
        back = localizer.update(frames_of(source, 17))
        assert back.status == "ok"
        assert np.hypot(back.x_m - truth[17, 0], back.y_m - truth[17, 1]) < 0.1
    finally:
        localizer.close()


def test_a_bridged_pose_moves_at_the_kart_s_measured_speed(source: SyntheticStereoSource) -> None:
    """The kart brakes during a camera gap: its own speed sensor says 0.5 m/s, and the bridged pose follows
    it instead of the 2 m/s the last frames showed; a stale measurement is not used."""
    localizer = StereoVOLocalizer(source.rig, BODY_CAM, config=LocalizerConfig(max_bridge_s=0.25))
    try:
        last = [localizer.update(frames_of(source, i)) for i in range(6)][-1]
        localizer.observe_speed(last.stamp_ns, 0.5)
        bridged = localizer.update(frames_of(source, 6, drop=True))
        assert bridged.status == "bridged" and bridged.speed_mps == 0.5
        assert math.hypot(bridged.x_m - last.x_m, bridged.y_m - last.y_m) == pytest.approx(0.05, abs=1e-3)
        stale = localizer.update(frames_of(source, 9, drop=True))  # 0.3 s after the measurement
        assert stale.speed_mps == 0.5  # the bridge's last speed carries on, not a fresh measurement
        localizer.observe_speed(stale.stamp_ns, math.nan)  # a NaN from the bus is ignored
        assert localizer.update(frames_of(source, 10, drop=True)).speed_mps == 0.5
    finally:
        localizer.close()


def test_a_taught_map_relocalises_its_own_frames_and_survives_a_round_trip(source, tmp_path) -> None:
    run, visual_map = run_teach(source, BODY_CAM)
    assert len(visual_map) >= 8  # 5.8 m driven, a keyframe every 0.5 m
    target = visual_map.save(map_path_for(tmp_path / "ref.csv"))
    assert target.name == "ref.map.npz"
    loaded = load_visual_map(target)
    assert len(loaded) == len(visual_map) and np.array_equal(loaded.descriptors[3], visual_map.descriptors[3])
    # frame 7 seen from keyframe 1 (about 0.9 m behind it): the relocalised pose agrees with VO's
    from kartpilot.odometry.stereo_vo import StereoVO

    vo = StereoVO(source.rig)
    vo.process(source.frame(7).as_frame_set())
    latest = vo.last_features()
    assert latest is not None
    found = relocalize(loaded, 1, latest[0], source.rig.camera.matrix, RelocConfig())
    vo.close()
    assert found is not None and found[1] >= 15
    measured = vo_ground_pose(found[0], BODY_CAM)
    expected = vo_ground_pose(run.trajectory.poses[7], BODY_CAM)
    print(f"relocalised {found[1]} inliers, {math.dist(measured[:2], expected[:2]) * 100:.1f} cm from VO")
    assert math.dist(measured[:2], expected[:2]) < 0.03
    (tmp_path / "bad.map.npz").write_bytes(b"not a map")
    with pytest.raises(PlanningError, match="unreadable visual map"):
        load_visual_map(tmp_path / "bad.map.npz")

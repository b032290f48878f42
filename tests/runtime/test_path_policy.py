"""The stereo-VO path-following policy fails closed."""

import numpy as np

from kartpilot.control.path_follow import PathFollowConfig
from kartpilot.core.types import ActuatorCommand, FrameSet
from kartpilot.core.vehicle import camera_pose_on_body
from kartpilot.odometry.localizer import LocalizerConfig, StereoVOLocalizer
from kartpilot.planning.reference_path import PathConfig, build_reference_path
from kartpilot.runtime.path_policy import PathFollowPolicy, write_drive_log
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource


def test_losing_vo_stops_the_kart_and_it_stays_stopped(tmp_path):
    source = SyntheticStereoSource(SyntheticStereoConfig(frames=16, speed_mps=1.0, yaw_rate_dps=0.0))
    localizer = StereoVOLocalizer(source.rig, np.array(camera_pose_on_body(0.0, 0.0, 0.6)),
                                  config=LocalizerConfig(max_bridge_s=0.3))
    path = build_reference_path(np.column_stack([np.linspace(0, 30, 301), np.zeros(301)]), PathConfig())
    policy = PathFollowPolicy(localizer, path, PathFollowConfig(), 0.35, 0.45, 10.0)
    commands: list[ActuatorCommand] = []
    try:
        for i in range(16):
            frame = source.frame(i)
            images = {} if 6 <= i < 12 else {"left": frame.left, "right": frame.right}  # the cameras stall
            commands.append(policy(FrameSet(i, frame.stamp_ns, images)))
    finally:
        policy.close()
    assert all(c.brake == 0.0 and c.throttle > 0.0 for c in commands[1:6])  # driving
    assert commands[6].brake == 0.0  # a short gap is bridged by the motion model
    stopped = [i for i, c in enumerate(commands) if c == ActuatorCommand.stop(c.stamp_ns)]
    assert stopped == list(range(stopped[0], 16)) and stopped[0] <= 10  # lost: stop, and stay stopped
    assert policy.stop_reason.startswith("localisation lost")
    log = write_drive_log(policy.samples, tmp_path / "log.csv").read_text().splitlines()
    assert log[0].startswith("stamp_ns,x_m,y_m,yaw_rad,speed_mps,pose_status") and len(log) == 17


def test_a_kart_that_drives_past_the_whole_reference_is_stopped_whatever_its_pose_says():
    from kartpilot.core.types import VehiclePose

    class StuckLocalizer:  # a pose pinned in place while the speed says the kart moves
        def update(self, frames: FrameSet) -> VehiclePose:
            return VehiclePose(frames.stamp_ns, 1.0, 0.0, 0.0, 1.0, 0.0, "ok")

        def close(self) -> None:
            pass

    path = build_reference_path(np.column_stack([np.linspace(0, 10, 101), np.zeros(101)]), PathConfig())
    policy = PathFollowPolicy(StuckLocalizer(), path, PathFollowConfig(), 0.35, 0.45, 10.0)  # type: ignore[arg-type]
    commands = [policy(FrameSet(i, i * 100_000_000, {})) for i in range(140)]
    stop_at = next(i for i, c in enumerate(commands) if c.brake == 1.0)
    assert 125 <= stop_at <= 132  # 1.1 x 10 m + 2 m at 1 m/s, 10 Hz
    assert policy.stop_reason.startswith("drove 13.")


def test_the_kart_s_measured_speed_drives_the_speed_control_when_it_reports_one():
    from kartpilot.core.types import VehicleFeedback, VehiclePose

    class SlowOdometry:  # odometry says the kart crawls
        def __init__(self) -> None:
            self.heard: list[float] = []

        def update(self, frames: FrameSet) -> VehiclePose:
            return VehiclePose(frames.stamp_ns, 1.0 + frames.index * 0.01, 0.0, 0.0, 0.1, 0.0, "ok")

        def observe_speed(self, stamp_ns: int, speed_mps: float) -> None:
            self.heard.append(speed_mps)

        def close(self) -> None:
            pass

    path = build_reference_path(np.column_stack([np.linspace(0, 30, 301), np.zeros(301)]),
                                PathConfig(cruise_speed_mps=1.0))
    by_odometry = PathFollowPolicy(SlowOdometry(), path, PathFollowConfig(), 0.35, 0.45, 10.0)  # type: ignore[arg-type]
    by_sensor = PathFollowPolicy(SlowOdometry(), path, PathFollowConfig(), 0.35, 0.45, 10.0)  # type: ignore[arg-type]
    for i in range(5):
        frames = FrameSet(i, i * 100_000_000, {})
        throttle = by_odometry(frames).throttle
        by_sensor.observe_vehicle(VehicleFeedback(frames.stamp_ns, speed_mps=3.0))  # the kart's 0x440: too fast
        braking = by_sensor(frames)
    assert throttle > 0.0  # odometry alone: speed up
    assert braking.throttle == 0.0 and braking.brake > 0.0  # the measured speed: brake
    assert by_sensor.localizer.heard == [3.0] * 5  # and the localiser hears it (bridging, one camera's scale)
    by_sensor.observe_vehicle(VehicleFeedback(0, speed_mps=None))  # stale or none: odometry again
    assert by_sensor(FrameSet(5, 500_000_000, {})).throttle > 0.0
    assert len(by_sensor.localizer.heard) == 5

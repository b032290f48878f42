"""The RPLIDAR driver (issue 58) against a fake device on a pseudo-terminal that speaks the maker's protocol
(tests/sensors/fake_rplidar.py): sweeps with the angles turned to ROS's sense, a device that reports bad health,
garbage on the line once and for good, and a device unplugged mid-drive. Each ends in one clear error or goes
on; a frame source with the LiDAR keeps delivering frames whatever the LiDAR does, and the watchdog reports a
LiDAR that stopped. Waits on what happened (sweeps counted, an error set), with a bound for a broken run."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from tests.sensors.fake_rplidar import FakeRplidar

from kartpilot.core.errors import ConfigError, SensorError
from kartpilot.core.types import FrameSet, LaserScan
from kartpilot.sensors.health import LidarWatchdog
from kartpilot.sensors.lidar import RplidarConfig, RplidarScanner, WithScans, sweep_from_measures


def _wall_on_the_right(angle_cw_deg: float) -> float:
    return 2000.0 if 80.0 <= angle_cw_deg <= 100.0 else 0.0


def _until(condition, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s  # a bound for a broken run, not a measure of speed
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return False


@pytest.fixture
def fake(request):
    device = FakeRplidar(_wall_on_the_right, **getattr(request, "param", {}))
    yield device
    device.close()


def test_sweeps_arrive_with_the_angles_in_ros_s_sense(fake) -> None:
    """The device measures clockwise: a wall it sees at 80 to 100 deg (its right) is at -100 to -80 deg in the
    sweep (counter-clockwise), 2 m away; the motor was given its PWM and the scan was asked for once."""
    with RplidarScanner(RplidarConfig(port=fake.port)).start() as scanner:
        assert scanner.health == ("Good", 0) and scanner.info["model"] == 0x18
        sweeps: list[LaserScan] = []

        def three() -> bool:
            sweeps.extend(scanner.take())
            return len(sweeps) >= 3

        assert _until(three)
    sweep = sweeps[-1]
    seen = np.isfinite(sweep.ranges_m)
    angles = np.degrees(sweep.angles_rad()[seen])
    print(f"{len(sweeps)} sweeps; returns from {angles.min():.0f} to {angles.max():.0f} deg at "
          f"{np.nanmean(sweep.ranges_m):.3f} m, a sweep every {sweep.scan_time_s:.3f} s")
    assert angles.min() == pytest.approx(-100.0, abs=1.0) and angles.max() == pytest.approx(-80.0, abs=1.0)
    assert np.allclose(sweep.ranges_m[seen], 2.0, atol=0.003) and np.all(sweep.points_m()[:, 1] < 0)
    assert 0.05 < sweep.scan_time_s < 0.5 and [s.stamp_ns for s in sweeps] == sorted(s.stamp_ns for s in sweeps)
    assert fake.pwm[0] == 660 and fake.requests.count(0x20) == 1


@pytest.mark.parametrize("fake", [{"health": "Error", "error_code": 0x8001}], indirect=True)
def test_a_device_that_reports_bad_health_is_refused_before_the_drive(fake) -> None:
    scanner = RplidarScanner(RplidarConfig(port=fake.port))
    with pytest.raises(SensorError, match=rf"LiDAR on {fake.port} reports its health as Error \(code"):
        scanner.start()
    assert not scanner.running and 0x20 not in fake.requests  # no scan was started


def test_no_device_at_the_port_is_one_clear_error(tmp_path) -> None:
    with pytest.raises(SensorError, match=r"LiDAR on .*nothing-here"):
        RplidarScanner(RplidarConfig(port=str(tmp_path / "nothing-here"), timeout_s=0.2)).start()


@pytest.mark.parametrize("fake", [{"garbage_at_sweeps": (2,)}], indirect=True)
def test_garbage_on_the_line_once_restarts_the_scan_and_the_sweeps_go_on(fake) -> None:
    with RplidarScanner(RplidarConfig(port=fake.port)).start() as scanner:
        assert _until(lambda: scanner.sweeps >= 5)
        assert scanner.error is None and fake.requests.count(0x20) == 2  # the scan asked for again, once


@pytest.mark.parametrize("fake", [{"garbage_always_from": 1}], indirect=True)
def test_garbage_for_good_gives_up_with_the_reason(fake) -> None:
    with RplidarScanner(RplidarConfig(port=fake.port, max_resyncs=2)).start() as scanner:
        assert _until(lambda: scanner.error is not None)
        assert "garbage on the line 3 times in a row" in str(scanner.error) and "baud rate" in str(scanner.error)
        assert _until(lambda: not scanner.running)


class _Frames:
    """A camera that goes on delivering (stamped by a simulated clock: 30 ms a set)."""

    def __init__(self) -> None:
        self.k = 0

    def read(self) -> FrameSet:
        self.k += 1
        return FrameSet(self.k, self.k * 30_000_000, {"center": np.full((4, 4), 100, np.uint8)})


@pytest.mark.parametrize("fake", [{"vanish_after": 4}], indirect=True)
def test_a_device_unplugged_mid_drive_ends_its_thread_and_the_frames_go_on(fake) -> None:
    """The fake closes its side of the line after four sweeps: the scanner says it went away, naming the port;
    the frame source goes on delivering frames (without sweeps), and the watchdog, on the frames' own clock,
    reports the LiDAR once half a second has passed without a good sweep."""
    scanner = RplidarScanner(RplidarConfig(port=fake.port, timeout_s=0.3)).start()
    source = WithScans(_Frames(), scanner)
    watchdog = LidarWatchdog(["lidar"])
    try:
        reports: list[dict[str, str]] = []
        with_sweep = 0

        def step() -> bool:
            frames = source.read()
            nonlocal with_sweep
            with_sweep += "lidar" in frames.scans
            reports.append(watchdog.check(frames))
            time.sleep(0.03)
            return scanner.error is not None and bool(reports[-1])

        assert _until(step)
    finally:
        source.close()
    print(scanner.error, reports[-1])
    assert with_sweep >= 2 and f"LiDAR on {fake.port} went away" in str(scanner.error)
    assert "no good sweep for" in reports[-1]["lidar"]


def test_a_sweep_keeps_each_beam_s_nearest_return_within_the_range() -> None:
    config = RplidarConfig(step_deg=1.0, range_min_m=0.2, range_max_m=5.0)
    sweep = sweep_from_measures([(10, 0.0, 3000.0), (20, 0.2, 2500.0), (5, 90.0, 100.0), (5, 180.0, 9000.0)], 7,
                                0.1, config)
    assert len(sweep.ranges_m) == 360 and sweep.stamp_ns == 7 and sweep.time_increment_s == pytest.approx(0.1 / 360)
    ahead = int(np.argmin(np.abs(sweep.angles_rad())))
    assert sweep.ranges_m[ahead] == pytest.approx(2.5) and sweep.intensities[ahead] == 20  # the nearer of two
    assert np.count_nonzero(np.isfinite(sweep.ranges_m)) == 1  # 0.1 m: too near; 9 m: too far
    assert sweep_from_measures([], 0, 0.1, config).ranges_m.size == 360


@pytest.mark.parametrize("changes", [{"port": ""}, {"baudrate": 9600}, {"scan_mode": "boost"}, {"motor_pwm": 2000},
                                     {"step_deg": 0.0}, {"timeout_s": math.nan}])
def test_a_driver_setting_that_cannot_be_is_refused_by_name(changes) -> None:
    with pytest.raises(ConfigError, match=rf"lidar\.{next(iter(changes))}"):
        RplidarConfig(**changes)


def test_the_monitor_prints_the_device_and_its_sweeps_rate(fake, tmp_path, capsys) -> None:
    from kartpilot.cli.main import main

    assert main(["lidar", "monitor", "--port", fake.port, "--duration", "0.8", "--every", "0.3",
                 "--json", str(tmp_path / "lidar.json")]) == 0
    out = capsys.readouterr().out
    print(out)
    assert "health Good" in out and "model 24" in out and "Hz" in out
    import json

    summary = json.loads((tmp_path / "lidar.json").read_text())
    assert summary["error"] is None and 5.0 < summary["lidar"]["rate_hz"] < 20.0
    assert summary["lidar"]["frozen"] == 0 and summary["lidar"]["returns_median"] == 21


@pytest.mark.parametrize("fake", [{"vanish_after": 3}], indirect=True)
def test_the_monitor_of_a_device_that_goes_away_says_so_and_fails(fake, capsys) -> None:
    from kartpilot.cli.main import main

    assert main(["lidar", "monitor", "--port", fake.port, "--duration", "5"]) == 1
    assert f"kartpilot: error: LiDAR on {fake.port} went away" in capsys.readouterr().err


def test_a_device_given_on_the_command_line_is_not_taken_for_a_file(capsys) -> None:
    """The command line's file checks refused any device (a serial port, the gamepad's joystick) as "not a regular
    file": the LiDAR's port and the gamepad name devices, which their drivers open (and say what is wrong)."""
    from kartpilot.cli.main import main

    assert main(["lidar", "monitor", "--port", "/dev/null", "--duration", "0.1"]) == 1
    err = capsys.readouterr().err
    assert "not a regular file" not in err and "kartpilot: error: LiDAR on /dev/null" in err
    main(["drive", "--live", "/nonexistent-rig.yaml", "--gamepad", "/dev/null"])
    assert "not a regular file" not in capsys.readouterr().err


def test_a_device_that_never_answers_is_one_clear_error_within_the_timeout(tmp_path) -> None:
    """A pty with nothing behind it (a cable to a sensor without power): the first question times out, and the
    error names the port; nothing is left open."""
    import os

    master, slave = os.openpty()
    try:
        scanner = RplidarScanner(RplidarConfig(port=os.ttyname(slave), timeout_s=0.2))
        with pytest.raises(SensorError, match=rf"LiDAR on {os.ttyname(slave)}: .*(no data|Descriptor)"):
            scanner.start()
        assert not scanner.running
    finally:
        os.close(master)
        os.close(slave)

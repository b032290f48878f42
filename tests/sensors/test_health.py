"""A camera that stalls, goes black or freezes is reported within the timeout."""

import numpy as np

from kartpilot.core.types import FrameSet
from kartpilot.sensors.health import CameraWatchdog, HealthConfig, frame_problem


def noisy(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(40, 200, (48, 64), dtype=np.uint8)


def test_each_kind_of_bad_frame_is_named():
    config = HealthConfig()
    good = noisy(1)
    assert frame_problem(good, noisy(2), config) == ""
    assert frame_problem(None, good, config) == "missing"
    assert frame_problem(np.zeros((0, 0), np.uint8), good, config) == "empty"
    assert frame_problem(np.full((48, 64), 3, np.uint8), good, config) == "black"
    assert frame_problem(np.full((48, 64), 255, np.uint8), good, config) == "blank"
    assert frame_problem(good.copy(), good, config) == "frozen"


def test_a_stalled_or_frozen_camera_is_reported_within_the_timeout():
    watchdog = CameraWatchdog(["left", "right"], HealthConfig(timeout_s=0.3))
    frozen = noisy(0)
    reports = []
    for k in range(12):  # 10 Hz; the right camera freezes at frame 2, the left stops at frame 6
        images = {"right": noisy(100 + k) if k < 2 else frozen}
        if k < 6:
            images["left"] = noisy(k)
        reports.append(watchdog.check(FrameSet(k, k * 100_000_000, images)))
    first_right = next(k for k, r in enumerate(reports) if "right" in r)
    first_left = next(k for k, r in enumerate(reports) if "left" in r)
    # the frozen image is good once (it differs from frame 1), then repeats: last good frame 2, reported
    # at frame 6, the first more than 0.3 s later
    assert first_right == 6 and "frozen" in reports[first_right]["right"]
    assert first_left == 9 and "missing" in reports[first_left]["left"]  # last good at frame 5
    assert all("left" in r and "right" in r for r in reports[9:])

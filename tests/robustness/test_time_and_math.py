"""The order of time and the mathematics' preconditions, checked where the input enters: stamps that go
backwards or repeat (every pose file becomes a Trajectory, which checks them; a recording's frames and commands),
a rotation that is not one, a quaternion that is not a unit one. Property-based (Hypothesis) where the kind has
many shapes."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kartpilot.core.errors import DataError, KartpilotError
from kartpilot.core.trajectory import Trajectory, read_kitti_poses, read_tum

SETTINGS = settings(max_examples=40, deadline=None, derandomize=True, database=None)


@SETTINGS
@given(st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=2, max_size=30))
def test_a_trajectory_takes_only_times_that_go_forward(tmp_path_factory, stamps):
    path = tmp_path_factory.mktemp("tum") / "poses.txt"
    path.write_text("".join(f"{t!r} 0 0 0 0 0 0 1\n" for t in stamps))
    forward = all(b > a for a, b in itertools.pairwise(stamps))
    if forward:
        assert len(read_tum(path)) == len(stamps)
    else:
        with pytest.raises(DataError, match=r"poses\.txt: timestamps go backwards or repeat"):
            read_tum(path)


def test_a_trajectory_refuses_times_that_are_not_numbers():
    with pytest.raises(DataError, match="not a number"):
        Trajectory(np.array([0.0, np.nan]), np.tile(np.eye(4), (2, 1, 1)))


@SETTINGS
@given(st.lists(st.floats(-2.0, 2.0), min_size=4, max_size=4))
def test_a_quaternion_must_be_a_unit_one(tmp_path_factory, quat):
    path = tmp_path_factory.mktemp("tum") / "poses.txt"
    path.write_text("0 1 2 3 " + " ".join(repr(q) for q in quat) + "\n")
    if abs(np.linalg.norm(quat) - 1.0) <= 0.1:
        assert read_tum(path).poses.shape == (1, 4, 4)
    else:
        with pytest.raises(DataError, match="not a unit one"):
            read_tum(path)


@SETTINGS
@given(st.floats(0.5, 2.0), st.booleans())
def test_a_kitti_pose_must_hold_a_rotation(tmp_path_factory, scale, mirror):
    rotation = np.eye(3) * scale
    if mirror:
        rotation[2, 2] *= -1
    path = tmp_path_factory.mktemp("kitti") / "poses.txt"
    path.write_text(" ".join(f"{v:.9e}" for v in np.column_stack([rotation, [1, 2, 3]]).ravel()) + "\n")
    if abs(scale - 1.0) < 1e-4 and not mirror:
        assert len(read_kitti_poses(path)) == 1
    else:
        with pytest.raises(DataError, match="not a rotation"):
            read_kitti_poses(path)


def test_a_recording_whose_frames_go_back_in_time_is_refused_naming_the_line(tmp_path):
    from kartpilot.core.camera import PinholeCamera
    from kartpilot.record.recording import RecordingReader, RecordingWriter

    camera = PinholeCamera(width_px=32, height_px=24, fx_px=30.0, fy_px=30.0, cx_px=16.0, cy_px=12.0)
    with RecordingWriter(tmp_path / "rec", {"left": camera}) as writer:
        for stamp in (1_000, 2_000, 3_000):
            writer.write_frame("left", stamp, np.zeros((24, 32, 3), np.uint8))
    frames = tmp_path / "rec" / "cameras" / "left" / "frames.csv"
    lines = frames.read_text().splitlines()
    lines[2], lines[3] = lines[3], lines[2]  # the second and third frames swapped
    frames.write_text("\n".join(lines) + "\n")
    with pytest.raises(KartpilotError, match=r"frames\.csv:4: stamp_ns 2000 .*go backwards or repeat"):
        RecordingReader(tmp_path / "rec").frames("left")


@SETTINGS
@given(st.lists(st.integers(0, 10**6), min_size=2, max_size=12))
def test_a_euroc_frame_list_takes_only_stamps_that_go_forward(tmp_path_factory, stamps):
    """EuRoC's ``cam0/data.csv``: a repeat or a step back is refused with its line, not sorted into order (which
    would pair the wrong images)."""
    from kartpilot.sensors.euroc import _read_stamps

    folder = tmp_path_factory.mktemp("cam0")
    (folder / "data").mkdir()
    for k, _ in enumerate(stamps):
        (folder / "data" / f"{k}.png").write_bytes(b"")
    path = folder / "data.csv"
    path.write_text("#timestamp [ns],filename\r\n" + "".join(f"{t},{k}.png\r\n" for k, t in enumerate(stamps)))
    if all(b > a for a, b in itertools.pairwise(stamps)):
        assert list(_read_stamps(path)) == stamps
    else:
        with pytest.raises(DataError, match=r"data\.csv, line \d+: stamp \d+ (repeats|goes back)"):
            _read_stamps(path)
    path.write_text("#timestamp [ns],filename\n1.5e9,0.png\n")
    with pytest.raises(DataError, match="not whole nanoseconds"):
        _read_stamps(path)

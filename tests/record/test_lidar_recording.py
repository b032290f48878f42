"""The LiDAR in a recording (issue 58): a simulated drive of the 2026 kart records its sweeps beside the frames,
they read back sweep for sweep, a replay hands them to the frame sets as the drive did, and a line cut off by a
crash or a damaged line is left out or named."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kartpilot.core.errors import RecordingError
from kartpilot.core.types import LidarMount
from kartpilot.record.recording import RecordingReader
from kartpilot.record.replay import RecordingFrameSource
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.simulator import SimConfig, Simulator
from kartpilot.sim.track import Prop

CONFIG = SimConfig(track="straight20", vehicle="sdc-kart-2026", cameras=("center",), camera_rate_hz=15.0,
                   max_time_s=2.0, props=(Prop(kind="car", s_m=12.0, offset_m=0.0),))


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lidar") / "drive"
    run_simulation(CONFIG, "centerline", driver_config=CenterlineDriverConfig(speed_mps=2.0),
                   outputs=SessionOutputs(record_dir=folder))
    return folder


def test_the_sweeps_are_recorded_with_the_mount_and_read_back_sweep_for_sweep(drive) -> None:
    """The first sweep as the same simulation (same seed) makes it again, each range to the format's 0.1 mm, a
    return and no return where they were; 10 Hz beside 15 Hz frames: 20 sweeps in 2 s, each at its own time."""
    reader = RecordingReader(drive)
    assert reader.lidars == {"lidar": LidarMount(1.45, 0.0, 0.30)}
    recorded = reader.scans("lidar")
    assert reader.manifest["scan_counts"] == {"lidar": len(recorded)} and len(recorded) == 20
    with Simulator(CONFIG) as sim:  # the first sweep, taken standing still before any command, made again
        frames = sim.read()
        assert frames is not None
        same = frames.scans["lidar"]
    first = recorded[0]
    assert first.stamp_ns == same.stamp_ns and first.angle_increment_rad == pytest.approx(same.angle_increment_rad)
    assert np.array_equal(np.isnan(first.ranges_m), np.isnan(same.ranges_m))
    assert np.nanmax(np.abs(first.ranges_m - same.ranges_m)) <= 5e-5
    assert [s.stamp_ns for s in recorded] == [round(k * 0.1e9) for k in range(20)]


def test_a_replay_hands_each_sweep_to_the_set_it_came_with(drive) -> None:
    source = RecordingFrameSource(drive)
    handed = []
    while (frames := source.read()) is not None:
        if "lidar" in frames.scans:
            assert frames.scans["lidar"].stamp_ns <= frames.stamp_ns
            handed.append(frames.scans["lidar"].stamp_ns)
    assert handed == [s.stamp_ns for s in RecordingReader(drive).scans("lidar")]


def test_a_torn_last_sweep_is_left_out_and_a_damaged_one_named(drive, tmp_path) -> None:
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(drive, copy)
    path = copy / "lidar" / "lidar" / "scans.csv"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:-1]) + lines[-1][: len(lines[-1]) // 2])  # cut off mid-line, as a crash leaves
    assert len(RecordingReader(copy).scans("lidar")) == 19
    lines[3] = lines[3].replace(",", ",x", 1)
    path.write_text("".join(lines))
    with pytest.raises(RecordingError, match=r"scans\.csv:4: not a sweep"):
        RecordingReader(copy).scans("lidar")
    values = lines[5].split(",")
    values[-1] = " ".join(values[-1].split()[:-3]) + "\n"  # fewer intensities than ranges
    lines[3] = lines[4]
    lines[5] = ",".join(values)
    path.write_text("".join(lines[:4] + lines[5:]))
    with pytest.raises(RecordingError, match="ranges but"):
        RecordingReader(copy).scans("lidar")
    with pytest.raises(RecordingError, match="no LiDAR 'front'"):
        RecordingReader(copy).scans("front")


def test_a_recording_without_a_lidar_reads_as_one_with_none(tmp_path) -> None:
    folder = tmp_path / "plain"
    run_simulation(SimConfig(track="straight20", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=10.0,
                             max_time_s=0.5), "centerline", outputs=SessionOutputs(record_dir=folder))
    reader = RecordingReader(folder)
    assert reader.lidars == {} and not (folder / "lidar").exists()
    frames = RecordingFrameSource(folder).read()
    assert frames is not None and frames.scans == {}
    assert math.isfinite(reader.manifest["frame_counts"]["center"])

import json
import math
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import RecordingError
from kartpilot.core.types import ActuatorCommand, FrameSet
from kartpilot.record.recording import RecordingReader, RecordingStereoSource, RecordingWriter
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource


def _cameras(source: SyntheticStereoSource) -> dict[str, PinholeCamera]:
    left = source.rig.camera
    right_pose = np.eye(4)
    right_pose[0, 3] = source.rig.baseline_m
    right = PinholeCamera(left.fx_px, left.fy_px, left.cx_px, left.cy_px, left.width_px, left.height_px,
                          pose_body_cam=tuple(tuple(row) for row in right_pose))
    return {"left": left, "right": right}


@pytest.fixture(scope="module")
def source() -> SyntheticStereoSource:
    return SyntheticStereoSource(SyntheticStereoConfig(frames=4, width_px=320, height_px=180, focal_px=200))


def test_round_trip_frames_commands_and_groundtruth(tmp_path, source: SyntheticStereoSource) -> None:
    folder = tmp_path / "run1"
    with RecordingWriter(folder, _cameras(source), stereo_pair=("left", "right"), metadata={"track": "synthetic"}) as w:
        for frame in source:
            w.write_frame("left", frame.stamp_ns, frame.left)
            w.write_frame("right", frame.stamp_ns, frame.right)
            w.write_command(ActuatorCommand(frame.stamp_ns, 0.01 * frame.index, 0.3, 0.0))
        w.write_groundtruth(source.ground_truth())
    reader = RecordingReader(folder)
    assert reader.closed
    assert reader.manifest["frame_counts"] == {"left": 4, "right": 4}
    assert reader.commands()[3] == ActuatorCommand(source.frame(3).stamp_ns, 0.03, 0.3, 0.0)
    replay = RecordingStereoSource(folder)
    assert replay.rig.baseline_m == pytest.approx(source.rig.baseline_m)
    for original, loaded in zip(source, replay, strict=True):
        np.testing.assert_array_equal(original.left, loaded.left)
        np.testing.assert_array_equal(original.right, loaded.right)
        assert original.stamp_ns == loaded.stamp_ns
    truth = replay.ground_truth()
    assert truth is not None
    np.testing.assert_allclose(truth.poses, source.ground_truth().poses, atol=1e-8)


def test_recording_cut_off_by_a_crash_still_opens(tmp_path, source: SyntheticStereoSource) -> None:
    folder = tmp_path / "crash"
    writer = RecordingWriter(folder, _cameras(source), stereo_pair=("left", "right"))
    for frame in list(source)[:3]:
        writer.write_frame("left", frame.stamp_ns, frame.left)
        writer.write_frame("right", frame.stamp_ns, frame.right)
    # simulate power loss: never closed, and a half-written last line
    with (folder / "cameras" / "left" / "frames.csv").open("a") as handle:
        handle.write("3,12345")
    reader = RecordingReader(folder)
    assert not reader.closed
    assert len(RecordingStereoSource(folder)) == 3


def test_lanes_opens_a_recording_cut_off_mid_row(tmp_path, source: SyntheticStereoSource) -> None:
    """A drive killed while it listed a frame: the row names a file that was never written. ``kartpilot lanes``
    keeps every frame flushed before it (it refused the whole recording)."""
    import csv

    from kartpilot.cli.main import main

    folder = tmp_path / "killed"
    writer = RecordingWriter(folder, _cameras(source), stereo_pair=("left", "right"))
    for frame in list(source)[:3]:
        writer.write_frame("left", frame.stamp_ns, frame.left)
        writer.write_frame("right", frame.stamp_ns, frame.right)
    with (folder / "cameras" / "left" / "frames.csv").open("a") as handle:
        handle.write("3,3000000000,30000")  # cut in the middle of the file's name
    out = tmp_path / "lanes.csv"
    assert main(["lanes", str(folder), "--out", str(out)]) == 0
    assert len(list(csv.DictReader(out.open()))) == 3


def test_refuses_to_overwrite_and_rejects_foreign_folders(tmp_path, source: SyntheticStereoSource) -> None:
    folder = tmp_path / "run"
    RecordingWriter(folder, _cameras(source)).close()
    with pytest.raises(RecordingError, match="not empty"):
        RecordingWriter(folder, _cameras(source))
    with pytest.raises(RecordingError, match="no manifest"):
        RecordingReader(tmp_path)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "manifest.json").write_text(json.dumps({"format": "donkey"}))
    with pytest.raises(RecordingError, match="format"):
        RecordingReader(tmp_path / "other")
    with pytest.raises(RecordingError, match="no stereo pair"):
        RecordingStereoSource(folder)


def test_recordings_info_reports_frames_skew_and_commands_of_a_cut_off_recording(tmp_path, capsys):
    import json

    import numpy as np

    from kartpilot.cli.main import main
    from kartpilot.core.camera import PinholeCamera
    from kartpilot.core.types import ActuatorCommand
    from kartpilot.record.recording import RecordingWriter

    camera = PinholeCamera(100.0, 100.0, 31.5, 23.5, 64, 48)
    writer = RecordingWriter(tmp_path / "run", {"left": camera, "right": camera}, stereo_pair=("left", "right"))
    image = np.zeros((48, 64), np.uint8)
    for k in range(10):
        stamp = k * 100_000_000
        writer.write_frame("left", stamp, image)
        writer.write_frame("right", stamp + 3_000_000, image)  # the right camera 3 ms late
        writer.send(ActuatorCommand(stamp, 0.1 * (k % 2), 0.5, 0.0 if k < 8 else 1.0))
    # no close(): the run was cut off
    assert main(["recordings", "info", str(tmp_path / "run"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["closed"] is False and info["duration_s"] == 0.903
    assert info["cameras"]["left"]["frames"] == 10 and info["cameras"]["left"]["rate_hz"] == 10.0
    assert info["cameras"]["right"]["skew_to_left_ms"] == {"median": 3.0, "max": 3.0}
    assert info["commands"]["count"] == 10 and info["commands"]["braking_fraction"] == 0.2
    assert main(["recordings", "info", str(tmp_path / "run")]) == 0
    assert "NOT closed properly" in capsys.readouterr().out


def test_outputs_can_traffic_and_capture_stamps_round_trip_through_the_writer_thread(tmp_path):
    camera = PinholeCamera(100.0, 100.0, 31.5, 23.5, 64, 48)
    folder = tmp_path / "run"
    image = np.full((48, 64), 90, np.uint8)
    with RecordingWriter(folder, {"a": camera, "b": camera}, queue_frames=4, drop_when_full=False) as writer:
        for k in range(5):
            stamp = 1_000 + k * 50_000_000
            images = {"a": image} if k == 2 else {"a": image, "b": image}  # b delivered nothing once
            writer.write_frames(FrameSet(k, stamp, images, {"a": stamp - 2_000_000, "b": stamp + 1_000_000}))
            writer.write_outputs(stamp, {"pose": {"x_m": 0.5 * k, "status": "ok" if k else "bridged"},
                                         "lanes": {"steer_rad": -0.01 * k, "left_x_bottom_px": math.nan}})
            writer.write_can(stamp, 0x101, bytes([k, 255]))
        with pytest.raises(RecordingError, match="columns x_m, status"):
            writer.write_output("pose", 9, {"y_m": 1.0})
        with pytest.raises(RecordingError, match="topic"):
            writer.write_output("Bad Topic", 9, {"y_m": 1.0})
    reader = RecordingReader(folder)
    assert reader.output_topics() == ["lanes", "pose"]
    pose = reader.outputs("pose")
    assert [row["x_m"] for row in pose] == [0.0, 0.5, 1.0, 1.5, 2.0] and pose[0]["status"] == "bridged"
    assert math.isnan(float(reader.outputs("lanes")[0]["left_x_bottom_px"]))
    assert reader.can_frames()[3] == (1_000 + 150_000_000, "tx", 0x101, bytes([3, 255]))
    assert reader.manifest["missing_frames"] == {"a": 0, "b": 1}
    assert reader.capture_stamps("b")[0] == 1_000 + 1_000_000
    assert reader.frames("b")[0][0] == 1_000  # grouped under the set's time
    with pytest.raises(RecordingError, match="no output 'odometry'"):
        reader.outputs("odometry")


def test_a_live_recorder_drops_frames_it_cannot_keep_up_with_and_counts_them(tmp_path, monkeypatch):
    import threading

    camera = PinholeCamera(100.0, 100.0, 31.5, 23.5, 64, 48)
    gate = threading.Event()
    writer = RecordingWriter(tmp_path / "run", {"a": camera}, queue_frames=2, drop_when_full=True)
    original = writer._write_image

    def slow_disk(*args):
        gate.wait(5)
        original(*args)

    monkeypatch.setattr(writer, "_write_image", slow_disk)
    image = np.full((48, 64), 90, np.uint8)
    for k in range(10):  # the caller never waits: 1 frame being written, 2 queued, the rest dropped
        writer.write_frame("a", k, image)
    gate.set()
    writer.close()
    reader = RecordingReader(tmp_path / "run")
    written = len(reader.frames("a"))
    assert written + reader.manifest["dropped_frames"]["a"] == 10 and 2 <= written <= 3


def test_a_donkey_tub_imports_as_a_recording_and_exports_to_images_and_csv(tmp_path, capsys):
    import csv

    import cv2
    from tests.sensors.test_donkeycar import write_tub

    from kartpilot.cli.main import main

    tub = tmp_path / "tub"
    lines = [json.dumps({"_index": i, "_timestamp_ms": 1000 + 50 * i, "cam/image_array": f"{i}_cam.jpg",
                         "user/angle": [-0.5, 0.0, 1.0, 0.2][i], "user/throttle": [0.4, 0.4, -0.3, 0.0][i]})
             for i in range(4)]
    write_tub(tub, lines, deleted=[3])
    rng = np.random.default_rng(0)
    for i in range(4):
        cv2.imwrite(str(tub / "images" / f"{i}_cam.jpg"), rng.integers(0, 255, (120, 160, 3), np.uint8))
    assert main(["recordings", "import-tub", str(tub), "--out", str(tmp_path / "rec"), "--max-steer-deg", "20"]) == 0
    reader = RecordingReader(tmp_path / "rec")
    assert reader.closed and reader.cameras["center"].size_wh == (160, 120)
    assert reader.cameras["center"].fx_px == pytest.approx(80 / math.tan(math.radians(60)))
    commands = reader.commands()
    assert [c.stamp_ns for c in commands] == [1_000_000_000, 1_050_000_000, 1_100_000_000]
    assert commands[0].steer_rad == pytest.approx(0.5 * math.radians(20), abs=1e-6)  # Donkey's left is negative
    assert (commands[2].throttle, commands[2].brake) == (0.0, 0.3)
    assert [row["user_angle"] for row in reader.outputs("donkey")] == [-0.5, 0.0, 1.0]
    assert "guessed" in reader.manifest["metadata"]["intrinsics"]

    assert main(["recordings", "export", str(tmp_path / "rec"), "--out", str(tmp_path / "export")]) == 0
    with (tmp_path / "export" / "frames.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 3 and float(rows[2]["brake"]) == 0.3
    image = cv2.imread(str(tmp_path / "export" / rows[1]["center_image"]))
    np.testing.assert_array_equal(image, cv2.imread(str(reader.frames("center")[1][1])))
    assert main(["recordings", "export", str(tmp_path / "rec"), "--out", str(tmp_path / "export")]) == 2
    assert "not empty" in capsys.readouterr().err


def _recorded_sim(folder: Path, **popen: Any) -> subprocess.Popen:
    """``kartpilot sim --record folder`` as another process (the small kart on straight20, 10 Hz)."""
    command = [str(Path(sys.executable).with_name("kartpilot")), "sim", "--track", "straight20", "--vehicle",
               "rc-kart", "--cameras", "left", "--rate", "10", "--record", str(folder), "--no-progress"]
    return subprocess.Popen(command, stdout=subprocess.DEVNULL, **popen)


def _after_frames(process: subprocess.Popen, folder: Path, count: int) -> None:
    """Wait until the recording lists ``count`` frames; on the recording's contents, not on the clock."""
    frames = folder / "cameras" / "left" / "frames.csv"
    deadline = time.monotonic() + 300  # a bound for a broken run, not a measure of speed
    while time.monotonic() < deadline and process.poll() is None:
        if frames.is_file() and frames.read_text().count("\n") > count:
            break
        time.sleep(0.05)
    assert process.poll() is None, "the drive ended before it could be stopped"


def _truth_for_every_frame(reader: RecordingReader, at_least: int) -> None:
    kept = reader.frames("left")
    truth = reader.groundtruth()
    assert truth is not None and len(kept) >= at_least
    truth_ns = np.asarray(truth.stamps_s) * 1e9
    assert all(np.min(np.abs(truth_ns - stamp)) < 1e3 for stamp, _ in kept)


@pytest.mark.slow
def test_sigkill_at_ten_random_moments_leaves_recordings_that_open_with_their_ground_truth(tmp_path) -> None:
    """``kill -9`` during ``sim --record``, ten times, each at a random moment (after a random number of frames
    and a random part of a frame's period, so a write may be cut anywhere): every recording opens, not closed,
    with the ground truth of every frame it kept (the truth used to be written only on close). Two drives run at
    a time. Waits on the recordings' contents, not on the clock."""
    rng = random.Random(36)
    moments = [(tmp_path / f"killed-{k}", rng.randint(2, 25), rng.uniform(0.0, 0.1)) for k in range(10)]
    for runs in (moments[k:k + 2] for k in range(0, len(moments), 2)):
        processes = [_recorded_sim(folder, stderr=subprocess.DEVNULL) for folder, _, _ in runs]
        try:
            for process, (folder, frames, delay) in zip(processes, runs, strict=True):
                _after_frames(process, folder, frames)
                time.sleep(delay)
                os.kill(process.pid, signal.SIGKILL)
        finally:
            for process in processes:
                process.kill()
                process.wait()
        for folder, frames, _ in runs:
            reader = RecordingReader(folder)
            assert not reader.closed
            # every frame kept has its true pose (the truth may run ahead: frames still queued were lost)
            _truth_for_every_frame(reader, frames)


def test_sigterm_ends_a_recorded_drive_as_ctrl_c_does(tmp_path) -> None:
    """SIGTERM (a service manager's or a container's stop) during ``sim --record``: the command stops through
    the same clean-up as Ctrl-C, says so on one line, exits 143, and the recording is closed with the ground
    truth of every frame."""
    folder = tmp_path / "stopped"
    process = _recorded_sim(folder, stderr=subprocess.PIPE, text=True)
    try:
        _after_frames(process, folder, 12)
        os.kill(process.pid, signal.SIGTERM)
        _, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    print(err)
    assert process.returncode == 143 and "terminated" in err
    reader = RecordingReader(folder)
    assert reader.closed
    _truth_for_every_frame(reader, 12)


def test_a_file_size_limit_ends_a_recorded_drive_with_one_line_and_a_readable_recording(tmp_path) -> None:
    """A full disk, as a file size limit (RLIMIT_FSIZE) makes it: the first frame cannot be written. The drive
    stops (the kart is commanded to stop), says why on one line, and leaves a recording that opens, marked as not
    closed properly with the failure's reason."""
    import resource

    folder = tmp_path / "full"

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, 100_000))

    command = [str(Path(sys.executable).with_name("kartpilot")), "sim", "--track", "straight20", "--vehicle",
               "rc-kart", "--cameras", "left", "--rate", "10", "--record", str(folder), "--no-progress"]
    done = subprocess.run(command, capture_output=True, text=True, preexec_fn=limit, timeout=300)
    err = done.stderr.strip()
    print(err)
    assert done.returncode == 1
    assert len(err.splitlines()) == 1 and err.startswith("kartpilot: error:") and "File too large" in err
    reader = RecordingReader(folder)
    assert not reader.closed and "File too large" in reader.manifest["write_error"]
    assert reader.frames("left") == [] and reader.commands()  # what was written is there

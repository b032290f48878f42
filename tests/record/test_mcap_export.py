"""MCAP export, read back with the mcap library's own reader: schemas, counts, time stamps and bytes."""

import base64
import json

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from tests.record.test_recording_format import _cameras

from kartpilot.cli.main import main
from kartpilot.core.types import ActuatorCommand
from kartpilot.record.mcap_export import export_mcap
from kartpilot.record.recording import RecordingReader, RecordingWriter
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource

ODD_NS = 1_700_000_000_123_456_789  # a stamp whose nanoseconds a float in seconds would lose


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    source = SyntheticStereoSource(SyntheticStereoConfig(frames=4, width_px=160, height_px=96, focal_px=100))
    folder = tmp_path_factory.mktemp("mcap") / "run"
    with RecordingWriter(folder, _cameras(source), stereo_pair=("left", "right")) as writer:
        for frame in source:
            stamp = ODD_NS + frame.stamp_ns
            writer.write_frame("left", stamp, frame.left)
            writer.write_frame("right", stamp, frame.right)
            writer.write_command(ActuatorCommand(stamp, 0.01 * frame.index, 0.3, 0.0))
            writer.write_output("lanes", stamp, {"confidence": 0.5, "left_x_bottom_px": float("nan"), "rule": "hold"})
            writer.write_can(stamp, 0x220, bytes([1, 2, 3, frame.index]))
        writer.write_groundtruth(source.ground_truth())
    return folder


def test_an_mcap_export_reads_back_with_foxglove_schemas_exact_stamps_and_the_same_image_bytes(recording, tmp_path):
    out = tmp_path / "run.mcap"
    counts = export_mcap(recording, out)
    reader = RecordingReader(recording)
    with out.open("rb") as handle:
        mcap = make_reader(handle)
        summary = mcap.get_summary()
        assert summary is not None
        schemas = {s.name for s in summary.schemas.values()}
        assert {"foxglove.CompressedImage", "foxglove.CameraCalibration", "foxglove.FrameTransform",
                "foxglove.PoseInFrame"} <= schemas
        read: dict[str, list] = {}
        for schema, channel, message in mcap.iter_messages(log_time_order=True):
            assert schema is not None and channel.message_encoding == "json"
            read.setdefault(channel.topic, []).append((schema.name, message, json.loads(message.data)))
    assert {topic: len(rows) for topic, rows in read.items()} == counts
    assert counts["/left/image"] == counts["/right/image"] == 4 and counts["/commands"] == 4
    assert counts["/can"] == 4 and counts["/outputs/lanes"] == 4 and counts["/left/calibration"] == 1
    assert counts["/groundtruth"] == len(reader.groundtruth().poses)
    for (stamp, path), (name, message, body) in zip(reader.frames("left"), read["/left/image"], strict=True):
        assert name == "foxglove.CompressedImage" and message.log_time == stamp
        assert body["timestamp"]["sec"] * 1_000_000_000 + body["timestamp"]["nsec"] == stamp  # to the nanosecond
        assert base64.b64decode(body["data"]) == path.read_bytes()  # the recording's own PNG, not re-encoded
        decoded = cv2.imdecode(np.frombuffer(base64.b64decode(body["data"]), np.uint8), cv2.IMREAD_UNCHANGED)
        assert decoded.shape[:2] == (96, 160) and body["format"] == "png"
    calibration = read["/right/calibration"][0][2]
    assert calibration["K"][0] == pytest.approx(100.0) and calibration["width"] == 160
    mounts = {b["child_frame_id"]: b for _, _, b in read["/tf"] if b["parent_frame_id"] == "base_link"}
    baseline = reader.cameras["right"].pose_body_cam_array[0, 3]
    assert mounts["right"]["translation"]["x"] == pytest.approx(baseline)
    lanes = read["/outputs/lanes"][0][2]
    assert lanes["left_x_bottom_px"] is None and lanes["rule"] == "hold"  # NaN is JSON null
    assert base64.b64decode(read["/can"][3][2]["data"]) == bytes([1, 2, 3, 3]) and read["/can"][0][2]["id"] == 0x220


def test_the_cli_exports_whole_or_not_at_all(recording, tmp_path, capsys):
    out = tmp_path / "drive.mcap"
    assert main(["recordings", "export", str(recording), "--format", "mcap", "--out", str(out)]) == 0
    assert "Foxglove" in capsys.readouterr().out and out.stat().st_size > 0
    assert main(["recordings", "export", str(recording), "--format", "mcap", "--out", str(tmp_path / "x.mcap"),
                 "--cameras", "centre"]) != 0
    assert "no camera 'centre'" in capsys.readouterr().err
    assert not (tmp_path / "x.mcap").exists() and not list(tmp_path.glob(".*partial"))
    # a usage error, as for the folder format
    assert main(["recordings", "export", str(recording), "--format", "mcap", "--out", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err

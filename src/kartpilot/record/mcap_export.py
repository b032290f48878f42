"""A recording as one MCAP file that Foxglove opens as it is.

Messages are JSON-encoded with Foxglove's well-known schema names, so Foxglove's image, 3D and plot panels
understand them without a plugin:

* ``/<camera>/image``: ``foxglove.CompressedImage``: the recording's own PNG bytes (lossless, not decoded);
* ``/<camera>/calibration``: ``foxglove.CameraCalibration`` at the camera's first frame (K, D, R, P);
* ``/tf``: ``foxglove.FrameTransform``: each camera's mount on the kart (``base_link`` to ``<camera>``) at
  the start, and the kart in the world (``world`` to ``base_link``) at each ground-truth pose;
* ``/groundtruth``: ``foxglove.PoseInFrame`` in ``world``;
* ``/commands``: the actuator commands (``kartpilot.ActuatorCommand``: steer_rad, throttle, brake);
* ``/can``: the CAN frames on the bus (``kartpilot.CanFrame``: id, data, direction);
* ``/outputs/<topic>``: each pipeline output topic, its values as they were recorded;
* ``/<lidar>/scan``: ``foxglove.LaserScan``, each sweep of a LiDAR in its own frame (its mount on ``/tf``), a beam
  without a return as null (JSON has no NaN).

Every message's log time is the recording's time stamp in nanoseconds, and the ``timestamp`` field carries
the same instant split into seconds and nanoseconds: nothing is rounded. Chunks are zstd-compressed. The
file is written whole or not at all.
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from mcap.writer import CompressionType, Writer

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import RecordingError
from kartpilot.core.files import read_file_bytes, write_atomic
from kartpilot.core.geometry import quaternion_xyzw_from_pose
from kartpilot.record.recording import RecordingReader

__all__ = ["SCHEMAS", "export_mcap"]

_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_VECTOR = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUATERNION = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_BYTES = {"type": "string", "contentEncoding": "base64"}
_NUMBERS = {"type": "array", "items": {"type": "number"}}

SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.CompressedImage": {"timestamp": _TIME, "frame_id": {"type": "string"}, "data": _BYTES,
                                 "format": {"type": "string"}},
    "foxglove.CameraCalibration": {"timestamp": _TIME, "frame_id": {"type": "string"},
                                   "width": {"type": "integer"}, "height": {"type": "integer"},
                                   "distortion_model": {"type": "string"}, "D": _NUMBERS, "K": _NUMBERS,
                                   "R": _NUMBERS, "P": _NUMBERS},
    "foxglove.FrameTransform": {"timestamp": _TIME, "parent_frame_id": {"type": "string"},
                                "child_frame_id": {"type": "string"}, "translation": _VECTOR,
                                "rotation": _QUATERNION},
    "foxglove.PoseInFrame": {"timestamp": _TIME, "frame_id": {"type": "string"},
                             "pose": {"type": "object", "properties": {"position": _VECTOR,
                                                                       "orientation": _QUATERNION}}},
    "kartpilot.ActuatorCommand": {"timestamp": _TIME, "steer_rad": {"type": "number"},
                                  "throttle": {"type": "number"}, "brake": {"type": "number"}},
    "kartpilot.CanFrame": {"timestamp": _TIME, "id": {"type": "integer"}, "data": _BYTES,
                           "direction": {"type": "string"}},
    "kartpilot.Outputs": {"timestamp": _TIME},
    "foxglove.LaserScan": {"timestamp": _TIME, "frame_id": {"type": "string"},
                           "pose": {"type": "object", "properties": {"position": _VECTOR, "orientation": _QUATERNION}},
                           "start_angle": {"type": "number"}, "end_angle": {"type": "number"},
                           "ranges": {"type": "array", "items": {"type": ["number", "null"]}}, "intensities": _NUMBERS},
}


def _time(stamp_ns: int) -> dict[str, int]:
    return {"sec": stamp_ns // 1_000_000_000, "nsec": stamp_ns % 1_000_000_000}


def _transform(stamp_ns: int, parent: str, child: str, pose: np.ndarray) -> dict[str, Any]:
    t = pose[:3, 3]
    return {"timestamp": _time(stamp_ns), "parent_frame_id": parent, "child_frame_id": child,
            "translation": {"x": float(t[0]), "y": float(t[1]), "z": float(t[2])},
            "rotation": dict(zip("xyzw", (float(v) for v in quaternion_xyzw_from_pose(pose)), strict=True))}


def _calibration(stamp_ns: int, name: str, camera: PinholeCamera) -> dict[str, Any]:
    return {"timestamp": _time(stamp_ns), "frame_id": name, "width": camera.width_px, "height": camera.height_px,
            **camera.ros_calibration()}


def _clean(value: Any) -> Any:
    """JSON has no NaN: a missing number is null."""
    return None if isinstance(value, float) and not math.isfinite(value) else value


def export_mcap(folder: str | Path, out: str | Path, cameras: Sequence[str] | None = None) -> dict[str, int]:
    """Write the recording at ``folder`` as the MCAP file ``out``; returns the message count per topic."""
    reader = RecordingReader(folder)
    names = list(cameras) if cameras else list(reader.cameras)
    unknown = [n for n in names if n not in reader.cameras]
    if unknown:
        raise RecordingError(f"the recording has no camera {unknown[0]!r} (it has {', '.join(reader.cameras)})")
    messages: list[tuple[int, str, str, dict[str, Any]]] = []  # (stamp_ns, topic, schema, message)
    first_ns = min([s for n in names for s, _ in reader.frames(n)[:1]] or [0])
    for name in names:
        camera = reader.cameras[name]
        frames = reader.frames(name)
        messages.append((first_ns, "/tf", "foxglove.FrameTransform",
                         _transform(first_ns, "base_link", name, camera.pose_body_cam_array)))
        if frames:
            messages.append((frames[0][0], f"/{name}/calibration", "foxglove.CameraCalibration",
                             _calibration(frames[0][0], name, camera)))
        for stamp, path in frames:
            messages.append((stamp, f"/{name}/image", "foxglove.CompressedImage",
                             {"timestamp": _time(stamp), "frame_id": name, "format": path.suffix.lstrip(".").lower(),
                              "data": base64.b64encode(read_file_bytes(path)).decode("ascii")}))
    for name, mount in reader.lidars.items():
        messages.append((first_ns, "/tf", "foxglove.FrameTransform",
                         _transform(first_ns, "base_link", name, mount.pose_body_lidar())))
        for scan in reader.scans(name):
            angles = scan.angles_rad()
            messages.append((scan.stamp_ns, f"/{name}/scan", "foxglove.LaserScan", {
                "timestamp": _time(scan.stamp_ns), "frame_id": name,
                "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                         "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
                "start_angle": float(angles[0]) if len(angles) else 0.0,
                "end_angle": float(angles[-1]) if len(angles) else 0.0,
                "ranges": [_clean(float(r)) for r in scan.ranges_m],
                "intensities": [float(v) for v in scan.intensities]}))
    truth = reader.body_poses()
    if truth is not None:
        for stamp_s, pose in zip(truth.stamps_s, truth.poses, strict=True):
            stamp = round(float(stamp_s) * 1e9)  # the ground-truth file keeps seconds
            transform = _transform(stamp, "world", "base_link", pose)
            messages.append((stamp, "/tf", "foxglove.FrameTransform", transform))
            messages.append((stamp, "/groundtruth", "foxglove.PoseInFrame", {
                "timestamp": _time(stamp), "frame_id": "world",
                "pose": {"position": transform["translation"], "orientation": transform["rotation"]}}))
    for command in reader.commands():
        messages.append((command.stamp_ns, "/commands", "kartpilot.ActuatorCommand",
                         {"timestamp": _time(command.stamp_ns), "steer_rad": command.steer_rad,
                          "throttle": command.throttle, "brake": command.brake}))
    for stamp, direction, arbitration_id, data in reader.can_frames():
        messages.append((stamp, "/can", "kartpilot.CanFrame",
                         {"timestamp": _time(stamp), "id": arbitration_id, "direction": direction,
                          "data": base64.b64encode(data).decode("ascii")}))
    for topic in reader.output_topics():
        for row in reader.outputs(topic):
            stamp = int(row["stamp_ns"])
            values = {k: _clean(v) for k, v in row.items() if k != "stamp_ns"}
            messages.append((stamp, f"/outputs/{topic}", "kartpilot.Outputs", {"timestamp": _time(stamp), **values}))
    messages.sort(key=lambda m: m[0])
    counts: dict[str, int] = {}

    def write(handle: BinaryIO) -> None:
        writer = Writer(handle, compression=CompressionType.ZSTD)
        writer.start(profile="", library="kartpilot")
        schema_ids = {name: writer.register_schema(name=name, encoding="jsonschema", data=json.dumps(
            {"type": "object", "title": name, "properties": props}).encode()) for name, props in SCHEMAS.items()}
        channels: dict[str, int] = {}
        for stamp, topic, schema, message in messages:
            if topic not in channels:
                channels[topic] = writer.register_channel(topic=topic, message_encoding="json",
                                                          schema_id=schema_ids[schema])
            writer.add_message(channel_id=channels[topic], log_time=stamp, publish_time=stamp,
                               data=json.dumps(message, allow_nan=False).encode())
            counts[topic] = counts.get(topic, 0) + 1
        writer.finish()

    write_atomic(out, write)
    return counts

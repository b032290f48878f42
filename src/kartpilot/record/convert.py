"""Data in and out of the recording format, so it moves between tools.

* :func:`import_donkey_tub`: a Donkey Car tub as a recording: its images as camera ``center``,
  the human's ``user/angle`` and ``user/throttle`` as commands, and both raw values kept as the
  ``donkey`` output. A tub has no calibration: give the camera (from a rig file) or accept one
  guessed from a horizontal field of view, which the manifest says.
* :func:`import_stereo_source`: a stereo sequence (KITTI, EuRoC) as a recording: its rectified pair as
  cameras ``left`` and ``right`` on the kart at a given mount, and its ground truth, so the place
  database, the one-camera pipeline and replay run on it as on the kart's own drives.
* :func:`export_recording`: a recording as a folder of images plus one CSV row per set, with the
  command in force at that set (what image-to-steering trainers and spreadsheets read).
"""

from __future__ import annotations

import csv
import math
import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import DataError, RecordingError
from kartpilot.core.geometry import Array, mount_pose
from kartpilot.core.images import read_image
from kartpilot.core.types import ActuatorCommand
from kartpilot.record.recording import RecordingReader, RecordingWriter
from kartpilot.sensors.base import StereoSource
from kartpilot.sensors.donkeycar import DonkeyTub

__all__ = ["export_recording", "guessed_camera", "import_donkey_tub", "import_stereo_source"]


def guessed_camera(width_px: int, height_px: int, horizontal_fov_deg: float, height_m: float = 0.15) -> PinholeCamera:
    """A distortion-free camera with this field of view, looking ahead ``height_m`` above the ground."""
    if not 10.0 <= horizontal_fov_deg < 179.0:
        raise DataError(f"a horizontal field of view of {horizontal_fov_deg} deg is not a camera's")
    focal = (width_px / 2.0) / math.tan(math.radians(horizontal_fov_deg) / 2.0)
    pose = mount_pose(z_m=height_m)
    return PinholeCamera(focal, focal, (width_px - 1) / 2.0, (height_px - 1) / 2.0, width_px, height_px,
                         pose_body_cam=tuple(tuple(float(v) for v in row) for row in pose))


def import_donkey_tub(tub_folder: str | Path, out: str | Path, camera: PinholeCamera | None = None,
                      horizontal_fov_deg: float = 120.0, max_steer_rad: float = math.radians(25.0)) -> int:
    """Write the tub at ``tub_folder`` as a recording at ``out``; returns the number of frames.

    ``user/angle`` (-1 left to 1 right) becomes ``steer_rad = -angle * max_steer_rad`` (positive left);
    a positive ``user/throttle`` is the throttle, a negative one (reverse on a Donkey car) the brake.
    """
    tub = DonkeyTub(tub_folder)
    first = read_image(tub.records[0].image_path)
    height, width = first.shape[:2]
    metadata: dict[str, object] = {"source": "donkeycar tub", "imported_from": str(Path(tub_folder).resolve()),
                                   "max_steer_rad": max_steer_rad}
    if camera is None:
        camera = guessed_camera(width, height, horizontal_fov_deg)
        metadata["intrinsics"] = f"guessed from a {horizontal_fov_deg:g} deg horizontal field of view, no distortion"
    elif camera.size_wh != (width, height):
        raise DataError(f"the tub's images are {width}x{height}, the camera given is "
                        f"{camera.width_px}x{camera.height_px}")
    with RecordingWriter(out, {"center": camera}, metadata=metadata) as writer:
        for record, frames in zip(tub.records, tub.frames(), strict=True):
            image = frames.images["center"]
            if image.shape[:2] != (height, width):
                raise DataError(f"{record.image_path} is {image.shape[1]}x{image.shape[0]}, the tub's first image "
                                f"{width}x{height}")
            writer.write_frame("center", frames.stamp_ns, image)
            writer.write_command(ActuatorCommand(frames.stamp_ns, -record.angle * max_steer_rad,
                                                 float(np.clip(record.throttle, 0.0, 1.0)),
                                                 float(np.clip(-record.throttle, 0.0, 1.0))))
            writer.write_output("donkey", frames.stamp_ns, {"index": record.index, "user_angle": record.angle,
                                                             "user_throttle": record.throttle})
    return len(tub)


def import_stereo_source(source: StereoSource, out: str | Path, pose_body_left: Array) -> int:
    """Write ``source`` as a recording at ``out``, the left camera at ``pose_body_left`` on the body (the right
    one beside it, the baseline to its right); returns the number of frames written. A frame that cannot be
    read is left out."""
    left = source.rig.camera.on_body(pose_body_left)
    right_on_left = np.eye(4)
    right_on_left[0, 3] = source.rig.baseline_m
    right = source.rig.camera.on_body(pose_body_left @ right_on_left)
    truth = source.ground_truth()
    metadata: dict[str, object] = {"source": source.name, "groundtruth_camera": "left",
                                   "mount": "given on import (the source has no body frame)"}
    written = 0
    with RecordingWriter(out, {"left": left, "right": right}, stereo_pair=("left", "right"),
                         metadata=metadata) as writer:
        for frames in source.frame_sets():
            if isinstance(frames, int):
                continue
            writer.write_frames(frames)
            written += 1
        if truth is not None:
            writer.write_groundtruth(truth)
    if written == 0:
        raise DataError(f"none of the {len(source)} frames of {source.name} could be read")
    return written


def export_recording(folder: str | Path, out: str | Path, cameras: Sequence[str] | None = None) -> int:
    """Copy the recording's images to ``out/images/<camera>/`` and write ``out/frames.csv``: one row per set
    with each camera's image (empty where it missed the set) and the command in force (the last one sent at
    or before the set's time). Returns the number of rows."""
    reader = RecordingReader(folder)
    names = list(cameras) if cameras else list(reader.cameras)
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise RecordingError(f"export folder {out} exists and is not empty")
    sets: dict[int, dict[str, str]] = {}
    for name in names:
        target = out / "images" / name
        target.mkdir(parents=True, exist_ok=True)
        for stamp, path in reader.frames(name):
            shutil.copy2(path, target / path.name)
            sets.setdefault(stamp, {})[name] = f"images/{name}/{path.name}"
    commands = reader.commands()
    command_stamps = np.array([c.stamp_ns for c in commands], np.int64)
    with (out / "frames.csv").open("w", newline="") as handle:
        rows = csv.writer(handle)
        rows.writerow(["index", "stamp_ns", *(f"{n}_image" for n in names), "steer_rad", "throttle", "brake"])
        for index, stamp in enumerate(sorted(sets)):
            k = int(np.searchsorted(command_stamps, stamp, side="right")) - 1
            command = [f"{commands[k].steer_rad:.6f}", f"{commands[k].throttle:.6f}",
                       f"{commands[k].brake:.6f}"] if k >= 0 else ["", "", ""]
            rows.writerow([index, stamp, *(sets[stamp].get(n, "") for n in names), *command])
    return len(sets)

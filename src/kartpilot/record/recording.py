"""kartpilot's recording format: one self-describing folder per run.

Layout (format version 1)::

    NAME/
      manifest.json        format, version, rig (cameras with intrinsics, distortion,
                           resolution and pose on the kart), stereo pair names,
                           counts, and whether the recording was closed properly
      cameras/<cam>/frames.csv   index,stamp_ns,file  (one line per frame, flushed)
      cameras/<cam>/<stamp_ns>.png
      commands.csv         stamp_ns,steer_rad,throttle,brake
      groundtruth.tum      left camera poses in TUM format, when known

The manifest is written first with ``"closed": false`` and rewritten on close,
so a recording cut off by a crash still opens and says it was not closed.
Frame and command lines are flushed as they are written.
"""

from __future__ import annotations

import csv
import json
import os
import queue
import threading
from dataclasses import asdict
from pathlib import Path
from typing import IO, Any

import cv2
import numpy as np

from kartpilot.calibration.rectify import StereoRectification, rectify_stereo
from kartpilot.core.camera import PinholeCamera, StereoRig
from kartpilot.core.errors import CalibrationError, RecordingError
from kartpilot.core.geometry import Array, invert_pose
from kartpilot.core.trajectory import Trajectory, read_tum, write_tum
from kartpilot.core.types import ActuatorCommand, FrameSet, Image, StereoFrame
from kartpilot.sensors.base import StereoSource, read_gray

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "RecordingReader",
    "RecordingStereoSource",
    "RecordingWriter",
]

FORMAT_NAME = "kartpilot-recording"
FORMAT_VERSION = 1
COMMAND_COLUMNS = ("stamp_ns", "steer_rad", "throttle", "brake")
_PNG_FAST = [cv2.IMWRITE_PNG_COMPRESSION, 1]  # lossless; level 1 writes about 3x faster than the default


def _camera_to_json(camera: PinholeCamera) -> dict[str, Any]:
    data = asdict(camera)
    data["distortion"] = list(camera.distortion)
    data["pose_body_cam"] = [list(row) for row in camera.pose_body_cam]
    return data


def _camera_from_json(name: str, data: dict[str, Any]) -> PinholeCamera:
    try:
        return PinholeCamera(
            float(data["fx_px"]), float(data["fy_px"]), float(data["cx_px"]), float(data["cy_px"]),
            int(data["width_px"]), int(data["height_px"]), tuple(float(d) for d in data.get("distortion", ())),
            tuple(tuple(float(v) for v in row) for row in data.get("pose_body_cam", np.eye(4).tolist())),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise CalibrationError(f"camera {name!r} in the manifest is malformed ({exc})") from exc


class RecordingWriter:
    """Writes a recording folder. Use as a context manager; ``close`` marks it complete.

    With ``queue_frames > 0``, images are encoded and written by one background thread per camera
    (PNG encoding releases the GIL) through a bounded queue, so recording does not hold up the
    caller. When the queue is full the frame is dropped and counted (``drop_when_full``, for a live
    loop that must not wait) or the caller waits (for the simulator, whose time does not run away).
    """

    def __init__(self, folder: str | Path, cameras: dict[str, PinholeCamera],
                 stereo_pair: tuple[str, str] | None = None, metadata: dict[str, Any] | None = None,
                 overwrite: bool = False, queue_frames: int = 0, drop_when_full: bool = True) -> None:
        self.folder = Path(folder)
        if self.folder.exists() and any(self.folder.iterdir()) and not overwrite:
            raise RecordingError(f"recording folder {self.folder} exists and is not empty")
        if stereo_pair and not set(stereo_pair) <= set(cameras):
            raise RecordingError(f"stereo pair {stereo_pair} names unknown cameras")
        self.cameras = cameras
        self.stereo_pair = stereo_pair
        self.metadata = dict(metadata or {})
        self.frame_counts = dict.fromkeys(cameras, 0)
        self.dropped_frames = 0
        self.command_count = 0
        self._frame_files: dict[str, IO[str]] = {}
        for name in cameras:
            camera_dir = self.folder / "cameras" / name
            camera_dir.mkdir(parents=True, exist_ok=True)
            handle = (camera_dir / "frames.csv").open("w", newline="")
            handle.write("index,stamp_ns,file\n")
            self._frame_files[name] = handle
        self._commands = (self.folder / "commands.csv").open("w", newline="")
        self._commands.write(",".join(COMMAND_COLUMNS) + "\n")
        self._closed = False
        self._drop_when_full = drop_when_full
        self._queues: dict[str, queue.Queue[tuple[str, int, Image] | None]] = {}
        self._threads: list[threading.Thread] = []
        self._error: BaseException | None = None
        if queue_frames > 0:
            for name in cameras:
                self._queues[name] = queue.Queue(maxsize=queue_frames)
                thread = threading.Thread(target=self._drain, args=(self._queues[name],),
                                          name=f"recording-{name}", daemon=True)
                thread.start()
                self._threads.append(thread)
        self._write_manifest(closed=False)

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _write_manifest(self, closed: bool) -> None:
        manifest = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "closed": closed,
            "cameras": {name: _camera_to_json(cam) for name, cam in self.cameras.items()},
            "stereo_pair": list(self.stereo_pair) if self.stereo_pair else None,
            "frame_counts": self.frame_counts,
            "dropped_frames": self.dropped_frames,
            "command_count": self.command_count,
            "has_groundtruth": (self.folder / "groundtruth.tum").is_file(),
            "metadata": self.metadata,
        }
        temporary = self.folder / "manifest.json.tmp"
        temporary.write_text(json.dumps(manifest, indent=2))
        os.replace(temporary, self.folder / "manifest.json")  # atomic: never a half-written manifest

    def write_frame(self, camera: str, stamp_ns: int, image: Image) -> None:
        if self._closed:
            raise RecordingError("the recording is closed")
        if camera not in self._frame_files:
            raise RecordingError(f"unknown camera {camera!r}")
        if self._error is not None:
            raise RecordingError(f"the recording's writer failed: {self._error}") from self._error
        if not self._queues:
            self._write_image(camera, stamp_ns, image)
            return
        try:
            self._queues[camera].put((camera, stamp_ns, image), block=not self._drop_when_full)
        except queue.Full:
            self.dropped_frames += 1

    def _drain(self, jobs: queue.Queue[tuple[str, int, Image] | None]) -> None:
        while (item := jobs.get()) is not None:
            try:
                self._write_image(*item)
            except BaseException as exc:
                self._error = exc

    def _write_image(self, camera: str, stamp_ns: int, image: Image) -> None:
        name = f"{stamp_ns}.png"
        path = self.folder / "cameras" / camera / name
        if not cv2.imwrite(str(path), image, _PNG_FAST):
            raise RecordingError(f"cannot write {path}")
        handle = self._frame_files[camera]
        handle.write(f"{self.frame_counts[camera]},{stamp_ns},{name}\n")
        handle.flush()
        self.frame_counts[camera] += 1

    def write_frames(self, frames: FrameSet) -> None:
        """Frame sink: write every image of a synchronised set under its camera's name."""
        for camera, image in frames.images.items():
            self.write_frame(camera, frames.stamp_ns, image)

    def send(self, command: ActuatorCommand) -> None:
        """Command sink: the recorder takes commands like any actuator would."""
        self.write_command(command)

    def write_command(self, command: ActuatorCommand) -> None:
        self._commands.write(f"{command.stamp_ns},{command.steer_rad:.6f},{command.throttle:.6f},{command.brake:.6f}\n")
        self._commands.flush()
        self.command_count += 1

    def write_groundtruth(self, trajectory: Trajectory) -> None:
        write_tum(self.folder / "groundtruth.tum", trajectory)

    def count_dropped(self, frames: int = 1) -> None:
        self.dropped_frames += frames

    def close(self) -> None:
        if self._closed:
            return
        for jobs in self._queues.values():
            jobs.put(None)  # after every queued frame: nothing queued is lost
        for thread in self._threads:
            thread.join()
        for handle in self._frame_files.values():
            handle.close()
        self._commands.close()
        self._closed = True
        self._write_manifest(closed=True)


class RecordingReader:
    """Reads a recording folder written by :class:`RecordingWriter` (or cut off mid-run)."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        manifest_path = self.folder / "manifest.json"
        if not manifest_path.is_file():
            raise RecordingError(f"{self.folder} is not a kartpilot recording (no manifest.json)")
        try:
            manifest = json.loads(manifest_path.read_text())
        except json.JSONDecodeError as exc:
            raise RecordingError(f"{manifest_path} is not valid JSON: {exc}") from exc
        if manifest.get("format") != FORMAT_NAME:
            raise RecordingError(f"{manifest_path}: format is {manifest.get('format')!r}, not {FORMAT_NAME!r}")
        if int(manifest.get("version", 0)) > FORMAT_VERSION:
            raise RecordingError(
                f"{manifest_path}: format version {manifest['version']} is newer than this kartpilot "
                f"reads ({FORMAT_VERSION})")
        self.manifest: dict[str, Any] = manifest
        self.closed = bool(manifest.get("closed", False))
        self.cameras = {name: _camera_from_json(name, data) for name, data in manifest["cameras"].items()}
        pair = manifest.get("stereo_pair")
        self.stereo_pair: tuple[str, str] | None = (pair[0], pair[1]) if pair else None

    def frames(self, camera: str) -> list[tuple[int, Path]]:
        """(stamp_ns, image path) of every complete frame of a camera, in order."""
        if camera not in self.cameras:
            raise RecordingError(f"recording has no camera {camera!r} (has {', '.join(self.cameras)})")
        csv_path = self.folder / "cameras" / camera / "frames.csv"
        if not csv_path.is_file():
            raise RecordingError(f"missing frame list {csv_path}")
        rows = []
        with csv_path.open(newline="") as handle:
            for row in csv.DictReader(handle):
                try:
                    path = csv_path.parent / row["file"]
                    stamp = int(row["stamp_ns"])
                except (KeyError, TypeError, ValueError):
                    continue  # a line cut off by a crash
                if path.is_file():
                    rows.append((stamp, path))
        return rows

    def commands(self) -> list[ActuatorCommand]:
        path = self.folder / "commands.csv"
        if not path.is_file():
            return []
        result = []
        with path.open(newline="") as handle:
            for row in csv.DictReader(handle):
                try:
                    result.append(ActuatorCommand(int(row["stamp_ns"]), float(row["steer_rad"]),
                                                  float(row["throttle"]), float(row["brake"])))
                except (KeyError, TypeError, ValueError):
                    continue
        return result

    def groundtruth(self) -> Trajectory | None:
        path = self.folder / "groundtruth.tum"
        return read_tum(path) if path.is_file() else None


class RecordingStereoSource(StereoSource):
    """The stereo pair of a recording, rectified from the manifest's calibration when needed."""

    def __init__(self, folder: str | Path) -> None:
        self.reader = RecordingReader(folder)
        if self.reader.stereo_pair is None:
            raise RecordingError(f"recording {self.reader.folder} names no stereo pair")
        left_name, right_name = self.reader.stereo_pair
        self.name = f"recording-{self.reader.folder.name}"
        left_cam, right_cam = self.reader.cameras[left_name], self.reader.cameras[right_name]
        pose_right_left = invert_pose(right_cam.pose_body_cam_array) @ left_cam.pose_body_cam_array
        self._rectification: StereoRectification | None = None
        if left_cam.distortion or right_cam.distortion or not np.allclose(pose_right_left[:3, :3], np.eye(3)):
            self._rectification = rectify_stereo(left_cam, right_cam, pose_right_left)
            self._rig = self._rectification.rig
        else:
            if left_cam.size_wh != right_cam.size_wh or not np.allclose(left_cam.matrix, right_cam.matrix, atol=1e-6):
                raise CalibrationError("unrectified stereo cameras with different intrinsics need a rectification")
            self._rig = StereoRig(left_cam, float(-pose_right_left[0, 3]))
        right_frames = dict(self.reader.frames(right_name))
        self._pairs = [(stamp, path, right_frames[stamp]) for stamp, path in self.reader.frames(left_name)
                       if stamp in right_frames]
        if not self._pairs:
            raise RecordingError(f"recording {self.reader.folder} has no complete stereo pair")

    @property
    def rig(self) -> StereoRig:
        return self._rig

    @property
    def pose_body_left(self) -> Array:
        """The (rectified) left camera's pose on the kart, from the recording's rig."""
        assert self.reader.stereo_pair is not None
        pose = self.reader.cameras[self.reader.stereo_pair[0]].pose_body_cam_array
        if self._rectification is None:
            return pose
        rect_raw = np.eye(4)
        rect_raw[:3, :3] = self._rectification.rotation_rect_left.T  # rectified axes in the raw camera frame
        return pose @ rect_raw

    def __len__(self) -> int:
        return len(self._pairs)

    def stamp_ns(self, index: int) -> int:
        return self._pairs[index][0]

    def frame(self, index: int) -> StereoFrame:
        stamp, left_path, right_path = self._pairs[index]
        left, right = read_gray(left_path), read_gray(right_path)
        if self._rectification is not None:
            left, right = self._rectification.rectify(left, right)
        return StereoFrame(index, stamp, left, right)

    def ground_truth(self) -> Trajectory | None:
        return self.reader.groundtruth()

"""kartpilot's recording format: one self-describing folder per run.

Layout (format version 1)::

    NAME/
      manifest.json        format, version, rig (cameras with intrinsics, distortion,
                           resolution and pose on the kart), stereo pair names,
                           counts, and whether the recording was closed properly
      cameras/<cam>/frames.csv   index,stamp_ns,file,capture_ns  (one line per frame, flushed;
                           stamp_ns is the synchronised set's time, capture_ns the camera's own)
      cameras/<cam>/<stamp_ns>.png   (or .jpg: live recordings of several cameras, see below)
      commands.csv         stamp_ns,steer_rad,throttle,brake
      outputs/<topic>.csv  the pipeline's own outputs (poses, lane observations, diagnostics):
                           stamp_ns and one column per named value
      can.csv              stamp_ns,direction,id,data  (CAN traffic, when there is a bus)
      groundtruth.tum      left camera poses in TUM format, when known
      lidar/<name>/scans.csv   a planar LiDAR's sweeps, one line each (flushed like every line):
                           stamp_ns, angle_min_rad, angle_increment_rad, time_increment_s, scan_time_s,
                           range_min_m, range_max_m, then ranges_m and intensities, each its beams'
                           values separated by spaces (``nan``: no return); its mount in the manifest

The manifest is written first with ``"closed": false``, refreshed every second (its counts)
and rewritten on close, so a recording cut off by a crash still opens and says it was not closed.
Every line is flushed as it is written. ``outputs/`` and ``can.csv`` are optional:
a recording without them reads as one with none.
"""

from __future__ import annotations

import logging
import math
import queue
import re
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import asdict
from pathlib import Path
from typing import IO, Any

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.calibration.rectify import stereo_setup
from kartpilot.core.camera import PinholeCamera, StereoRig, camera_from_dict, camera_to_dict
from kartpilot.core.errors import DataError, KartpilotError, RecordingError
from kartpilot.core.files import (
    csv_records,
    free_bytes,
    is_torn_last_line,
    iter_csv_file,
    read_json_file,
    read_text_file,
    write_json_atomic,
)
from kartpilot.core.geometry import Array, invert_pose, quaternion_xyzw_from_pose
from kartpilot.core.trajectory import Trajectory, read_tum, write_tum
from kartpilot.core.types import ActuatorCommand, FrameSet, Image, LaserScan, LidarMount, StereoFrame
from kartpilot.sensors.base import StereoSource, read_gray
from kartpilot.sensors.capture import nearest_within

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "POSE_GAP_S",
    "RecordingReader",
    "RecordingStereoSource",
    "RecordingWriter",
]

log = logging.getLogger(__name__)

POSE_GAP_S = 0.05  # a frame takes the pose nearest its time within this (posed_frames, pose_indices)

FORMAT_NAME = "kartpilot-recording"
FORMAT_VERSION = 1
COMMAND_COLUMNS = ("stamp_ns", "steer_rad", "throttle", "brake")
CAN_COLUMNS = ("stamp_ns", "direction", "id", "data")
SCAN_COLUMNS = ("stamp_ns", "angle_min_rad", "angle_increment_rad", "time_increment_s", "scan_time_s", "range_min_m",
                "range_max_m", "ranges_m", "intensities")
MAX_BEAMS = 100_000  # a sweep's beams a recording reads (an RPLIDAR S3's densest mode has about 10,000)
_TOPIC = re.compile(r"[a-z][a-z0-9_]*")
OutputValue = float | int | str
# png: lossless, level 1, every row filtered by its left neighbour (libpng's "sub") rather than the filter tried
# best per row: the same size and 1.4 to 1.5x faster to write, measured on one core on the venue's 848x480
# frames (18.9 to 12.8 ms, 0.45 MB both) and on noisy 960x540 simulated ones (34 to 24 ms, 1.0 MB both).
# png-huffman: the same, its bytes Huffman-coded with no search for repeats (zlib's Z_HUFFMAN_ONLY), for frames
# whose sensor noise leaves no repeats to find: the simulator's. On its noisy 848x480 frames 12.3 ms rather than
# 22.4 and 5 % smaller (0.78 MB); on the venue's real frames 12.4 rather than 14.5 ms but a third larger, so
# recordings of real cameras keep png.
# jpg: quality 95 (1.4 ms), for live recording of several cameras on a small CPU: what an MJPG camera sends
# is JPEG already
_PNG_SUB = [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB] if hasattr(cv2, "IMWRITE_PNG_FILTER") else []
_HUFFMAN = [cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY] if hasattr(
    cv2, "IMWRITE_PNG_STRATEGY") else []
IMAGE_FORMATS = {"png": (".png", [cv2.IMWRITE_PNG_COMPRESSION, 1, *_PNG_SUB]),
                 "png-huffman": (".png", [cv2.IMWRITE_PNG_COMPRESSION, 1, *_PNG_SUB, *_HUFFMAN]),
                 "jpg": (".jpg", [cv2.IMWRITE_JPEG_QUALITY, 95])}


class RecordingWriter:
    """Writes a recording folder. Use as a context manager; ``close`` marks it complete.

    With ``queue_frames > 0``, images are encoded and written by one background thread per camera
    (PNG encoding releases the GIL) through a bounded queue, and the text lines (commands, outputs,
    CAN traffic) by one more thread, so recording does not hold up the caller. When a frame queue is
    full the frame is dropped and counted per camera (``drop_when_full``, for a live loop that must
    not wait) or the caller waits (for the simulator, whose time does not run away). Text lines are
    small: their queue holds ``LINE_QUEUE`` lines, and a line that does not fit is counted too.
    """

    LINE_QUEUE = 10_000
    MANIFEST_REFRESH_S = 1.0
    MIN_FREE_BYTES = 200 * 2**20
    """A recording starts only with this much free on its disk, and stops (as a write that failed does: the drive
    stops and says why) when less is left: a disk run full mid-file loses more than the last frame (the manifest's
    last refresh, other programs' files)."""

    def __init__(self, folder: str | Path, cameras: dict[str, PinholeCamera],
                 stereo_pair: tuple[str, str] | None = None, metadata: dict[str, Any] | None = None,
                 overwrite: bool = False, queue_frames: int = 0, drop_when_full: bool = True,
                 image_format: str = "png", lidars: Mapping[str, LidarMount] | None = None) -> None:
        self.folder = Path(folder)
        if image_format not in IMAGE_FORMATS:
            raise RecordingError(f"image format {image_format!r}: one of {', '.join(IMAGE_FORMATS)}")
        self.image_format = image_format
        if self.folder.exists() and any(self.folder.iterdir()) and not overwrite:
            raise RecordingError(f"recording folder {self.folder} exists and is not empty")
        free = free_bytes(self.folder)
        if free < self.MIN_FREE_BYTES:
            raise RecordingError(f"only {free / 2**20:.0f} MB free on the disk of {self.folder}: a recording needs "
                                 f"{self.MIN_FREE_BYTES / 2**20:.0f} MB at least; free some, or record elsewhere")
        if stereo_pair and not set(stereo_pair) <= set(cameras):
            raise RecordingError(f"stereo pair {stereo_pair} names unknown cameras")
        self.cameras = cameras
        self.stereo_pair = stereo_pair
        self.metadata = dict(metadata or {})
        self.frame_counts = dict.fromkeys(cameras, 0)
        self.dropped = dict.fromkeys(cameras, 0)  # frames the recording could not keep up with
        self.missing = dict.fromkeys(cameras, 0)  # sets a camera delivered no frame to
        self.dropped_lines = 0
        self.command_count = 0
        self.output_counts: dict[str, int] = {}
        self.can_count = 0
        self.lidars = dict(lidars or {})
        self.scan_counts = dict.fromkeys(self.lidars, 0)
        self._files: dict[str, IO[str]] = {}
        self._output_columns: dict[str, tuple[str, ...]] = {}
        for name in cameras:
            camera_dir = self.folder / "cameras" / name
            camera_dir.mkdir(parents=True, exist_ok=True)
            self._open(f"camera:{name}", camera_dir / "frames.csv", ("index", "stamp_ns", "file", "capture_ns"))
        self._open("commands", self.folder / "commands.csv", COMMAND_COLUMNS)
        self._closed = False
        self._drop_when_full = drop_when_full
        self._queues: dict[str, queue.Queue[tuple[str, int, Image, int] | None]] = {}
        self._lines: queue.Queue[tuple[str, str] | None] | None = None
        self._threads: list[threading.Thread] = []
        self._error: BaseException | None = None
        if queue_frames > 0:
            for name in cameras:
                self._queues[name] = queue.Queue(maxsize=queue_frames)
                self._start(self._drain, self._queues[name], f"recording-{name}")
            self._lines = queue.Queue(maxsize=self.LINE_QUEUE)
            self._start(self._drain_lines, self._lines, "recording-lines")
        self._write_manifest(closed=False)
        self._manifest_written = time.monotonic()

    def _open(self, key: str, path: Path, columns: tuple[str, ...]) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle = path.open("w", newline="")
        handle.write(",".join(columns) + "\n")
        handle.flush()
        self._files[key] = handle

    def _start(self, target: Any, jobs: queue.Queue[Any], name: str) -> None:
        thread = threading.Thread(target=target, args=(jobs,), name=name, daemon=True)
        thread.start()
        self._threads.append(thread)

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _write_manifest(self, closed: bool) -> None:
        manifest = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            # a recording whose writing failed (a full disk) is not closed properly, whatever was flushed
            "closed": closed and self._error is None,
            "write_error": None if self._error is None else str(self._error),
            "cameras": {name: camera_to_dict(cam) for name, cam in self.cameras.items()},
            "stereo_pair": list(self.stereo_pair) if self.stereo_pair else None,
            "frame_counts": self.frame_counts,
            "dropped_frames": self.dropped,
            "missing_frames": self.missing,
            "dropped_lines": self.dropped_lines,
            "command_count": self.command_count,
            "output_counts": self.output_counts,
            "can_count": self.can_count,
            "lidars": {name: asdict(mount) for name, mount in self.lidars.items()},
            "scan_counts": self.scan_counts,
            "has_groundtruth": (self.folder / "groundtruth.tum").is_file(),
            "image_format": self.image_format,
            "metadata": self.metadata,
        }
        write_json_atomic(self.folder / "manifest.json", manifest)

    def _check_open(self) -> None:
        if self._closed:
            raise RecordingError("the recording is closed")
        if self._error is not None:
            raise RecordingError(f"the recording's writer failed: {self._error}") from self._error

    def write_frame(self, camera: str, stamp_ns: int, image: Image, capture_ns: int | None = None) -> None:
        """One camera's image of the set at ``stamp_ns`` (``capture_ns``: the camera's own time, if other)."""
        self._check_open()
        if camera not in self.cameras:
            raise RecordingError(f"unknown camera {camera!r}")
        capture = stamp_ns if capture_ns is None else capture_ns
        if not self._queues:
            self._write_image(camera, stamp_ns, image, capture)
            return
        try:
            self._queues[camera].put((camera, stamp_ns, image, capture), block=not self._drop_when_full)
        except queue.Full:
            self.dropped[camera] += 1

    def _drain(self, jobs: queue.Queue[tuple[str, int, Image, int] | None]) -> None:
        while (item := jobs.get()) is not None:
            try:
                self._write_image(*item)
            except BaseException as exc:
                self._error = exc

    def _drain_lines(self, jobs: queue.Queue[tuple[str, str] | None]) -> None:
        while (item := jobs.get()) is not None:
            try:
                self._write_line(*item)
            except BaseException as exc:
                self._error = exc

    def _write_line(self, key: str, line: str) -> None:
        handle = self._files[key]
        handle.write(line)
        handle.flush()

    def _line(self, key: str, line: str) -> None:
        if self._lines is None:
            self._write_line(key, line)
            return
        try:
            self._lines.put_nowait((key, line))
        except queue.Full:
            self.dropped_lines += 1

    def _write_image(self, camera: str, stamp_ns: int, image: Image, capture_ns: int) -> None:
        suffix, params = IMAGE_FORMATS[self.image_format]
        name = f"{stamp_ns}{suffix}"
        path = self.folder / "cameras" / camera / name
        ok, encoded = cv2.imencode(suffix, image, params)
        if not ok:
            raise RecordingError(f"cannot encode the frame for {path}")
        try:  # written by Python, so a full disk or a file size limit says what it is (EFBIG, ENOSPC)
            path.write_bytes(encoded.tobytes())
        except OSError as exc:
            path.unlink(missing_ok=True)
            raise RecordingError(f"cannot write {path}: {exc.strerror or exc}") from None
        self._write_line(f"camera:{camera}", f"{self.frame_counts[camera]},{stamp_ns},{name},{capture_ns}\n")
        self.frame_counts[camera] += 1

    def write_frames(self, frames: FrameSet) -> None:
        """Frame sink: write every image of a synchronised set under its camera's name; a camera of the
        rig missing from the set is counted (``missing``: the camera's doing, not the recording's)."""
        if time.monotonic() - self._manifest_written > self.MANIFEST_REFRESH_S:
            free = free_bytes(self.folder)
            if free < self.MIN_FREE_BYTES and self._error is None:  # stop before the disk is full, not at it
                self._error = RecordingError(f"the disk of {self.folder} is nearly full ({free / 2**20:.0f} MB "
                                             f"left, under {self.MIN_FREE_BYTES / 2**20:.0f} MB): recording stopped")
            self._write_manifest(closed=False)  # the counts, in case the run is cut off
            self._manifest_written = time.monotonic()
        for camera in self.cameras:
            image = frames.images.get(camera)
            if image is None:
                self.missing[camera] += 1
            else:
                self.write_frame(camera, frames.stamp_ns, image, frames.capture_ns.get(camera))
        for name, scan in frames.scans.items():
            if name in self.lidars:
                self.write_scan(name, scan)

    def write_scan(self, name: str, scan: LaserScan) -> None:
        """One sweep of the named LiDAR, a line of its ``scans.csv``."""
        self._check_open()
        if name not in self.lidars:
            raise RecordingError(f"unknown LiDAR {name!r}")
        key = f"lidar:{name}"
        if key not in self._files:
            self._open(key, self.folder / "lidar" / name / "scans.csv", SCAN_COLUMNS)
        head = (f"{scan.stamp_ns},{scan.angle_min_rad:.9g},{scan.angle_increment_rad:.9g},{scan.time_increment_s:.9g},"
                f"{scan.scan_time_s:.9g},{scan.range_min_m:.9g},{scan.range_max_m:.9g}")
        ranges = " ".join(f"{v:.4f}" if math.isfinite(v) else "nan" for v in np.asarray(scan.ranges_m, float))
        strengths = " ".join(f"{v:.4g}" for v in np.nan_to_num(np.asarray(scan.intensities, float)))
        self._line(key, f"{head},{ranges},{strengths}\n")
        self.scan_counts[name] += 1

    def send(self, command: ActuatorCommand) -> None:
        """Command sink: the recorder takes commands like any actuator would."""
        self.write_command(command)

    def write_command(self, command: ActuatorCommand) -> None:
        self._check_open()
        self._line("commands", f"{command.stamp_ns},{command.steer_rad:.6f},{command.throttle:.6f},"
                               f"{command.brake:.6f}\n")
        self.command_count += 1

    def write_output(self, topic: str, stamp_ns: int, values: Mapping[str, OutputValue]) -> None:
        """One of the pipeline's outputs (``pose``, ``lanes``, ...) at ``stamp_ns``. A topic's columns are
        fixed by its first row."""
        self._check_open()
        columns = self._output_columns.get(topic)
        if columns is None:
            if not _TOPIC.fullmatch(topic):
                raise RecordingError(f"output topic {topic!r}: use lower-case letters, digits and _")
            columns = tuple(values)
            self._output_columns[topic] = columns
            self.output_counts[topic] = 0
            self._open(f"output:{topic}", self.folder / "outputs" / f"{topic}.csv", ("stamp_ns", *columns))
        elif tuple(values) != columns:
            raise RecordingError(f"output topic {topic!r} has columns {', '.join(columns)}, not "
                                 f"{', '.join(values)}")
        self._line(f"output:{topic}", ",".join([str(stamp_ns), *(_format(v) for v in values.values())]) + "\n")
        self.output_counts[topic] += 1

    def write_outputs(self, stamp_ns: int, outputs: Mapping[str, Mapping[str, OutputValue]]) -> None:
        """Output sink: every topic of one step."""
        for topic, values in outputs.items():
            self.write_output(topic, stamp_ns, values)

    def write_can(self, stamp_ns: int, arbitration_id: int, data: bytes, direction: str = "tx") -> None:
        """One CAN frame sent (``tx``) or received (``rx``)."""
        self._check_open()
        if direction not in ("tx", "rx"):
            raise RecordingError(f"CAN direction {direction!r}: tx or rx")
        if "can" not in self._files:
            self._open("can", self.folder / "can.csv", CAN_COLUMNS)
        self._line("can", f"{stamp_ns},{direction},{arbitration_id:#x},{bytes(data).hex()}\n")
        self.can_count += 1

    def write_truth_pose(self, stamp_ns: int, pose: Array) -> None:
        """One ground-truth pose as soon as it is known, appended to ``groundtruth.tum`` and flushed like every
        line, so a run killed before it closes keeps its truth up to there (``write_groundtruth`` at the end
        rewrites the file whole)."""
        self._check_open()
        if "groundtruth" not in self._files:
            self._open("groundtruth", self.folder / "groundtruth.tum", ("# timestamp tx ty tz qx qy qz qw",))
        values = [*np.asarray(pose)[:3, 3], *quaternion_xyzw_from_pose(np.asarray(pose))]
        self._line("groundtruth", f"{stamp_ns * 1e-9:.9f} " + " ".join(f"{v:.9f}" for v in values) + "\n")

    def write_groundtruth(self, trajectory: Trajectory) -> None:
        write_tum(self.folder / "groundtruth.tum", trajectory)

    def close(self) -> None:
        if self._closed:
            return
        for jobs in self._queues.values():
            jobs.put(None)  # after every queued frame: nothing queued is lost
        if self._lines is not None:
            self._lines.put(None)
        for thread in self._threads:
            thread.join()
        for handle in self._files.values():
            handle.close()
        self._closed = True
        self._write_manifest(closed=True)


def mount_from_dict(name: str, data: Any, where: str) -> LidarMount:
    """A LiDAR's mount from a manifest's or a rig file's mapping (``x_m``, ``y_m``, ``z_m``, ``yaw_rad``)."""
    try:
        return LidarMount(float(data["x_m"]), float(data["y_m"]), float(data["z_m"]), float(data.get("yaw_rad", 0.0)))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise RecordingError(f"LiDAR {name!r} {where}: a mount needs x_m, y_m, z_m (and yaw_rad): {exc}") from None
    except KartpilotError as exc:
        raise RecordingError(f"LiDAR {name!r} {where}: {exc}") from None


def _values(text: str, what: str) -> NDArray[np.float32]:
    values = np.array(text.split(), dtype=np.float32) if text.strip() else np.zeros(0, np.float32)
    if len(values) > MAX_BEAMS:
        raise ValueError(f"{len(values)} {what}, more than a sweep has ({MAX_BEAMS})")
    return values


def _format(value: OutputValue) -> str:
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, float):
        return f"{value:.9g}"
    # a free text (a reason, an error) must not break the CSV: its separators are replaced
    return str(value).replace(",", ";").replace('"', "'").replace("\n", " ")


def _parse(text: str) -> OutputValue:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


class RecordingReader:
    """Reads a recording folder written by :class:`RecordingWriter` (or cut off mid-run)."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        manifest_path = self.folder / "manifest.json"
        if not manifest_path.is_file():
            raise RecordingError(f"{self.folder} is not a kartpilot recording (no manifest.json)")
        try:
            manifest = read_json_file(manifest_path)
        except DataError as exc:
            raise RecordingError(str(exc)) from None
        if manifest.get("format") != FORMAT_NAME:
            raise RecordingError(f"{manifest_path}: format is {manifest.get('format')!r}, not {FORMAT_NAME!r}")
        if int(manifest.get("version", 0)) > FORMAT_VERSION:
            raise RecordingError(
                f"{manifest_path}: format version {manifest['version']} is newer than this kartpilot "
                f"reads ({FORMAT_VERSION})")
        self.manifest: dict[str, Any] = manifest
        self.closed = bool(manifest.get("closed", False))
        self.cameras = {name: camera_from_dict(name, data, "in the manifest")
                        for name, data in manifest["cameras"].items()}
        pair = manifest.get("stereo_pair")
        self.stereo_pair: tuple[str, str] | None = (pair[0], pair[1]) if pair else None

    @property
    def lidars(self) -> dict[str, LidarMount]:
        """The recording's LiDARs and their mounts (none in a recording without)."""
        return {name: mount_from_dict(name, data, "in the manifest")
                for name, data in (self.manifest.get("lidars") or {}).items()}

    def scans(self, name: str) -> list[LaserScan]:
        """Every sweep of the named LiDAR, in order. A torn last line (a recording cut off) is left out; any other
        line that is not a sweep is an error naming it."""
        if name not in self.lidars:
            raise RecordingError(f"recording has no LiDAR {name!r} (has {', '.join(self.lidars) or 'none'})")
        path = self.folder / "lidar" / name / "scans.csv"
        if not path.is_file():
            return []
        content = read_text_file(path)
        rows = csv_records(content)
        scans: list[LaserScan] = []
        for number, row in enumerate(rows, start=2):
            try:
                ranges, strengths = _values(row["ranges_m"], "ranges"), _values(row["intensities"], "intensities")
                if len(strengths) != len(ranges):
                    raise ValueError(f"{len(ranges)} ranges but {len(strengths)} intensities")
                scan = LaserScan(int(row["stamp_ns"]), float(row["angle_min_rad"]), float(row["angle_increment_rad"]),
                                 float(row["time_increment_s"]), float(row["scan_time_s"]), float(row["range_min_m"]),
                                 float(row["range_max_m"]), ranges, strengths)
            except (KeyError, TypeError, ValueError, AttributeError, KartpilotError) as exc:
                if is_torn_last_line(content, number, len(rows) + 1):
                    continue
                raise RecordingError(f"{path}:{number}: not a sweep: {exc}") from None
            if scans and scan.stamp_ns <= scans[-1].stamp_ns:
                raise RecordingError(f"{path}:{number}: stamp_ns {scan.stamp_ns} does not come after the line "
                                     f"before's ({scans[-1].stamp_ns})")
            scans.append(scan)
        return scans

    @property
    def vehicle(self) -> str | None:
        """The kart the recording was made on, where it says (live drives and simulated runs do)."""
        metadata = self.manifest.get("metadata") or {}
        name = metadata.get("vehicle") or (metadata.get("sim") or {}).get("vehicle")
        return str(name) if name else None

    @property
    def sim_track(self) -> str | None:
        """The simulated track a simulated run was made on (None for a real drive)."""
        metadata = self.manifest.get("metadata") or {}
        track = (metadata.get("sim") or {}).get("track")
        return str(track) if track else None

    def _frame_rows(self, camera: str) -> list[tuple[int, Path, int]]:
        if camera not in self.cameras:
            raise RecordingError(f"recording has no camera {camera!r} (has {', '.join(self.cameras)})")
        csv_path = self.folder / "cameras" / camera / "frames.csv"
        if not csv_path.is_file():
            raise RecordingError(f"missing frame list {csv_path}")
        rows: list[tuple[int, Path, int]] = []
        content = read_text_file(csv_path)
        listed = csv_records(content)
        for number, row in enumerate(listed, start=2):
            try:
                path = csv_path.parent / row["file"]
                stamp = int(row["stamp_ns"])
                capture = int(row["capture_ns"]) if row.get("capture_ns") else stamp
            except (KeyError, TypeError, ValueError) as exc:
                if is_torn_last_line(content, number, len(listed) + 1):
                    continue
                raise RecordingError(f"{csv_path}:{number}: not a frame (stamp_ns, file): {exc}") from None
            if number == len(listed) + 1 and not self.closed and not path.is_file():
                continue  # the last row of a recording cut off while it was written, its image not there
            if rows and stamp <= rows[-1][0]:
                raise RecordingError(f"{csv_path}:{number}: stamp_ns {stamp} does not come after the line before's "
                                     f"({rows[-1][0]}): the frames' times go backwards or repeat")
            # a listed frame whose image is gone stays listed: reading it fails, and the reader counts it as
            # unreadable (VO bridges it) instead of the frame silently vanishing
            rows.append((stamp, path, capture))
        return rows

    def frames(self, camera: str) -> list[tuple[int, Path]]:
        """(stamp_ns, image path) of every frame of a camera, in order (an image may have gone missing since:
        reading it raises DataError)."""
        return [(stamp, path) for stamp, path, _ in self._frame_rows(camera)]

    def capture_stamps(self, camera: str) -> list[int]:
        """Each complete frame's capture time by the camera's own clock (its set's time if not recorded)."""
        return [capture for _, _, capture in self._frame_rows(camera)]

    def commands(self) -> list[ActuatorCommand]:
        path = self.folder / "commands.csv"
        if not path.is_file():
            return []
        result: list[ActuatorCommand] = []
        content = read_text_file(path)
        rows = csv_records(content)
        for number, row in enumerate(rows, start=2):
            try:
                values = (float(row["steer_rad"]), float(row["throttle"]), float(row["brake"]))
                stamp_ns = int(row["stamp_ns"])
                if not all(math.isfinite(v) for v in values):
                    raise ValueError("a value is not finite")
            except (KeyError, TypeError, ValueError) as exc:
                if is_torn_last_line(content, number, len(rows) + 1):
                    log.warning("%s:%d: skipped the last line, cut off mid-write", path, number)
                    continue
                raise RecordingError(f"{path}:{number}: not a command (stamp_ns, steer_rad, throttle, brake): "
                                     f"{exc}") from None
            if result and stamp_ns < result[-1].stamp_ns:
                raise RecordingError(f"{path}:{number}: stamp_ns {stamp_ns} comes before the line before's "
                                     f"({result[-1].stamp_ns}): the commands' times go backwards")
            result.append(ActuatorCommand(stamp_ns, *values))
        return result

    def output_topics(self) -> list[str]:
        folder = self.folder / "outputs"
        return sorted(p.stem for p in folder.glob("*.csv")) if folder.is_dir() else []

    def outputs(self, topic: str) -> list[dict[str, OutputValue]]:
        """A topic's rows (numbers parsed); a line cut off by a crash is left out."""
        path = self.folder / "outputs" / f"{topic}.csv"
        if not path.is_file():
            raise RecordingError(f"recording has no output {topic!r} (has {', '.join(self.output_topics()) or 'none'})")
        return [{k: _parse(v) for k, v in row.items()} for row in iter_csv_file(path, skip_torn=True)]

    def can_frames(self) -> list[tuple[int, str, int, bytes]]:
        """(stamp_ns, direction, id, data) of the recorded CAN traffic."""
        path = self.folder / "can.csv"
        if not path.is_file():
            return []
        frames = []
        for row in iter_csv_file(path, skip_torn=True):
            try:
                frames.append((int(row["stamp_ns"]), row["direction"], int(row["id"], 16), bytes.fromhex(row["data"])))
            except (KeyError, TypeError, ValueError):
                continue
        return frames

    def groundtruth(self) -> Trajectory | None:
        path = self.folder / "groundtruth.tum"
        return read_tum(path) if path.is_file() else None

    def camera_poses(self, camera: str, trajectory: Trajectory | None = None) -> Trajectory | None:
        """The poses of ``camera``: ``trajectory`` if given (taken to be that camera's), else the ground
        truth, moved by the mounts onto ``camera`` when it is another camera's; None without either."""
        if trajectory is not None:
            return trajectory
        truth = self.groundtruth()
        if truth is None:
            return None
        measured = self.manifest.get("metadata", {}).get("groundtruth_camera", camera)
        if measured == camera or measured not in self.cameras or camera not in self.cameras:
            return truth
        cam_to_cam = invert_pose(self.cameras[measured].pose_body_cam_array) @ self.cameras[camera].pose_body_cam_array
        return Trajectory(truth.stamps_s, truth.poses @ cam_to_cam)

    def body_poses(self) -> Trajectory | None:
        """The kart's poses in the world (its body frame's), from the ground truth through the mount of the
        camera it was measured at; None without ground truth. A ground truth that names no camera is the
        kart's own."""
        truth = self.groundtruth()
        if truth is None:
            return None
        measured = self.manifest.get("metadata", {}).get("groundtruth_camera")
        if measured not in self.cameras:
            return truth
        return Trajectory(truth.stamps_s, truth.poses @ invert_pose(self.cameras[measured].pose_body_cam_array))

    def pose_indices(self, camera: str, poses: Trajectory, max_gap_s: float = POSE_GAP_S) -> list[int | None]:
        """For each frame of ``camera``, the index of the pose within ``max_gap_s`` of its time (None: none)."""
        stamps = np.round(poses.stamps_s * 1e9).astype(np.int64)  # once, not per frame
        return [nearest_within(stamp_ns, stamps, round(max_gap_s * 1e9)) for stamp_ns, _ in self.frames(camera)]

    def posed_frames(self, camera: str, poses: Trajectory, max_gap_s: float = POSE_GAP_S
                     ) -> Iterator[tuple[int, Image, Array]]:
        """(stamp_ns, grey image, pose_world_cam) of each frame of ``camera`` with a pose within ``max_gap_s``;
        frames without one are left out. An unreadable image raises DataError naming it."""
        if camera not in self.cameras:
            raise RecordingError(f"the recording has no camera {camera!r} (has {', '.join(self.cameras)})")
        for (stamp_ns, path), index in zip(self.frames(camera), self.pose_indices(camera, poses, max_gap_s),
                                           strict=True):
            if index is not None:
                yield stamp_ns, read_gray(path), poses.poses[index]


class RecordingStereoSource(StereoSource):
    """The stereo pair of a recording, rectified from the manifest's calibration when needed."""

    def __init__(self, folder: str | Path) -> None:
        self.reader = RecordingReader(folder)
        if self.reader.stereo_pair is None:
            raise RecordingError(f"recording {self.reader.folder} names no stereo pair")
        left_name, right_name = self.reader.stereo_pair
        self.name = f"recording-{self.reader.folder.name}"
        self.setup = stereo_setup(self.reader.cameras[left_name], self.reader.cameras[right_name])
        right_frames = dict(self.reader.frames(right_name))
        self._pairs = [(stamp, path, right_frames[stamp]) for stamp, path in self.reader.frames(left_name)
                       if stamp in right_frames]
        if not self._pairs:
            raise RecordingError(f"recording {self.reader.folder} has no complete stereo pair")

    @property
    def rig(self) -> StereoRig:
        return self.setup.rig

    @property
    def pose_body_left(self) -> Array:
        """The (rectified) left camera's pose on the kart, from the recording's rig."""
        return self.setup.pose_body_left

    def __len__(self) -> int:
        return len(self._pairs)

    def stamp_ns(self, index: int) -> int:
        return self._pairs[index][0]

    def frame(self, index: int) -> StereoFrame:
        stamp, left_path, right_path = self._pairs[index]
        left, right = self.setup.rectify(read_gray(left_path), read_gray(right_path))
        return StereoFrame(index, stamp, left, right)

    def ground_truth(self) -> Trajectory | None:
        return self.reader.groundtruth()

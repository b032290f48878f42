"""A drive as a Rerun view: every camera with what the pipeline saw, the trajectories, commands and CAN over time.

:class:`RerunView` is a sink like the recorder (frames, commands, the pipeline's outputs, CAN frames), so the
loop feeds a drive, a simulated run or a replay to it as it goes, and :func:`view_recording` feeds it a
recording afterwards: the same view either way. The loop only queues what a step produced; one background
thread encodes and logs it, so the loop keeps its rate. When the queue is full the step's images are dropped
and counted (the numbers are kept, up to ``SCALAR_QUEUE`` waiting). Entities (one timeline, ``stamp``: the
sets' time stamps, nanoseconds):

* ``cameras/<name>``: each camera's image (JPEG, scaled by ``image_scale``), and the camera's pinhole;
* ``cameras/center/lanes``: the detected lane boundaries and their meeting point (the ``lanes`` output);
* ``cameras/left/inliers`` and ``world/points``: VO's inlier points in the image and in the world
  (``kartpilot odometry``), with each filter stage's count as ``outputs/vo/<stage>``;
* ``world/estimate``: the pipeline's position (the ``pose`` output's ``x_m``, ``y_m`` and ``z_m``; VO's camera
  in its own world frame for ``kartpilot odometry``), ``world/truth`` and ``world/reference``: the
  ground truth and the reference path, as lines;
* ``commands/<steer_rad|throttle|brake>``: the commands;
* ``outputs/<topic>/<value>``: every number the pipeline recorded (confidence, cross-track error, speed, the
  kart's decoded CAN report in the ``kart`` topic), and ``events/<topic>``: its text values when they change
  (the supervisor's state and reason, the lane rule);
* ``can/<message>/<signal>``: each CAN frame decoded with the bus's DBC (``can/raw/<id>``: a frame it lacks);
* ``lidar/<name>``: each LiDAR sweep's returns as a top view in the sensor's frame (the sensor at the origin, its
  front up, its left to the left; metres);
* ``birdseye``: the road around the kart from above, the centre camera's image laid on the ground
  (:func:`kartpilot.perception.birdseye.birdseye`; the kart's front up, its rear axle ``birdseye_behind_m`` above
  the bottom edge), and ``birdseye/<lidar>``: each sweep's returns on it, where they are on the kart (through the
  LiDAR's mount): what the scan measures over what the camera sees.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cantools
import cv2
import numpy as np
import rerun as rr

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import DataError
from kartpilot.core.images import read_image
from kartpilot.core.trajectory import Trajectory
from kartpilot.core.types import ActuatorCommand, FrameSet, Image, LidarMount
from kartpilot.perception.birdseye import BirdseyeGrid, birdseye, birdseye_grid
from kartpilot.record.recording import RecordingReader

__all__ = ["LIVE", "RerunView", "ViewConfig", "birdseye_view_grid", "scan_on_birdseye", "view_recording"]

log = logging.getLogger(__name__)

LIVE = "live"  # the target that streams to a Rerun viewer instead of a file


@dataclass(frozen=True)
class ViewConfig:
    """Attributes:
        image_scale: the images are logged at this scale (JPEG): a 960x540 camera at 0.5 is about 25 kB a frame.
        image_every: the images of every n-th set are logged (the numbers of every set are).
        jpeg_quality: 1 to 100.
        queue_steps: steps waiting for the logging thread; beyond them a step's images are dropped and counted.
        birdseye_camera: the camera laid on the ground for the ``birdseye`` view (one with a mount; none: no view).
        birdseye_ahead_m, birdseye_behind_m, birdseye_side_m, birdseye_resolution_m: its extent from the rear
            axle (ahead, behind, to each side) and its metres a pixel.
    """

    image_scale: float = 0.5
    image_every: int = 1
    jpeg_quality: int = 80
    queue_steps: int = 16
    birdseye_camera: str = "center"
    birdseye_ahead_m: float = 20.0
    birdseye_behind_m: float = 4.0
    birdseye_side_m: float = 8.0
    birdseye_resolution_m: float = 0.05

    def __post_init__(self) -> None:
        checks = {"image_scale": 0 < self.image_scale <= 1, "image_every": self.image_every >= 1,
                  "jpeg_quality": 1 <= self.jpeg_quality <= 100, "queue_steps": self.queue_steps >= 1,
                  "birdseye_ahead_m": 0 < self.birdseye_ahead_m <= 100,
                  "birdseye_behind_m": 0 <= self.birdseye_behind_m <= 50,
                  "birdseye_side_m": 0 < self.birdseye_side_m <= 50,
                  "birdseye_resolution_m": 0.01 <= self.birdseye_resolution_m <= 1}
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"{bad[0]} is out of range ({getattr(self, bad[0])!r})")


class RerunView:
    """Logs a drive to a ``.rrd`` file or a live viewer (``target`` ``"live"``). A sink: ``write_frames``,
    ``send``, ``write_outputs``, ``write_can``; ``write_groundtruth`` and ``write_reference`` for the lines;
    ``close`` waits for the queue and closes the file."""

    SCALAR_BATCH = 30  # values of a time series sent at once: a second of a 30 Hz drive
    POLL_S = 0.002  # how often the thread looks for work when it has none
    SCALAR_QUEUE = 100_000  # numbers waiting for the thread: minutes of a drive's outputs and CAN traffic

    def __init__(self, target: str | Path, cameras: Mapping[str, PinholeCamera], config: ViewConfig = ViewConfig(),
                 database: cantools.database.can.Database | None = None, name: str = "kartpilot",
                 drop_when_full: bool = True, lidars: Mapping[str, LidarMount] | None = None) -> None:
        """``database``: the bus's messages, to decode the CAN frames with. ``drop_when_full``: a live loop drops
        a step's images when the logging thread lags; a recording's view (False) waits for it instead.
        ``lidars``: the LiDARs' mounts, to put their sweeps on the ``birdseye`` view."""
        self.config = config
        self._drop_when_full = drop_when_full
        self.cameras = dict(cameras)
        self.lidars = dict(lidars or {})
        self._grid = birdseye_view_grid(self.cameras.get(config.birdseye_camera), config)
        self.stream = rr.RecordingStream("kartpilot", recording_id=f"{name}-{time.time_ns()}")
        if str(target) == LIVE:
            self.stream.spawn()
        else:
            Path(target).parent.mkdir(parents=True, exist_ok=True)
            self.stream.save(str(target))
        self.database = database
        self.dropped_images = 0
        self.dropped_values = 0
        self.logged_steps = 0
        self.worker_s = 0.0  # the logging thread's time, for the cost per frame
        self._sets = 0
        self._text: dict[str, str] = {}
        self._series: dict[str, tuple[list[int], list[float]]] = {}
        # plain deques, polled by the thread: appending never waits on a lock the thread holds (a queue's
        # hand-over cost the loop 1 to 2 ms a frame on a busy machine)
        self._frames: deque[tuple[int, Mapping[str, Image]]] = deque()
        self._scalars: deque[tuple[str, int, Any]] = deque()
        self._closing = False
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._drain, name="rerun-view", daemon=True)
        self._thread.start()
        for camera_name, camera in self.cameras.items():
            scale = config.image_scale
            self.stream.log(f"cameras/{camera_name}", rr.Pinhole(
                image_from_camera=np.diag([scale, scale, 1.0]) @ camera.matrix,
                resolution=[round(camera.width_px * scale), round(camera.height_px * scale)]), static=True)

    # --- the sink: the loop's side only queues -----------------------------------------------------------

    def write_frames(self, frames: FrameSet) -> None:
        for name, scan in frames.scans.items():  # every sweep, whatever happens to the images
            self._queue(("scan", scan.stamp_ns, (name, scan)))
        self._sets += 1
        if (self._sets - 1) % self.config.image_every:
            return
        while not self._drop_when_full and len(self._frames) >= self.config.queue_steps and self._thread.is_alive():
            time.sleep(self.POLL_S)
        if len(self._frames) >= self.config.queue_steps:
            self.dropped_images += 1
            return
        self._frames.append((frames.stamp_ns, frames.images))

    def send(self, command: ActuatorCommand) -> None:
        self._queue(("command", command.stamp_ns, command))

    def write_outputs(self, stamp_ns: int, outputs: Mapping[str, Mapping[str, float | int | str]]) -> None:
        self._queue(("outputs", stamp_ns, {k: dict(v) for k, v in outputs.items()}))

    def write_can(self, stamp_ns: int, arbitration_id: int, data: bytes, direction: str = "tx") -> None:
        self._queue(("can", stamp_ns, (arbitration_id, bytes(data), direction)))

    def write_points(self, stamp_ns: int, camera: str, pixels: np.ndarray, points_world_m: np.ndarray) -> None:
        """A step's points: where they lie in ``camera``'s image at ``stamp_ns`` (``cameras/<camera>/inliers``)
        and in the world (``world/points``)."""
        self._queue(("points", stamp_ns, (camera, np.asarray(pixels, float), np.asarray(points_world_m))))

    def _queue(self, item: tuple[str, int, Any]) -> None:
        """A step's numbers for the thread; beyond ``SCALAR_QUEUE`` waiting (a thread that cannot keep up with
        the CAN traffic) they are dropped and counted rather than let memory grow."""
        if len(self._scalars) >= self.SCALAR_QUEUE:
            self.dropped_values += 1
            return
        self._scalars.append(item)

    def write_groundtruth(self, trajectory: Trajectory) -> None:
        """The true trajectory, as one line (positions of the poses it holds)."""
        self._scalars.append(("line", 0, ("world/truth", trajectory.poses[:, :3, 3], (0, 200, 0))))

    def write_reference(self, xy_m: np.ndarray) -> None:
        """The reference path on the ground, as one line."""
        points = np.column_stack([xy_m[:, 0], xy_m[:, 1], np.zeros(len(xy_m))])
        self._scalars.append(("line", 0, ("world/reference", points, (80, 80, 255))))

    def close(self) -> None:
        self._closing = True
        self._thread.join()
        self.stream.flush()
        self.stream.disconnect()
        if self._error is not None:
            raise DataError(f"the Rerun view failed: {self._error}") from self._error

    # --- the logging thread ------------------------------------------------------------------------------

    def _drain(self) -> None:
        while True:
            closing = self._closing  # read before the queues: whatever came before close is logged
            if not self._frames and not self._scalars and not closing:
                time.sleep(self.POLL_S)
                continue
            start = time.perf_counter()
            try:
                self._log_scalars()
                if self._frames:
                    self._log_frames(*self._frames.popleft())
                    self.logged_steps += 1
                elif closing:
                    for entity in list(self._series):
                        self._send_series(entity)
                    return
            except Exception as exc:  # the view must never stop the drive: the error is raised on close
                if self._error is None:
                    log.exception("the Rerun view failed")
                self._error = exc
            finally:
                self.worker_s += time.perf_counter() - start

    def _time(self, stamp_ns: int) -> None:
        self.stream.set_time("stamp", timestamp=np.datetime64(int(stamp_ns), "ns"))

    def _log_frames(self, stamp_ns: int, images: Mapping[str, Image]) -> None:
        self._time(stamp_ns)
        scale = self.config.image_scale
        for name, image in images.items():
            small = image if scale == 1 else cv2.resize(image, None, fx=scale, fy=scale,
                                                        interpolation=cv2.INTER_AREA)
            ok, jpeg = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, self.config.jpeg_quality])
            if ok:
                self.stream.log(f"cameras/{name}", rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg"))
        under = images.get(self.config.birdseye_camera)
        if self._grid is not None and under is not None:
            ok, jpeg = cv2.imencode(".jpg", birdseye(under, self._grid), [cv2.IMWRITE_JPEG_QUALITY,
                                                                          self.config.jpeg_quality])
            if ok:
                self.stream.log("birdseye", rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg"))

    def _log_scalars(self) -> None:
        while self._scalars:
            kind, stamp_ns, item = self._scalars.popleft()
            if kind == "line":
                entity, points, colour = item
                self.stream.log(entity, rr.LineStrips3D([points], colors=[colour]), static=True)
                continue
            self._time(stamp_ns)
            if kind == "points":
                camera, pixels, points = item
                self.stream.log(f"cameras/{camera}/inliers", rr.Points2D(pixels * self.config.image_scale,
                                                                          colors=[(255, 200, 0)], radii=2.0))
                self.stream.log("world/points", rr.Points3D(points, colors=[(120, 180, 255)], radii=0.03))
            elif kind == "command":
                for key in ("steer_rad", "throttle", "brake"):
                    self._scalar(f"commands/{key}", stamp_ns, getattr(item, key))
            elif kind == "outputs":
                for topic, values in item.items():
                    self._log_topic(stamp_ns, topic, values)
            elif kind == "can":
                self._log_can(stamp_ns, *item)
            elif kind == "scan":  # a top view: the sensor's front up, its left to the left
                name, scan = item
                points = scan.points_m()
                self.stream.log(f"lidar/{name}", rr.Points2D(np.column_stack([-points[:, 1], -points[:, 0]]),
                                                             colors=[(255, 80, 80)], radii=0.03))
                mount = self.lidars.get(name)
                if self._grid is not None and mount is not None:
                    self.stream.log(f"birdseye/{name}", rr.Points2D(
                        scan_on_birdseye(points, mount, self._grid), colors=[(255, 80, 80)], radii=2.0))

    def _scalar(self, entity: str, stamp_ns: int, value: float) -> None:
        """A number of a time series, sent with the others of its entity in one column every
        ``SCALAR_BATCH`` values: one call to Rerun per value held the interpreter long enough to slow the loop."""
        stamps, values = self._series.setdefault(entity, ([], []))
        stamps.append(stamp_ns)
        values.append(value)
        if len(values) >= self.SCALAR_BATCH:
            self._send_series(entity)

    def _send_series(self, entity: str) -> None:
        stamps, values = self._series.pop(entity)
        self.stream.send_columns(entity, indexes=[rr.TimeColumn("stamp", timestamp=np.array(stamps, "datetime64[ns]"))],
                                 columns=rr.Scalars.columns(scalars=np.asarray(values, float)))

    def _log_topic(self, stamp_ns: int, topic: str, values: Mapping[str, float | int | str]) -> None:
        texts = []
        for key, value in values.items():
            if isinstance(value, str):
                texts.append(f"{key}: {value}")
            elif math.isfinite(value):
                self._scalar(f"outputs/{topic}/{key}", stamp_ns, float(value))
        text = ", ".join(texts)
        if texts and self._text.get(topic) != text:  # a state change, not a line per frame
            self._text[topic] = text
            self.stream.log(f"events/{topic}", rr.TextLog(text))
        if topic == "lanes" and "left_x_bottom_px" in values:
            self._log_lanes(values)
        if topic == "pose" and "x_m" in values:
            point = [float(values.get(k, 0.0)) for k in ("x_m", "y_m", "z_m")]
            if all(math.isfinite(v) for v in point):
                self.stream.log("world/estimate", rr.Points3D([point], colors=[(255, 120, 0)], radii=0.05))

    def _log_lanes(self, values: Mapping[str, float | int | str]) -> None:
        scale = self.config.image_scale
        strips = []
        for side in ("left", "right"):
            ends = [values.get(f"{side}_{k}_px") for k in ("x_bottom", "y_bottom", "x_top", "y_top")]
            if all(isinstance(v, (int, float)) and math.isfinite(v) for v in ends):
                xb, yb, xt, yt = (float(v) * scale for v in ends)  # type: ignore[arg-type]
                strips.append([[xb, yb], [xt, yt]])
        self.stream.log("cameras/center/lanes", rr.LineStrips2D(strips, colors=[(0, 255, 0)], radii=1.5))
        meet = (values.get("intersection_x_px"), values.get("intersection_y_px"))
        if all(isinstance(v, (int, float)) and math.isfinite(v) for v in meet):
            self.stream.log("cameras/center/lanes/meeting_point", rr.Points2D(
                [[float(meet[0]) * scale, float(meet[1]) * scale]], colors=[(255, 0, 255)], radii=4.0))  # type: ignore[arg-type]

    def _log_can(self, stamp_ns: int, arbitration_id: int, data: bytes, direction: str) -> None:
        message = None
        if self.database is not None:
            try:
                message = self.database.get_message_by_frame_id(arbitration_id)
            except KeyError:
                message = None
        if message is None:
            self._scalar(f"can/raw/{arbitration_id:#x}", stamp_ns, float(len(data)))
            return
        try:
            signals = message.decode(data, decode_choices=False)
        except Exception:  # a frame the DBC cannot decode is shown raw
            signals = None
        if not isinstance(signals, dict):
            self._scalar(f"can/raw/{arbitration_id:#x}", stamp_ns, float(len(data)))
            return
        for signal, value in signals.items():
            if isinstance(value, (int, float)):
                self._scalar(f"can/{message.name}/{signal}", stamp_ns, float(value))


def birdseye_view_grid(camera: PinholeCamera | None, config: ViewConfig) -> BirdseyeGrid | None:
    """The ``birdseye`` view's grid through ``camera`` (None where there is no such camera, or it has no mount)."""
    if camera is None or camera.pose_body_cam_array[2, 3] <= 0:
        return None
    return birdseye_grid(camera, -config.birdseye_behind_m, config.birdseye_ahead_m, config.birdseye_side_m,
                         config.birdseye_resolution_m)


def scan_on_birdseye(points_m: np.ndarray, mount: LidarMount, grid: BirdseyeGrid) -> np.ndarray:
    """(M, 2) pixels of the bird's-eye view where a sweep's returns (``points_m``, in the sensor's frame) lie."""
    body = mount.to_body(points_m)
    return (np.column_stack([body, np.ones(len(body))]) @ grid.pixel_from_body.T)[:, :2]


def view_recording(folder: str | Path, target: str | Path, config: ViewConfig = ViewConfig(),
                   database: cantools.database.can.Database | None = None) -> int:
    """Feed the recording at ``folder`` (its frames, commands, outputs, CAN traffic and ground truth) to a
    :class:`RerunView` at ``target``, in time order; returns the number of sets. A file is written whole or not
    at all."""
    reader = RecordingReader(folder)
    live = str(target) == LIVE
    partial = Path(target).with_name(f".{Path(target).name}.partial") if not live else Path(target)
    view = RerunView(partial if not live else LIVE, reader.cameras, config, database, name=Path(folder).name,
                     drop_when_full=False, lidars=reader.lidars)
    sets: dict[int, dict[str, Path]] = {}
    done = False
    try:
        for name in reader.cameras:
            for stamp, path in reader.frames(name):
                sets.setdefault(stamp, {})[name] = path
        events: list[tuple[int, int, Any]] = [(stamp, 0, paths) for stamp, paths in sets.items()]
        events += [(c.stamp_ns, 1, c) for c in reader.commands()]
        rows: dict[int, dict[str, dict[str, Any]]] = {}
        for topic in reader.output_topics():
            for row in reader.outputs(topic):
                rows.setdefault(int(row["stamp_ns"]), {})[topic] = {k: v for k, v in row.items() if k != "stamp_ns"}
        events += [(stamp, 2, topics) for stamp, topics in rows.items()]
        events += [(stamp, 3, (i, d, direction)) for stamp, direction, i, d in reader.can_frames()]
        events += [(scan.stamp_ns, 4, (name, scan)) for name in reader.lidars for scan in reader.scans(name)]
        for index, (stamp, kind, item) in enumerate(sorted(events, key=lambda e: (e[0], e[1]))):
            if kind == 0:
                images = {name: read_image(path, cv2.IMREAD_UNCHANGED) for name, path in item.items()}
                view.write_frames(FrameSet(index, stamp, images))
            elif kind == 1:
                view.send(item)
            elif kind == 2:
                view.write_outputs(stamp, item)
            elif kind == 3:
                view.write_can(stamp, *item)
            else:  # a sweep, on its own (the frames' sets are the images')
                view.write_frames(FrameSet(index, stamp, {}, scans={item[0]: item[1]}))
        truth = reader.body_poses()
        if truth is not None:
            view.write_groundtruth(truth)
        done = True
    finally:
        view.close()
        if not live:
            if done:
                os.replace(partial, target)
            else:
                partial.unlink(missing_ok=True)
    return len(sets)

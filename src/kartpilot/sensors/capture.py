"""Live cameras: one capture thread per camera, grouped into synchronised frame sets.

Each :class:`CameraThread` opens its camera through OpenCV (V4L2 on Linux) with the size of its
calibration and the rig's :class:`~kartpilot.core.camera.CaptureSettings`, and stamps every frame
with the host's monotonic clock the moment ``grab`` returns it (OpenCV does not expose the
driver's own buffer time). A short ring of recent frames is kept per camera.

:class:`LiveFrameSource` serves the same ``read() -> FrameSet`` as a recording or the simulator:
it waits for the next frame of the reference camera and joins to it, from every other camera,
the unused frame nearest in time within ``sync_tolerance_ms``. A camera without such a frame is
left out of the set (never its old image again), the skew of every set is measured, and a
:class:`~kartpilot.sensors.health.CameraWatchdog` reports a camera that stops delivering or
delivers black, blank or frozen frames within its timeout. Frozen frames (the driver repeating
a buffer) are left out of the set too.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.calibration.rig import Rig
from kartpilot.core.camera import CaptureSettings
from kartpilot.core.errors import ConfigError, SensorError
from kartpilot.core.types import FrameSet, Image
from kartpilot.sensors.health import CameraWatchdog, HealthConfig

__all__ = ["CameraThread", "LiveConfig", "LiveFrameSource", "nearest_within", "open_capture"]

log = logging.getLogger(__name__)

Clock = Callable[[], int]


class VideoCaptureLike(Protocol):
    """What kartpilot uses of ``cv2.VideoCapture`` (tests pass a fake)."""

    def isOpened(self) -> bool: ...
    def grab(self) -> bool: ...
    def retrieve(self) -> tuple[bool, Any]: ...
    def get(self, prop: int) -> float: ...
    def release(self) -> None: ...


Opener = Callable[[CaptureSettings, int, int], VideoCaptureLike]


@dataclass(frozen=True)
class LiveConfig:
    """Attributes:
        reference_camera: the camera whose frames set the pace and the sets' times (default: the first).
        sync_tolerance_ms: another camera's frame joins a set when captured within this of the reference's.
        wait_s: ``read`` waits this long for the reference camera before it delivers a set without it.
        ring_frames: recent frames kept per camera for the matching.
        reopen_after_s: a camera that has delivered nothing for this long is closed and opened again
            (a USB camera that dropped off the bus).
        health: what counts as a bad frame, and how long a camera may go without a good one.
    """

    reference_camera: str = ""
    sync_tolerance_ms: float = 15.0
    wait_s: float = 0.2
    ring_frames: int = 4
    reopen_after_s: float = 1.0
    health: HealthConfig = field(default_factory=HealthConfig)

    def __post_init__(self) -> None:
        if self.sync_tolerance_ms <= 0 or self.wait_s <= 0 or self.ring_frames < 1 or self.reopen_after_s <= 0:
            raise ConfigError("live: sync_tolerance_ms, wait_s, reopen_after_s and ring_frames must be positive")


def _is_file(device: str) -> bool:
    return not device.isdigit() and not device.startswith("/dev/") and Path(device).is_file()


def open_capture(settings: CaptureSettings, width_px: int, height_px: int) -> cv2.VideoCapture:
    """Open a camera (or a video file) and ask for the size, rate, pixel format and exposure."""
    device = settings.device
    if _is_file(device):
        return cv2.VideoCapture(device)
    backend = cv2.CAP_V4L2 if sys.platform.startswith("linux") else cv2.CAP_ANY
    capture = cv2.VideoCapture(int(device) if device.isdigit() else device, backend)
    if not capture.isOpened():
        return capture
    capture.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*settings.fourcc))
    capture.set(cv2.CAP_PROP_FRAME_WIDTH, width_px)
    capture.set(cv2.CAP_PROP_FRAME_HEIGHT, height_px)
    capture.set(cv2.CAP_PROP_FPS, settings.fps)
    capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # the newest frame, not one queued in the driver
    if settings.exposure is None:
        capture.set(cv2.CAP_PROP_AUTO_EXPOSURE, 3)  # V4L2: aperture priority (auto)
    else:
        capture.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)  # V4L2: manual
        capture.set(cv2.CAP_PROP_EXPOSURE, settings.exposure)
    return capture


def nearest_within(reference_ns: int, stamps: Sequence[int] | NDArray[np.int64], tolerance_ns: int) -> int | None:
    """The index of the stamp nearest ``reference_ns``, if it is within ``tolerance_ns``."""
    if len(stamps) == 0:
        return None
    distances = np.abs(np.asarray(stamps, np.int64) - reference_ns)
    best = int(np.argmin(distances))
    return best if distances[best] <= tolerance_ns else None


@dataclass(frozen=True)
class _Frame:
    seq: int
    stamp_ns: int
    image: Image


class CameraThread:
    """One camera's capture thread and its ring of recent frames."""

    def __init__(self, name: str, settings: CaptureSettings, width_px: int, height_px: int,
                 arrived: threading.Condition, config: LiveConfig, opener: Opener = open_capture,
                 clock: Clock = time.monotonic_ns) -> None:
        self.name, self.settings = name, settings
        self.size_wh = (width_px, height_px)
        self.config = config
        self._opener, self._clock = opener, clock
        self._arrived = arrived
        self.ring: deque[_Frame] = deque(maxlen=config.ring_frames)
        self.frames = 0
        self.failures = 0
        self.reopens = 0
        self.ended = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._capture: VideoCaptureLike | None = None
        self._is_file = _is_file(settings.device)

    def _open(self) -> VideoCaptureLike:
        capture = self._opener(self.settings, *self.size_wh)
        if not capture.isOpened():
            raise SensorError(f"camera {self.name}: cannot open {self.settings.device}")
        size = (round(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), round(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        if size != self.size_wh:
            capture.release()
            raise SensorError(f"camera {self.name} ({self.settings.device}) delivers {size[0]}x{size[1]}, but the "
                              f"rig's calibration is for {self.size_wh[0]}x{self.size_wh[1]}")
        return capture

    def start(self) -> None:
        """Open the camera (errors are raised here, not in the thread) and start capturing."""
        self._capture = self._open()
        self._thread = threading.Thread(target=self._run, name=f"camera-{self.name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        period_ns = round(1e9 / self.settings.fps)
        next_ns = self._clock()
        last_good_ns = next_ns
        seq = 0
        while not self._stop.is_set():
            capture = self._capture
            if capture is None:
                break
            if self._is_file:  # a file delivers as fast as it is read: pace it like the camera it stands for
                delay = (next_ns - self._clock()) * 1e-9
                if delay > 0:
                    time.sleep(delay)
                next_ns += period_ns
            ok = capture.grab()
            stamp = self._clock()
            image = capture.retrieve()[1] if ok else None
            if image is not None and image.size:
                seq += 1
                last_good_ns = stamp
                with self._arrived:
                    self.ring.append(_Frame(seq, stamp, image))
                    self.frames += 1
                    self._arrived.notify_all()
                continue
            self.failures += 1
            if self._is_file:
                break  # the end of the file
            if (stamp - last_good_ns) * 1e-9 > self.config.reopen_after_s:
                self._reopen()
                last_good_ns = self._clock()
            else:
                time.sleep(0.01)
        with self._arrived:
            self.ended = True
            self._arrived.notify_all()

    def _reopen(self) -> None:
        log.warning("camera %s delivered nothing for %.1f s: opening it again", self.name, self.config.reopen_after_s)
        if self._capture is not None:
            self._capture.release()
        self.reopens += 1
        try:
            self._capture = self._open()
        except SensorError as exc:
            log.warning("%s", exc)
            self._capture = _Closed()
            time.sleep(min(self.config.reopen_after_s, 0.5))

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._capture is not None:
            self._capture.release()


class _Closed:
    """A camera that could not be opened again: it delivers nothing until the next attempt."""

    def isOpened(self) -> bool:
        return False

    def grab(self) -> bool:
        return False

    def retrieve(self) -> tuple[bool, Any]:
        return False, None

    def get(self, prop: int) -> float:
        return 0.0

    def release(self) -> None:
        pass


class LiveFrameSource:
    """Live cameras as a frame source. ``start`` opens them all (or raises, opening none)."""

    def __init__(self, rig: Rig, config: LiveConfig | None = None, cameras: Sequence[str] | None = None,
                 opener: Opener = open_capture, clock: Clock = time.monotonic_ns) -> None:
        self.config = config or LiveConfig()
        names = list(cameras) if cameras else list(rig.capture)
        if not names:
            raise ConfigError("the rig file says how to open none of its cameras (add capture: {device: ...})")
        for name in names:
            rig.camera(name)
            if name not in rig.capture:
                raise ConfigError(f"the rig file says nothing on how to open camera {name!r} "
                                  "(capture: {device: ...})")
        self.reference = self.config.reference_camera or names[0]
        if self.reference not in names:
            raise ConfigError(f"live.reference_camera {self.reference!r} is not one of {', '.join(names)}")
        self._arrived = threading.Condition()
        self._clock = clock
        self.threads = {name: CameraThread(name, rig.capture[name], rig.cameras[name].width_px,
                                           rig.cameras[name].height_px, self._arrived, self.config, opener, clock)
                        for name in names}
        self.watchdog = CameraWatchdog(names, self.config.health)
        self._used = dict.fromkeys(names, 0)
        self._index = 0
        self._problems: dict[str, str] = {}
        self.skews_ns: list[int] = []
        self.incomplete_sets = 0

    def start(self) -> LiveFrameSource:
        started: list[CameraThread] = []
        try:
            for thread in self.threads.values():
                thread.start()
                started.append(thread)
        except BaseException:
            for thread in started:
                thread.stop()
            raise
        return self

    def __enter__(self) -> LiveFrameSource:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        for thread in self.threads.values():
            thread.stop()

    @property
    def problems(self) -> dict[str, str]:
        """The cameras in trouble as of the last set, with the reason."""
        return dict(self._problems)

    def _unused(self, name: str) -> list[_Frame]:
        return [f for f in self.threads[name].ring if f.seq > self._used[name]]

    def read(self) -> FrameSet | None:
        """The next synchronised set; None once every camera has ended (a file at its end)."""
        tolerance_ns = round(self.config.sync_tolerance_ms * 1e6)
        reference = self.threads[self.reference]
        with self._arrived:
            self._arrived.wait_for(lambda: bool(self._unused(self.reference)) or reference.ended,
                                   timeout=self.config.wait_s)
            fresh = self._unused(self.reference)
            if not fresh and all(t.ended for t in self.threads.values()):
                return None
            stamp = fresh[-1].stamp_ns if fresh else self._clock()
            others = [n for n in self.threads if n != self.reference]
            # give the other cameras until the tolerance has passed to deliver their frame of this moment

            def complete() -> bool:
                return all(self.threads[n].ended or any(f.stamp_ns >= stamp - tolerance_ns for f in self._unused(n))
                           for n in others)

            remaining = (stamp + tolerance_ns - self._clock()) * 1e-9
            if remaining > 0:
                self._arrived.wait_for(complete, timeout=remaining)
            chosen: dict[str, _Frame] = {}
            for name in self.threads:
                candidates = self._unused(name)
                best = nearest_within(stamp, [f.stamp_ns for f in candidates], tolerance_ns)
                if best is not None:
                    chosen[name] = candidates[best]
                    self._used[name] = candidates[best].seq  # this frame and the older ones are spent
        images = {name: frame.image for name, frame in chosen.items()}
        capture = {name: frame.stamp_ns for name, frame in chosen.items()}
        frames = FrameSet(self._index, stamp, images, capture)
        problems = self.watchdog.check(frames)
        frozen = [n for n, p in self.watchdog.frame_problems.items() if p == "frozen" and n in images]
        if frozen:  # a repeated buffer is not a new frame
            frames = FrameSet(self._index, stamp, {n: i for n, i in images.items() if n not in frozen},
                              {n: c for n, c in capture.items() if n not in frozen})
        for name in problems.keys() - self._problems.keys():
            log.warning("camera %s: %s", name, problems[name])
        for name in self._problems.keys() - problems.keys():
            log.warning("camera %s delivers good frames again", name)
        self._problems = problems
        if len(frames.images) < len(self.threads):
            self.incomplete_sets += 1
        if len(capture) > 1:
            self.skews_ns.append(max(capture.values()) - min(capture.values()))
        self._index += 1
        return frames

    def stats(self) -> dict[str, Any]:
        """Frames and failures per camera, incomplete sets, and the sets' skew (ms)."""
        skew = np.asarray(self.skews_ns, float) * 1e-6
        return {
            "cameras": {name: {"frames": t.frames, "failures": t.failures, "reopens": t.reopens}
                        for name, t in self.threads.items()},
            "sets": self._index, "incomplete_sets": self.incomplete_sets,
            "skew_ms": ({"median": round(float(np.median(skew)), 3), "p99": round(float(np.percentile(skew, 99)), 3),
                         "max": round(float(skew.max()), 3)} if len(skew) else None),
            "problems": self.problems,
        }

"""Replay from files: one image, a folder of images, a video, a kartpilot recording or a Donkey Car tub,
all as frame sets with one camera (``center``), so a pipeline cannot tell them apart; a recording's
cameras as a frame source (:class:`RecordingFrameSource`), and its stereo pair rectified
(:class:`StereoReplaySource`). A frame that cannot be read is left out of its set and counted, as a
live camera that skipped a frame would be."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2

from kartpilot.core.errors import DataError, KartpilotError, RecordingError
from kartpilot.core.images import read_image
from kartpilot.core.types import FrameSet, LaserScan
from kartpilot.record.recording import RecordingReader, RecordingStereoSource
from kartpilot.sensors.donkeycar import DonkeyTub, is_donkey_tub

__all__ = ["IMAGE_SUFFIXES", "VIDEO_SUFFIXES", "RecordingFrameSource", "ScanReplay", "StereoReplaySource",
           "open_frames"]

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}
VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".webm"}


def open_frames(path: str | Path, camera: str = "center", left_out: list[str] | None = None
                ) -> tuple[str, Iterator[FrameSet]]:
    """(kind, frames) for whatever ``path`` holds. A recording gives its ``camera`` (or its first one).

    ``left_out``: where given, an image of a folder that cannot be read (cut off, empty, not an image) is left
    out and named there with the reason, and the folder's other images are read (one bad photo among hundreds
    does not lose the rest); the frame indices stay the images' places in the folder. Where not given, it
    raises :class:`DataError`, as a single image that cannot be read always does."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"input not found: {path}")
    if path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES:
        return "image", _images([path])
    if path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES:
        return "video", _video(path)
    if path.is_dir() and is_donkey_tub(path):
        return "donkeycar-tub", DonkeyTub(path).frames()
    if path.is_dir() and (path / "manifest.json").is_file():
        reader = RecordingReader(path)
        name = camera if camera in reader.cameras else next(iter(reader.cameras))
        return "recording", _recording(reader, name)
    if path.is_dir():
        images = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not images:
            raise DataError(f"no images in {path}")
        return "folder", _images(images, left_out)
    raise DataError(f"cannot read {path}: not an image, a video, a recording, a tub or a folder of images")


def _images(paths: list[Path], left_out: list[str] | None = None) -> Iterator[FrameSet]:
    read = 0
    for k, path in enumerate(paths):
        try:
            image = read_image(path)
        except DataError as exc:
            if left_out is None:
                raise
            left_out.append(f"{path.name}: {exc}")
            continue
        read += 1
        yield FrameSet(k, k, {"center": image}, name=path.name)
    if read == 0 and left_out:
        raise DataError(f"none of the {len(paths)} images in {paths[0].parent} can be read (the first: "
                        f"{left_out[0]})")


def _video(path: Path) -> Iterator[FrameSet]:
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise DataError(f"cannot open the video {path}")
    fps = capture.get(cv2.CAP_PROP_FPS) or 30.0
    k = 0
    try:
        while True:
            ok, image = capture.read()
            if not ok:
                break
            yield FrameSet(k, int(k * 1e9 / fps), {"center": image})
            k += 1
    finally:
        capture.release()
    if k == 0:
        raise DataError(f"the video {path} has no frames")


def _recording(reader: RecordingReader, camera: str) -> Iterator[FrameSet]:
    """The camera's frames; in a recording that was not closed (a killed drive), a frame that cannot be read is
    left out with a warning: everything flushed is kept, as the recording's format promises."""
    k = 0
    scans = ScanReplay(reader)
    for stamp, path in reader.frames(camera):
        try:
            image = read_image(path)
        except DataError as exc:
            if reader.closed:
                raise DataError(f"cannot read the recording's frame {path}: {exc}") from None
            log.warning("%s was not closed properly: left out %s (%s)", reader.folder, path.name, exc)
            continue
        yield FrameSet(k, stamp, {"center": image}, name=path.name, scans=scans.until(stamp))
        k += 1


class ScanReplay:
    """A recording's LiDAR sweeps handed out with the frame sets as they were recorded: each set gets the latest
    sweep of each LiDAR that began at or before its time and after the set before's."""

    def __init__(self, reader: RecordingReader) -> None:
        self._scans = {name: reader.scans(name) for name in reader.lidars}
        self._next = dict.fromkeys(self._scans, 0)

    def until(self, stamp_ns: int) -> dict[str, LaserScan]:
        out = {}
        for name, scans in self._scans.items():
            k = self._next[name]
            while k < len(scans) and scans[k].stamp_ns <= stamp_ns:
                out[name] = scans[k]
                k += 1
            self._next[name] = k
        return out


class RecordingFrameSource:
    """A recording's cameras as a frame source: one set per recorded set time, images as stored."""

    def __init__(self, folder: str | Path, cameras: Sequence[str] | None = None) -> None:
        self.reader = RecordingReader(folder)
        names = list(cameras) if cameras else list(self.reader.cameras)
        sets: dict[int, dict[str, tuple[Path, int]]] = {}
        for name in names:
            stamps, captures = self.reader.frames(name), self.reader.capture_stamps(name)
            for (stamp, path), capture in zip(stamps, captures, strict=True):
                sets.setdefault(stamp, {})[name] = (path, capture)
        if not sets:
            raise RecordingError(f"recording {self.reader.folder} has no frames of {', '.join(names)}")
        self._sets = sorted(sets.items())
        self.cameras = names
        self.unreadable = 0
        self._next = 0
        self._scans = ScanReplay(self.reader)

    def __len__(self) -> int:
        return len(self._sets)

    def read(self) -> FrameSet | None:
        if self._next >= len(self._sets):
            return None
        index, self._next = self._next, self._next + 1
        stamp, members = self._sets[index]
        images, capture = {}, {}
        for name, (path, capture_ns) in members.items():
            try:
                image = read_image(path, cv2.IMREAD_UNCHANGED)
            except DataError as exc:
                self.unreadable += 1
                log.warning("frame %s of %s unreadable: %s", path.name, name, exc)
                continue
            images[name], capture[name] = image, capture_ns
        return FrameSet(index, stamp, images, capture, scans=self._scans.until(stamp))


class StereoReplaySource:
    """A recording's stereo pair as a frame source: frame sets keyed by the pair's camera names.

    A pair that cannot be read is delivered without its images, so the pipeline bridges it
    as it would a camera that skipped a frame.
    """

    def __init__(self, folder: str | Path) -> None:
        self.stereo = RecordingStereoSource(folder)
        pair = self.stereo.reader.stereo_pair
        assert pair is not None  # RecordingStereoSource checked
        self.left_name, self.right_name = pair
        self.unreadable = 0
        self._next = 0
        self._scans = ScanReplay(self.stereo.reader)

    def read(self) -> FrameSet | None:
        if self._next >= len(self.stereo):
            return None
        index, self._next = self._next, self._next + 1
        try:
            frame = self.stereo.frame(index)
        except KartpilotError as exc:
            self.unreadable += 1
            log.warning("frame %d of %s unreadable: %s", index, self.stereo.name, exc)
            stamp = self.stereo.stamp_ns(index)
            return FrameSet(index, stamp, {}, scans=self._scans.until(stamp))
        return FrameSet(index, frame.stamp_ns, {self.left_name: frame.left, self.right_name: frame.right},
                        scans=self._scans.until(frame.stamp_ns))

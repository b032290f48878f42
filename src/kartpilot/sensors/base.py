"""The one interface every stereo frame source serves.

A KITTI sequence, a EuRoC sequence, a kartpilot recording, the simulator and a
live camera pair all yield :class:`~kartpilot.core.types.StereoFrame` objects
with rectified images, so the pipeline cannot tell them apart.
"""

from __future__ import annotations

import abc
import queue
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TypeVar, cast

import cv2
import numpy as np

from kartpilot.core.camera import StereoRig
from kartpilot.core.errors import DataError, KartpilotError
from kartpilot.core.trajectory import Trajectory
from kartpilot.core.types import FrameSet, Image, StereoFrame

__all__ = ["StereoSource", "read_ahead", "read_gray", "read_image"]

T = TypeVar("T")


class StereoSource(abc.ABC):
    """A finite, indexable sequence of rectified stereo frames."""

    name: str = "stereo"

    @property
    @abc.abstractmethod
    def rig(self) -> StereoRig:
        """The rectified rig the frames were taken with."""

    @abc.abstractmethod
    def __len__(self) -> int: ...

    @abc.abstractmethod
    def frame(self, index: int) -> StereoFrame:
        """Load frame ``index`` (0-based). Raises DataError if it cannot be read."""

    def ground_truth(self) -> Trajectory | None:
        """Left-camera poses (camera to world of the first frame) when the source has them."""
        return None

    def __iter__(self) -> Iterator[StereoFrame]:
        for index in range(len(self)):
            yield self.frame(index)

    def frame_sets(self, cameras: tuple[str, str] = ("left", "right"), stride: int = 1) -> Iterator[FrameSet | int]:
        """Every frame (every ``stride``-th: the same drive at larger steps) as a frame set of the two named
        cameras; a frame that cannot be read is its bare index (for VO to bridge and count, or an importer to leave
        out)."""
        for index in range(0, len(self), stride):
            try:
                frame = self.frame(index)
            except KartpilotError:
                yield index
                continue
            yield frame.as_frame_set(*cameras)


def read_ahead(items: Iterable[T], depth: int = 2) -> Iterator[T]:
    """``items`` as they come, the next ``depth`` of them read in a thread while the caller works on the current
    one: a dataset's frames are decoded from disk (two 1226x370 PNGs of KITTI, about 9 ms) while VO runs on the
    last (OpenCV's decoding lets go of the interpreter), so the two take the time of the longer, not of both. An
    error in reading is raised here, at the item it stopped at; when the caller stops early, the thread stops."""
    if depth < 1:
        raise ValueError(f"read_ahead needs a depth of at least 1, got {depth}")
    ready: queue.Queue[tuple[str, object]] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(kind: str, value: object) -> bool:
        while not stop.is_set():
            try:
                ready.put((kind, value), timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def read() -> None:
        try:
            for item in items:
                if not put("item", item):
                    return
        except BaseException as exc:  # handed to the caller, raised there
            put("error", exc)
            return
        put("end", None)

    thread = threading.Thread(target=read, name="read-ahead", daemon=True)
    thread.start()
    try:
        while True:
            kind, value = ready.get()
            if kind == "end":
                return
            if kind == "error":
                assert isinstance(value, BaseException)
                raise value
            yield cast(T, value)
    finally:
        stop.set()
        thread.join(timeout=5.0)


def read_gray(path: str | Path) -> Image:
    """Read an image as 8-bit grayscale; a missing, corrupt or empty file raises DataError."""
    return read_image(path, cv2.IMREAD_GRAYSCALE)


MIN_IMAGE_PX = 32
"""The smallest side an image may have (a Donkey Car's camera gives 160x120): below it no pipeline has a region of
interest to look at, and OpenCV's resizing and HOG fail inside (one crashed the process)."""


def read_image(path: str | Path, flags: int = cv2.IMREAD_COLOR) -> Image:
    """Read an image (BGR by default; OpenCV's ``flags``); a missing, corrupt, cut-off, empty or tiny (under
    :data:`MIN_IMAGE_PX` a side) file raises DataError. A JPEG or PNG cut off in its writing (a full disk, a copy
    stopped half-way) still decodes in OpenCV, with its lower part grey, so its end marker is checked first."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"image not found: {path}")
    if path.stat().st_size == 0:  # OpenCV asserts on an empty buffer rather than returning None
        raise DataError(f"the image {path} is empty (0 bytes)")
    _check_complete(path)
    # decoded from its bytes: OpenCV's own reader fails on a file name that is not valid UTF-8
    image = cv2.imdecode(np.fromfile(path, np.uint8), flags)
    if image is None or image.size == 0:
        raise DataError(f"cannot read image (corrupt or not an image): {path}")
    if min(image.shape[:2]) < MIN_IMAGE_PX:
        raise DataError(f"the image {path} is {image.shape[1]}x{image.shape[0]} px: too small for a camera's view "
                        f"(at least {MIN_IMAGE_PX} px a side)")
    return image


def _check_complete(path: Path) -> None:
    """A JPEG must end with its end-of-image marker, a PNG with its IEND chunk (a few padding bytes allowed)."""
    with path.open("rb") as f:
        head = f.read(8)
        f.seek(0, 2)
        size = f.tell()
        f.seek(max(size - 64, 0))
        tail = f.read()
    if head[:3] == b"\xff\xd8\xff" and b"\xff\xd9" not in tail.rstrip(b"\x00\r\n ")[-4:]:
        raise DataError(f"the JPEG {path} is cut off: it has no end-of-image marker")
    if head == b"\x89PNG\r\n\x1a\n" and b"IEND" not in tail[-16:]:
        raise DataError(f"the PNG {path} is cut off: it has no IEND chunk")

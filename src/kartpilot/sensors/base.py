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
from typing import TypeVar, cast

from kartpilot.core.camera import StereoRig
from kartpilot.core.errors import KartpilotError
from kartpilot.core.images import MIN_IMAGE_PX, read_gray, read_image
from kartpilot.core.trajectory import Trajectory
from kartpilot.core.types import FrameSet, StereoFrame

__all__ = ["MIN_IMAGE_PX", "StereoSource", "read_ahead", "read_gray", "read_image"]

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



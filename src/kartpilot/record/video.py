"""H.264 video files of what a pipeline saw, written through the ffmpeg that imageio-ffmpeg ships in its wheel.

OpenCV's own writer only has MPEG-4 part 2 (``mp4v``) in its pip wheels: about 2 MB per second of a
960x540 drive, where H.264 at the same look is a tenth of that. The file is written under a temporary
name and moved into place when closed, so a run that ends early leaves either the whole video of what it
drove or none, never a file a player cannot open.
"""

from __future__ import annotations

import os
from collections.abc import Generator
from pathlib import Path
from typing import Any

import imageio_ffmpeg
import numpy as np

from kartpilot.core.errors import RecordingError
from kartpilot.core.types import Image

__all__ = ["VideoFile"]


class VideoFile:
    """An H.264 MP4 file, one BGR (or grey) frame at a time.

    Args:
        path: the file to write (``.mp4``).
        fps: the frame rate it plays at.
        size_wh: the frames' width and height; frames of another size are refused. An odd size is padded by
            a pixel (H.264's chroma needs even sizes).
        crf: the constant rate factor (x264: 18 looks lossless, 23 is its default, 28 is small and fine for a
            simulated drive).
    """

    def __init__(self, path: str | Path, fps: float, size_wh: tuple[int, int], crf: int = 28) -> None:
        self.path = Path(path)
        self.size_wh = size_wh
        self._even = (size_wh[0] + size_wh[0] % 2, size_wh[1] + size_wh[1] % 2)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._partial = self.path.with_name(f".{self.path.name}.partial.mp4")
        self.frames = 0
        self._writer: Generator[Any, Any, None] | None = imageio_ffmpeg.write_frames(
            str(self._partial), self._even, pix_fmt_in="bgr24", fps=fps, codec="libx264", quality=None,
            macro_block_size=2, ffmpeg_log_level="error",
            output_params=["-crf", str(crf), "-preset", "veryfast", "-movflags", "+faststart"])
        try:
            self._writer.send(None)  # starts ffmpeg
        except Exception as exc:  # imageio-ffmpeg raises plain OSError/RuntimeError
            self._writer = None
            raise RecordingError(f"cannot write the video {self.path}: {exc}") from exc

    def write(self, image: Image) -> None:
        """Append one frame (BGR, or grey that is shown as grey)."""
        if self._writer is None:
            raise RecordingError(f"the video {self.path} is closed")
        if image.shape[:2] != (self.size_wh[1], self.size_wh[0]):
            raise RecordingError(f"a frame of {image.shape[1]}x{image.shape[0]} for the video {self.path}, "
                                 f"which is {self.size_wh[0]}x{self.size_wh[1]}")
        frame = image if image.ndim == 3 else np.repeat(image[:, :, None], 3, axis=2)
        if self._even != self.size_wh:
            frame = np.pad(frame, ((0, self._even[1] - self.size_wh[1]), (0, self._even[0] - self.size_wh[0]), (0, 0)),
                           mode="edge")
        self._writer.send(np.ascontiguousarray(frame, dtype=np.uint8))
        self.frames += 1

    def close(self) -> None:
        """Finish the file and move it into place (a video without a frame is not kept)."""
        if self._writer is None:
            return
        writer, self._writer = self._writer, None
        writer.close()
        if self.frames == 0:
            self._partial.unlink(missing_ok=True)
            return
        os.replace(self._partial, self.path)

    def __enter__(self) -> VideoFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

"""What one drive session writes, whichever backend it runs on (simulator, replay, live)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

__all__ = ["SessionOutputs"]


@dataclass(frozen=True)
class SessionOutputs:
    """Attributes:
        record_dir: the recording (frames, commands, the pipeline's outputs, CAN traffic, result.json).
        result_path: the result JSON, besides the copy in the recording.
        video_path: the pipeline's view as a video.
        drive_log: the path follower's log, one row per step (path-following pipelines).
        progress: a progress bar on the terminal.
    """

    record_dir: str | Path | None = None
    result_path: str | Path | None = None
    video_path: str | Path | None = None
    drive_log: str | Path | None = None
    progress: bool = False

"""Recording the live cameras: every synchronised set goes to the recorder's writer threads, with the
cameras' health beside it (``outputs/health.csv``), until the time is up or the user stops it."""

from __future__ import annotations

import logging
import time
from typing import Any

from kartpilot.core.types import FrameSet
from kartpilot.record.recording import RecordingWriter
from kartpilot.sensors.capture import LiveFrameSource

__all__ = ["record_live"]

log = logging.getLogger(__name__)


def _health_row(frames: FrameSet, problems: dict[str, str]) -> dict[str, float | int | str]:
    captures = list(frames.capture_ns.values())
    skew_ms = (max(captures) - min(captures)) * 1e-6 if len(captures) > 1 else 0.0
    text = "; ".join(f"{name}: {reason}" for name, reason in sorted(problems.items()))
    return {"cameras": len(frames.images), "skew_ms": skew_ms, "problems": text.replace(",", " ")}


def record_live(source: LiveFrameSource, writer: RecordingWriter, duration_s: float | None = None) -> dict[str, Any]:
    """Record until ``duration_s`` has passed, the cameras end, or Ctrl-C. The writer is closed in every
    case, so the recording is complete and marked closed. Returns the source's statistics."""
    start = time.monotonic()
    how = "ended"
    try:
        with writer:
            while duration_s is None or time.monotonic() - start < duration_s:
                frames = source.read()
                if frames is None:
                    break
                writer.write_frames(frames)
                writer.write_output("health", frames.stamp_ns, _health_row(frames, source.problems))
            else:
                how = "duration reached"
    except KeyboardInterrupt:
        how = "stopped by the user"
    finally:
        source.close()
    stats = source.stats()
    stats.update(stopped=how, seconds=round(time.monotonic() - start, 2), written=dict(writer.frame_counts),
                 dropped=dict(writer.dropped), missing=dict(writer.missing))
    return stats

"""What a recording holds: duration, frames per camera, drops, synchronisation skew, commands."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

import numpy as np

from kartpilot.record.recording import RecordingReader
from kartpilot.sensors.health import summarise_sweeps

__all__ = ["recording_info"]


def _skew_ms(reference_ns: np.ndarray, other_ns: np.ndarray) -> tuple[float, float]:
    """(median, max) of each reference stamp's distance to the nearest stamp of the other camera, in ms."""
    if len(reference_ns) == 0 or len(other_ns) == 0:
        return float("nan"), float("nan")
    other = np.sort(other_ns)
    index = np.clip(np.searchsorted(other, reference_ns), 1, len(other) - 1) if len(other) > 1 else np.zeros(
        len(reference_ns), np.intp)
    nearest = np.minimum(np.abs(reference_ns - other[index]), np.abs(reference_ns - other[np.maximum(index - 1, 0)]))
    return float(np.median(nearest)) * 1e-6, float(np.max(nearest)) * 1e-6


def recording_info(reader: RecordingReader) -> dict[str, Any]:
    """A summary of the recording (what ``kartpilot recordings info`` prints)."""
    # each camera's own capture times: the skew within a synchronised set shows there
    stamps = {name: np.array(reader.capture_stamps(name), np.int64) for name in reader.cameras}
    every = np.concatenate([s for s in stamps.values() if len(s)] or [np.zeros(0, np.int64)])
    commands = reader.commands()
    command_stamps = np.array([c.stamp_ns for c in commands], np.int64)
    ends = [a for a in (every, command_stamps) if len(a)]
    start = min(int(a.min()) for a in ends) if ends else 0
    end = max(int(a.max()) for a in ends) if ends else 0
    dropped = reader.manifest.get("dropped_frames", {}) or {}
    missing = reader.manifest.get("missing_frames", {}) or {}
    cameras: dict[str, Any] = {}
    first = next(iter(stamps))
    for name, s in stamps.items():
        rate = (len(s) - 1) / ((s[-1] - s[0]) * 1e-9) if len(s) > 1 and s[-1] > s[0] else float("nan")
        entry: dict[str, Any] = {"frames": len(s), "rate_hz": round(rate, 2),
                                 "dropped": int(dropped.get(name, 0)) if isinstance(dropped, dict) else 0,
                                 "missing": int(missing.get(name, 0)) if isinstance(missing, dict) else 0}
        if name != first:
            median, worst = _skew_ms(stamps[first], s)
            entry["skew_to_" + first + "_ms"] = {"median": round(median, 3), "max": round(worst, 3)}
        cameras[name] = entry
    info: dict[str, Any] = {
        "folder": str(reader.folder), "closed": reader.closed, "write_error": reader.manifest.get("write_error"),
        "duration_s": round((end - start) * 1e-9, 3), "cameras": cameras,
        "stereo_pair": list(reader.stereo_pair) if reader.stereo_pair else None,
        "has_groundtruth": (reader.folder / "groundtruth.tum").is_file(),
        "commands": {"count": len(commands)},
        "outputs": {topic: len(reader.outputs(topic)) for topic in reader.output_topics()},
        "can_frames": len(reader.can_frames()),
        "lidars": {name: {**asdict(summarise_sweeps(reader.scans(name))), "mount": asdict(mount)}
                   for name, mount in reader.lidars.items()},
        "dropped_lines": int(reader.manifest.get("dropped_lines", 0) or 0),
        "metadata": reader.manifest.get("metadata", {}),
    }
    if commands:
        steer = np.array([c.steer_rad for c in commands])
        throttle = np.array([c.throttle for c in commands])
        brake = np.array([c.brake for c in commands])
        span = (command_stamps[-1] - command_stamps[0]) * 1e-9
        info["commands"].update({
            "rate_hz": round((len(commands) - 1) / span, 2) if span > 0 else None,
            "steer_rad": {"min": round(float(steer.min()), 4), "mean": round(float(steer.mean()), 4),
                          "max": round(float(steer.max()), 4)},
            "throttle_mean": round(float(throttle.mean()), 4),
            "braking_fraction": round(float(np.mean(brake > 0)), 4),
        })
    return info

"""A recording through the same pipeline code as live driving, its outputs written as a new recording.

Any pipeline of :mod:`kartpilot.runtime.pipelines`: ``lanes`` gets the recording's cameras, ``stereo-vo``
its rectified stereo pair (with a reference path to follow), ``mono-vo`` its centre camera (with a place
database, following the database's drive or a given reference). Nothing
moves: the commands go to a log and to the new recording, with the pipeline's outputs
(``outputs/<topic>.csv``) and, on request, the frames. The replay runs as fast as it can or, with
``realtime``, at the recorded pace. OpenCV's random generator (RANSAC) is seeded first, so two
replays of one recording give identical outputs.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from kartpilot.calibration.rectify import StereoSetup
from kartpilot.core.config import config_to_dict
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand, FrameSet, FrameSource
from kartpilot.core.vehicle import get_vehicle
from kartpilot.record.recording import RecordingReader, RecordingWriter
from kartpilot.record.replay import RecordingFrameSource, StereoReplaySource
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.loop import Outputs, Recorder, run_loop
from kartpilot.runtime.path_policy import write_drive_log
from kartpilot.runtime.pipelines import PIPELINES, PipelineContext, Route, StereoInput, build_pipeline, path_policy_of
from kartpilot.runtime.session import SessionOutputs

__all__ = ["ReplayResult", "recorded_rate_hz", "replay_recording"]

RNG_SEED = 0


@dataclass(frozen=True)
class ReplayResult:
    """What a replay did. ``commands`` are the pipeline's, one per set."""

    pipeline: str
    steps: int
    unreadable_frames: int
    missed_deadlines: int
    stage_ms: dict[str, float]
    commands: tuple[ActuatorCommand, ...]
    out: Path | None
    extra: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return {"pipeline": self.pipeline, "steps": self.steps, "unreadable_frames": self.unreadable_frames,
                "missed_deadlines": self.missed_deadlines, "out": str(self.out) if self.out else None, **self.extra,
                "stage_ms": {k: round(v, 3) for k, v in self.stage_ms.items()}}


class _CommandLog:
    """The command sink of a replay: nothing moves, the commands are kept."""

    def __init__(self) -> None:
        self.commands: list[ActuatorCommand] = []

    def send(self, command: ActuatorCommand) -> None:
        self.commands.append(command)


class _WithoutFrames:
    """A recorder that keeps the commands and outputs and leaves the frames (already recorded) out."""

    def __init__(self, writer: RecordingWriter) -> None:
        self.writer = writer

    def write_frames(self, frames: FrameSet) -> None:
        pass

    def send(self, command: ActuatorCommand) -> None:
        self.writer.send(command)

    def write_outputs(self, stamp_ns: int, outputs: Outputs) -> None:
        self.writer.write_outputs(stamp_ns, outputs)


class _Paced:
    """A source delivered at the pace it was recorded."""

    def __init__(self, source: FrameSource) -> None:
        self.source = source
        self._first: tuple[int, float] | None = None

    def read(self) -> FrameSet | None:
        frames = self.source.read()
        if frames is None:
            return None
        if self._first is None:
            self._first = (frames.stamp_ns, time.perf_counter())
        due = self._first[1] + (frames.stamp_ns - self._first[0]) * 1e-9
        delay = due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        return frames


def recorded_rate_hz(reader: RecordingReader, camera: str) -> float:
    """The camera's median frame rate in the recording."""
    stamps = np.array([s for s, _ in reader.frames(camera)], np.int64)
    if len(stamps) < 2:
        raise ConfigError(f"the recording has {len(stamps)} frame(s) of {camera}: too few to replay")
    return float(1e9 / np.median(np.diff(stamps)))


def replay_recording(folder: str | Path, pipeline: str, stack: StackConfig, route: Route | None = None,
                     vehicle: str | None = None, outputs: SessionOutputs | None = None, realtime: bool = False,
                     with_frames: bool = False) -> ReplayResult:
    """Push the recording at ``folder`` through ``pipeline``; write a new recording at ``outputs.record_dir``
    if given (with the frames too, ``with_frames``). The kart is the one the recording was made on
    (``vehicle`` overrides it, and names it where the recording does not say)."""
    if pipeline not in PIPELINES:
        raise ConfigError(f"unknown pipeline {pipeline!r} ({', '.join(PIPELINES)})")
    outputs = outputs or SessionOutputs()
    out, drive_log = outputs.record_dir, outputs.drive_log
    reader = RecordingReader(folder)
    name = vehicle or reader.vehicle
    if name is None:
        raise ConfigError(f"{folder} does not say which kart it was recorded on: give --vehicle (rc-kart, sdc-kart)")
    params = get_vehicle(name)
    cv2.setRNGSeed(RNG_SEED)
    source: StereoReplaySource | RecordingFrameSource
    stereo: StereoInput | None = None
    if pipeline == "stereo-vo":
        if reader.stereo_pair is None:
            raise ConfigError(f"{folder} has no stereo pair: the stereo-vo pipeline needs one")
        source = StereoReplaySource(folder)
        stereo = StereoInput((source.left_name, source.right_name),
                             StereoSetup(source.stereo.rig, None, source.stereo.pose_body_left))
        rate = recorded_rate_hz(reader, source.left_name)
    else:
        names = [stack.drive.mono.camera] if pipeline == "mono-vo" else list(reader.cameras)
        missing = [n for n in names if n not in reader.cameras]
        if missing:
            raise ConfigError(f"{folder} has no {', '.join(missing)} camera (it has {', '.join(reader.cameras)})")
        rate = recorded_rate_hz(reader, "center" if "center" in names else names[0])
        source = RecordingFrameSource(folder, names)
    context = PipelineContext(params, reader.cameras, rate, stack, stereo, route or Route())
    policy = build_pipeline(pipeline, context)
    path_policy = path_policy_of(policy)
    writer: RecordingWriter | None = None
    recorders: list[Recorder] = []
    if out is not None:
        stack_config = config_to_dict(stack)
        settings = {"lanes": {"lane_policy": stack_config["lane_policy"]},
                    "stereo-vo": {"stereo_vo": stack_config["stereo_vo"], "drive": stack_config["drive"]},
                    "mono-vo": {"mono_vo": stack_config["mono_vo"], "drive": stack_config["drive"]}}[pipeline]
        writer = RecordingWriter(out, reader.cameras, reader.stereo_pair, metadata={
            "source": "kartpilot replay", "replay_of": str(reader.folder), "pipeline": pipeline, "vehicle": params.name,
            "config": settings})
        recorders.append(writer if with_frames else _WithoutFrames(writer))
    sink = _CommandLog()
    try:
        stats = run_loop(_Paced(source) if realtime else source, policy, sink, recorders, period_s=1.0 / rate)
    finally:
        if path_policy is not None:
            path_policy.close()
            if drive_log is not None:
                write_drive_log(path_policy.samples, drive_log)
        if writer is not None:
            writer.close()
    stage_ms = stats.stage_ms()
    extra: dict[str, Any] = {"rate_hz": round(rate, 3), "stage_ms_percentiles": stats.stage_percentiles_ms()}
    if path_policy is not None:
        steps = max(stats.steps, 1)
        stage_ms.update({k: 1e3 * v / steps for k, v in path_policy.stage_s.items()})
        extra.update(stop_reason=path_policy.stop_reason, relocalised_frames=path_policy.localizer.relocalisations)
    result = ReplayResult(pipeline, stats.steps, source.unreadable, stats.missed_deadlines, stage_ms,
                          tuple(sink.commands), Path(out) if out is not None else None, extra)
    if out is not None:
        (Path(out) / "replay.json").write_text(json.dumps(result.to_json(), indent=2))
    return result

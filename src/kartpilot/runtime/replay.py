"""A recording through the same pipeline code as live driving, its outputs written as a new recording.

Where the drive recorded what the kart measured (its ``kart`` topic), the pipeline is told the same before
each step, so a replay of a closed-loop drive stays closed loop. Any pipeline of
:mod:`kartpilot.runtime.pipelines`: ``lanes`` gets the recording's cameras, ``stereo-vo``
its rectified stereo pair (with a reference path to follow), ``mono-vo`` its centre camera (with a place
database, following the database's drive or a given reference). Nothing
moves: the commands go to a log and to the new recording, with the pipeline's outputs
(``outputs/<topic>.csv``) and, on request, the frames. The replay runs as fast as it can or, with
``realtime``, at the recorded pace. OpenCV's random generator (RANSAC) is seeded first, so two
replays of one recording give identical outputs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from kartpilot.calibration.rectify import StereoSetup
from kartpilot.core.config import config_to_dict
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand, FrameSet, FrameSource, VehicleFeedback
from kartpilot.core.vehicle import get_vehicle
from kartpilot.record.recording import RecordingReader, RecordingWriter
from kartpilot.record.replay import RecordingFrameSource, StereoReplaySource
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.drive import ToldPipeline, recorded_feedback
from kartpilot.runtime.loop import Outputs, Recorder, run_loop
from kartpilot.runtime.path_policy import write_drive_log
from kartpilot.runtime.pipelines import PIPELINES, PipelineContext, Route, StereoInput, build_pipeline, path_policy_of
from kartpilot.runtime.session import SessionOutputs, SessionResult

__all__ = ["ReplayResult", "recorded_rate_hz", "replay_recording"]

RNG_SEED = 0


@dataclass(frozen=True)
class ReplayResult:
    """What a replay did: the session's result (``replay.json``), the pipeline's commands (one per set) and
    where the new recording went."""

    session: SessionResult
    commands: tuple[ActuatorCommand, ...]
    out: Path | None

    @property
    def steps(self) -> int:
        return self.session.steps

    def to_json(self) -> dict[str, Any]:
        return self.session.to_json()


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


def _told_at(kart: dict[int, dict[str, Any]], stamp_ns: int) -> VehicleFeedback | None:
    """What the drive told its pipeline at ``stamp_ns`` (its recorded ``kart`` row), as a live drive told it: a
    replay of a closed-loop drive stays closed loop."""
    row = kart.get(stamp_ns)
    return recorded_feedback(row, stamp_ns) if row is not None else None


def _recorded_kart(reader: RecordingReader) -> dict[int, dict[str, Any]]:
    """The drive's ``kart`` rows by stamp, where it recorded what it told the pipeline."""
    if "kart" not in reader.output_topics():
        return {}
    rows = reader.outputs("kart")
    return {int(r["stamp_ns"]): r for r in rows if "feedback_speed_mps" in r}


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
    outputs.check()
    reader = RecordingReader(folder)
    name = vehicle or reader.vehicle
    if name is None:
        raise ConfigError(f"{folder} does not say which kart it was recorded on: give --vehicle (rc-kart, sdc-kart)")
    params = get_vehicle(name)
    cv2.setRNGSeed(RNG_SEED)
    source, stereo, rate = _replay_source(reader, pipeline, stack)
    policy = build_pipeline(pipeline, PipelineContext(params, reader.cameras, rate, stack, stereo, route or Route()))
    path_policy = path_policy_of(policy)
    recorded = _recorded_kart(reader)
    if recorded and hasattr(policy, "observe_vehicle"):
        policy = ToldPipeline(policy, lambda frames: _told_at(recorded, frames.stamp_ns))
    writer = _replay_writer(reader, pipeline, params.name, stack, outputs.record_dir)
    recorders: list[Recorder] = [] if writer is None else [writer if with_frames else _WithoutFrames(writer)]
    view = outputs.open_view(reader.cameras, lidars=reader.lidars)
    if view is not None:
        recorders.append(view)
    sink = _CommandLog()
    try:
        stats = run_loop(_Paced(source) if realtime else source, policy, sink, recorders, period_s=1.0 / rate)
    finally:
        if view is not None:
            truth = reader.body_poses()
            if truth is not None:
                view.write_groundtruth(truth)
            if path_policy is not None:
                view.write_reference(np.column_stack([path_policy.path.x_m, path_policy.path.y_m]))
            view.close()
        if path_policy is not None:
            path_policy.close()
            if outputs.drive_log is not None:
                write_drive_log(path_policy.samples, outputs.drive_log)
        if writer is not None:
            writer.close()
    details: dict[str, Any] = {"replay_of": str(reader.folder), "rate_hz": round(rate, 3),
                               "unreadable_frames": source.unreadable,
                               "out": str(outputs.record_dir) if outputs.record_dir is not None else None}
    pipeline_ms, summary = path_policy.summary(stats.steps) if path_policy is not None else ({}, {})
    session = SessionResult("replay", pipeline, params.name, stats.steps, "the recording ended", None, None,
                            stats.missed_deadlines, stats.stage_summary_ms(), pipeline_ms,
                            details={**details, **summary})
    outputs.write_result(session, "replay.json")
    return ReplayResult(session, tuple(sink.commands), Path(outputs.record_dir) if outputs.record_dir else None)


def _replay_source(reader: RecordingReader, pipeline: str, stack: StackConfig
                   ) -> tuple[StereoReplaySource | RecordingFrameSource, StereoInput | None, float]:
    """The recording as the pipeline's source (a rectified stereo pair, or the cameras it reads), the pair,
    and the recorded rate."""
    if pipeline == "stereo-vo":
        if reader.stereo_pair is None:
            raise ConfigError(f"{reader.folder} has no stereo pair: the stereo-vo pipeline needs one")
        stereo_source = StereoReplaySource(reader.folder)
        stereo = StereoInput((stereo_source.left_name, stereo_source.right_name),
                             StereoSetup(stereo_source.stereo.rig, None, stereo_source.stereo.pose_body_left))
        return stereo_source, stereo, recorded_rate_hz(reader, stereo_source.left_name)
    names = [stack.drive.mono.camera] if pipeline == "mono-vo" else list(reader.cameras)
    missing = [n for n in names if n not in reader.cameras]
    if missing:
        raise ConfigError(f"{reader.folder} has no {', '.join(missing)} camera (it has {', '.join(reader.cameras)})")
    rate = recorded_rate_hz(reader, "center" if "center" in names else names[0])
    return RecordingFrameSource(reader.folder, names), None, rate


def _replay_writer(reader: RecordingReader, pipeline: str, vehicle: str, stack: StackConfig,
                   out: str | Path | None) -> RecordingWriter | None:
    """The replay's own recording, its manifest naming the replayed one and the settings that mattered."""
    if out is None:
        return None
    stack_config = config_to_dict(stack)
    settings = {"lanes": {"lane_policy": stack_config["lane_policy"]},
                "stereo-vo": {"stereo_vo": stack_config["stereo_vo"], "drive": stack_config["drive"]},
                "mono-vo": {"mono_vo": stack_config["mono_vo"], "drive": stack_config["drive"]}}[pipeline]
    return RecordingWriter(out, reader.cameras, reader.stereo_pair, lidars=reader.lidars, metadata={
        "source": "kartpilot replay", "replay_of": str(reader.folder), "pipeline": pipeline, "vehicle": vehicle,
        "config": settings})

"""What one drive session writes and returns, whichever backend it runs on (simulator, replay, live).

Every session ends with one result of one shape, :class:`SessionResult`, written as ``result.json``
(``replay.json`` for a replay) and returned to the caller. Its common fields are the same for every
backend; what only one backend knows (the referee's verdict, the CAN traffic, the cameras' skew, a
replay's rate) sits beside them as ``details``. ``schema_version`` changes whenever a common field
does, and :meth:`SessionResult.from_json` refuses a result of another version, or one with a common
field missing or of the wrong type, naming the field.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError, DataError
from kartpilot.core.files import write_json_atomic, write_text_atomic
from kartpilot.core.types import LidarMount
from kartpilot.runtime.loop import STAGE_STATS

if TYPE_CHECKING:  # rerun takes half a second to import: only a drive with a view loads it
    import cantools

    from kartpilot.record.rerun_view import RerunView

__all__ = ["BACKENDS", "SCHEMA_VERSION", "SessionOutputs", "SessionResult"]

SCHEMA_VERSION = 1
BACKENDS = ("sim", "replay", "live")


@dataclass(frozen=True)
class SessionOutputs:
    """Attributes:
        record_dir: the recording (frames, commands, the pipeline's outputs, CAN traffic, the result).
        result_path: the result JSON, besides the copy in the recording.
        video_path: the pipeline's view as a video.
        drive_log: the path follower's log, one row per step (path-following pipelines).
        progress: a progress bar on the terminal.
        view: a Rerun view of the drive as it goes: a ``.rrd`` file, or ``live`` for a viewer
            (:mod:`kartpilot.record.rerun_view`).
    """

    record_dir: str | Path | None = None
    result_path: str | Path | None = None
    video_path: str | Path | None = None
    drive_log: str | Path | None = None
    progress: bool = False
    view: str | Path | None = None

    def check(self) -> None:
        """Refuse, before anything runs, an output that could only fail once the session is over: a file
        target that is a folder, or sits under a file, or in a folder that cannot be written."""
        view = None if self.view is None or str(self.view) == "live" else self.view
        if view is not None and Path(view).suffix != ".rrd":
            raise ConfigError(f"the view would go to {view}: a Rerun file ends in .rrd (or give 'live')")
        for what, target in (("the result", self.result_path), ("the video", self.video_path),
                             ("the drive log", self.drive_log), ("the view", view)):
            if target is None:
                continue
            path = Path(target)
            if path.is_dir():
                raise ConfigError(f"{what} would go to {path}, which is a folder: give a file name")
            parent = path.parent
            while not parent.exists() and parent != parent.parent:
                parent = parent.parent
            if not parent.is_dir():
                raise ConfigError(f"{what} would go to {path}, but {parent} is a file")
            if not os.access(parent, os.W_OK):
                raise ConfigError(f"{what} would go to {path}, but {parent} cannot be written")

    def open_view(self, cameras: Mapping[str, PinholeCamera],
                  database: cantools.database.can.Database | None = None,
                  lidars: Mapping[str, LidarMount] | None = None) -> RerunView | None:
        """The Rerun view asked for (None: none), a sink beside the recorder; ``lidars``: the LiDARs' mounts,
        for their sweeps on its bird's-eye view."""
        if self.view is None:
            return None
        from kartpilot.record.rerun_view import RerunView

        return RerunView(self.view, cameras, database=database, lidars=lidars)

    def write_result(self, result: SessionResult, name: str = "result.json", error_text: str = "") -> dict[str, Any]:
        """The result where it was asked for and beside the recording (as ``name``), with the pipeline's
        traceback as ``error.txt`` there if it raised; returns the result's JSON."""
        payload = result.to_json()
        if self.result_path is not None:
            write_json_atomic(self.result_path, payload)
        if self.record_dir is not None:
            write_json_atomic(Path(self.record_dir) / name, payload)
            if error_text:
                write_text_atomic(Path(self.record_dir) / "error.txt", error_text)
        return payload


@dataclass(frozen=True)
class SessionResult:
    """Attributes:
        backend: ``sim``, ``replay`` or ``live``.
        pipeline: the pipeline (or, for ``kartpilot sim``, the driver) that drove.
        vehicle: the kart.
        steps: loop steps (frame sets).
        ended: why the session ended (the source ran out, a fault held, the duration, Ctrl-C).
        final_state: the supervisor's last state (None for an unsupervised run: a replay, ``kartpilot sim``).
        error: the pipeline's exception, if it raised (the kart was stopped).
        missed_deadlines: steps that took longer than the period.
        stage_ms: the loop's stages (source, policy, sinks): ``STAGE_STATS`` in milliseconds per step.
        pipeline_stage_ms: the pipeline's own stages, mean milliseconds per step (empty when it has none).
        transitions: the supervisor's transitions (time, state, reason).
        details: what only this backend knows, beside the common fields in the JSON.
        schema_version: the shape of the common fields.
    """

    backend: str
    pipeline: str
    vehicle: str
    steps: int
    ended: str
    final_state: str | None
    error: str | None
    missed_deadlines: int
    stage_ms: Mapping[str, Mapping[str, float]]
    pipeline_stage_ms: Mapping[str, float] = field(default_factory=dict)
    transitions: tuple[Mapping[str, Any], ...] = ()
    details: Mapping[str, Any] = field(default_factory=dict)
    schema_version: int = SCHEMA_VERSION

    def to_json(self) -> dict[str, Any]:
        common = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "details"}
        clash = sorted(set(common) & set(self.details))
        if clash:
            raise ValueError(f"details may not reuse common fields: {', '.join(clash)}")
        common["stage_ms"] = {k: dict(v) for k, v in self.stage_ms.items()}
        common["pipeline_stage_ms"] = {k: round(float(v), 3) for k, v in self.pipeline_stage_ms.items()}
        common["transitions"] = [dict(t) for t in self.transitions]
        return {**common, **self.details}

    @classmethod
    def from_json(cls, payload: Mapping[str, Any]) -> SessionResult:
        """The result in ``payload`` (a ``result.json``), checked against this schema."""
        version = payload.get("schema_version")
        if version != SCHEMA_VERSION:
            raise DataError(f"result schema_version {version!r}, this kartpilot reads {SCHEMA_VERSION}")
        expected: dict[str, tuple[type, ...]] = {
            "backend": (str,), "pipeline": (str,), "vehicle": (str,), "steps": (int,), "ended": (str,),
            "final_state": (str, type(None)), "error": (str, type(None)), "missed_deadlines": (int,),
            "stage_ms": (dict,), "pipeline_stage_ms": (dict,), "transitions": (list,)}
        for key, types in expected.items():
            if key not in payload:
                raise DataError(f"result: {key} missing")
            if not isinstance(payload[key], types) or isinstance(payload[key], bool):
                raise DataError(f"result: {key} is {type(payload[key]).__name__}, expected "
                                f"{' or '.join(t.__name__ for t in types)}")
        if payload["backend"] not in BACKENDS:
            raise DataError(f"result: backend {payload['backend']!r} is none of {', '.join(BACKENDS)}")
        for stage, stats in payload["stage_ms"].items():
            if not isinstance(stats, dict) or set(stats) != set(STAGE_STATS):
                raise DataError(f"result: stage_ms.{stage} must hold {', '.join(STAGE_STATS)}")
            if not all(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0 for v in stats.values()):
                raise DataError(f"result: stage_ms.{stage} must be finite, non-negative milliseconds")
        for stage, ms in payload["pipeline_stage_ms"].items():
            if not isinstance(ms, (int, float)) or not math.isfinite(ms):
                raise DataError(f"result: pipeline_stage_ms.{stage} must be finite milliseconds")
        for k, transition in enumerate(payload["transitions"]):
            if not isinstance(transition, dict) or not {"t_s", "state", "reason"} <= set(transition):
                raise DataError(f"result: transitions[{k}] must hold t_s, state and reason")
        common = {f.name for f in fields(cls)} - {"details"}
        return cls(**{k: payload[k] for k in expected if k != "transitions"}, transitions=tuple(payload["transitions"]),
                   details={k: v for k, v in payload.items() if k not in common}, schema_version=version)

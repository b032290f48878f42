"""The loop every drive goes through: live, replayed or simulated.

``frames -> policy -> command -> sinks``, one step per frame set, with the
per-stage time measured. With a ``period_s`` the loop has a deadline per step:
a step whose policy and sinks take longer is counted and logged, and with ``pace`` the loop
sleeps out the rest of each period (live driving; a simulator or a replay runs
as fast as it can). Sources and sinks are interchangeable: the simulator
is both, a recorder is one more sink; a policy with an ``outputs()`` method (what it
saw and decided in its last step, by topic) has them recorded next to the frames and
commands. If anything raises, the actuators get
the stop command before the error propagates, so a crash never leaves the
last command standing.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from kartpilot.core.errors import KartpilotError
from kartpilot.core.types import ActuatorCommand, CommandSink, FrameSet, FrameSink, FrameSource

__all__ = ["STAGE_STATS", "LoopStats", "Outputs", "Policy", "Recorder", "run_loop"]

log = logging.getLogger(__name__)

Policy = Callable[[FrameSet], ActuatorCommand]

STAGE_STATS = ("mean", "p50", "p90", "p99", "max")  # what a stage's timing is summarised by


Outputs = Mapping[str, Mapping[str, float | int | str]]


class Recorder(FrameSink, CommandSink, Protocol):
    """A sink for frames, commands and the pipeline's outputs (the recording writer is one)."""

    def write_outputs(self, stamp_ns: int, outputs: Outputs) -> None: ...


@dataclass
class LoopStats:
    steps: int = 0
    wall_time_s: float = 0.0
    missed_deadlines: int = 0
    worst_step_ms: float = 0.0
    stage_s: dict[str, float] = field(default_factory=lambda: {"source": 0.0, "policy": 0.0, "sinks": 0.0})
    samples_s: dict[str, list[float]] = field(default_factory=lambda: {"source": [], "policy": [], "sinks": []})

    def stage_ms(self) -> dict[str, float]:
        """Mean milliseconds per step of each stage."""
        return {k: 1000.0 * v / max(self.steps, 1) for k, v in self.stage_s.items()}

    def stage_summary_ms(self) -> dict[str, dict[str, float]]:
        """Each stage's milliseconds per step: mean, median, 90th and 99th percentile, and the worst
        (:data:`STAGE_STATS`)."""
        result = {}
        for stage, samples in self.samples_s.items():
            if samples:
                ms = np.asarray(samples, float) * 1e3
                values = (ms.mean(), *np.percentile(ms, (50, 90, 99)), ms.max())
                result[stage] = {name: round(float(v), 3) for name, v in zip(STAGE_STATS, values, strict=True)}
        return result


def run_loop(source: FrameSource, policy: Policy, actuators: CommandSink, recorders: Sequence[Recorder] = (),
             on_step: Callable[[FrameSet, ActuatorCommand], None] | None = None,
             max_steps: int | None = None, period_s: float | None = None, pace: bool = False) -> LoopStats:
    """Run until the source ends (or ``max_steps``); return the step count and per-stage times."""
    stats = LoopStats()
    outputs_of: Callable[[], Outputs] | None = getattr(policy, "outputs", None)
    start = time.perf_counter()
    next_tick = start
    last_stamp = 0
    try:
        while max_steps is None or stats.steps < max_steps:
            if pace and period_s:
                next_tick += period_s
            t0 = time.perf_counter()
            frames = source.read()
            t1 = time.perf_counter()
            if frames is None:
                break
            last_stamp = frames.stamp_ns
            command = policy(frames)
            t2 = time.perf_counter()
            outputs = outputs_of() if outputs_of is not None and recorders else {}
            for recorder in recorders:
                recorder.write_frames(frames)
                recorder.send(command)
                if outputs:
                    recorder.write_outputs(frames.stamp_ns, outputs)
            actuators.send(command)
            if on_step is not None:
                on_step(frames, command)
            t3 = time.perf_counter()
            for stage, seconds in (("source", t1 - t0), ("policy", t2 - t1), ("sinks", t3 - t2)):
                stats.stage_s[stage] += seconds
                stats.samples_s[stage].append(seconds)
            stats.steps += 1
            step_ms = (t3 - t1) * 1e3  # the pipeline's own work, not the wait for (or rendering of) frames
            stats.worst_step_ms = max(stats.worst_step_ms, step_ms)
            if period_s and step_ms > period_s * 1e3:
                stats.missed_deadlines += 1
                if stats.missed_deadlines == 1 or stats.missed_deadlines % 100 == 0:
                    log.warning("step %d took %.1f ms, over the %.1f ms period (%d missed so far)", stats.steps,
                                step_ms, period_s * 1e3, stats.missed_deadlines)
            if pace and period_s:
                delay = next_tick - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                else:
                    next_tick = time.perf_counter()  # late: do not try to catch up
    except BaseException as exc:
        _stop_all(exc, stats.steps, ActuatorCommand.stop(last_stamp), (actuators, *recorders))
        raise
    finally:
        stats.wall_time_s = time.perf_counter() - start
    return stats


def _stop_all(exc: BaseException, step: int, stop: ActuatorCommand, sinks: Sequence[CommandSink]) -> None:
    """Command a stop to every sink after the loop ended on ``exc`` (a user's Ctrl-C is not an error)."""
    if isinstance(exc, KeyboardInterrupt):
        log.info("interrupted at step %d: commanding a stop", step)
    elif isinstance(exc, KartpilotError):  # a known failure: the command says it in its one line
        log.info("the loop failed at step %d (%s): commanding a stop", step, exc)
    else:
        log.error("the loop failed at step %d: commanding a stop", step)
    for sink in sinks:
        try:
            sink.send(stop)
        except KartpilotError as failed:  # a known failure (the recording's disk is full): said once, at the end
            log.info("could not send the stop command to %r: %s", sink, failed)
        except Exception:
            log.exception("could not send the stop command to %r", sink)

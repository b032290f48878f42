"""A supervised drive: the pipeline's command goes through the safety supervisor to the actuators.

:class:`Watchdogs` gathers, every step, what the supervisor listens to: the cameras (a black, blank
or frozen frame at once; no frame for ``camera_timeout_s``), the pipeline's own health (localisation
lost, no lane boundary), a pipeline that keeps overrunning its period, and the CAN bus and ECUs.
:class:`SupervisedDrive` is the policy the loop runs: pipeline, watchdogs, operator, supervisor. A
pipeline that can use the kart's own measurements (``observe_vehicle``) gets them before each step,
and what the kart reported becomes the recording's ``kart`` topic (``outputs/kart.csv``). An
exception inside the pipeline is caught there: it is a fault like any other, the stop goes out in
the same step, and the error is kept so the run can end non-zero once the stop has been held.
"""

from __future__ import annotations

import logging
import math
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from kartpilot.actuation.can_bus import CanActuator
from kartpilot.core.types import ActuatorCommand, FrameSet, OperatorInput, VehicleFeedback
from kartpilot.runtime.loop import Policy
from kartpilot.runtime.supervisor import Supervisor
from kartpilot.sensors.health import CameraWatchdog, HealthConfig

__all__ = ["ScriptedOperator", "SupervisedDrive", "ToldPipeline", "WatchdogConfig", "Watchdogs", "feedback_columns",
           "recorded_feedback"]

log = logging.getLogger(__name__)

BAD_FRAMES = ("empty", "black", "blank", "frozen")


@dataclass(frozen=True)
class WatchdogConfig:
    """Attributes:
        health: what counts as a bad frame; ``health.timeout_s``: how long a camera may deliver nothing.
        overrun_factor, overrun_steps: the pipeline taking longer than this many periods, this many steps
            in a row, is a fault (one slow step is not). Checked where the clock is real (a live drive, a paced
            replay); in the simulator, whose clock waits for the pipeline, an overrun would say only how busy the
            machine running it is, so it is measured (the result's stage times) but not a fault.
    """

    health: HealthConfig = field(default_factory=HealthConfig)
    overrun_factor: float = 2.0
    overrun_steps: int = 3


class Watchdogs:
    def __init__(self, cameras: Sequence[str], period_s: float, config: WatchdogConfig | None = None,
                 actuator: CanActuator | None = None, real_time: bool = True) -> None:
        self.config = config or WatchdogConfig()
        self.real_time = real_time
        self.cameras = CameraWatchdog(list(cameras), self.config.health)
        self.period_s = period_s
        self.actuator = actuator
        self._overruns = 0

    def check(self, frames: FrameSet, pipeline_fault: str, pipeline_s: float) -> list[str]:
        faults = [f"camera {name}: {reason}" for name, reason in self.cameras.check(frames).items()]
        faults += [f"camera {name}: {problem} frame" for name, problem in self.cameras.frame_problems.items()
                   if problem in BAD_FRAMES and not any(f.startswith(f"camera {name}:") for f in faults)]
        if pipeline_fault:
            faults.append(pipeline_fault)
        over = self.real_time and pipeline_s > self.config.overrun_factor * self.period_s
        self._overruns = self._overruns + 1 if over else 0
        if self._overruns >= self.config.overrun_steps:
            faults.append(f"the pipeline overran its {self.period_s * 1e3:.0f} ms period {self._overruns} times in a "
                          f"row (last {pipeline_s * 1e3:.0f} ms)")
        if self.actuator is not None:
            self.actuator.poll()
            faults += self.actuator.faults()
        return faults


class ScriptedOperator:
    """The person in the simulator: asks for autonomy at the start and holds the dead-man button.
    ``unplug_at_s`` unplugs the gamepad (fault injection)."""

    def __init__(self, unplug_at_s: float | None = None) -> None:
        self.unplug_at_s = unplug_at_s
        self._asked = False

    def __call__(self, stamp_ns: int) -> OperatorInput:
        connected = self.unplug_at_s is None or stamp_ns * 1e-9 < self.unplug_at_s
        request = "" if self._asked else "autonomous"
        self._asked = True
        return OperatorInput(connected=connected, hold=connected, request=request, source="gamepad (scripted)")


class SupervisedDrive:
    """The policy the loop runs: ``pipeline`` -> watchdogs -> supervisor -> command."""

    def __init__(self, pipeline: Policy, supervisor: Supervisor, watchdogs: Watchdogs,
                 operator: Callable[[int], OperatorInput], actuator: CanActuator | None = None) -> None:
        self.pipeline = pipeline
        self.supervisor = supervisor
        self.watchdogs = watchdogs
        self.operator = operator
        self.actuator = actuator
        self.error: BaseException | None = None
        self.error_text = ""
        self.error_at_ns: int | None = None
        self.faults: list[str] = []
        self.step_s: list[float] = []
        self.feedback: VehicleFeedback | None = None  # what the pipeline was told the kart measured, last step

    def __call__(self, frames: FrameSet) -> ActuatorCommand:
        t0 = time.perf_counter()
        pipeline_fault = ""
        autonomous = ActuatorCommand.stop(frames.stamp_ns)
        if self.error is None:
            try:
                observe = getattr(self.pipeline, "observe_vehicle", None)
                if self.actuator is not None:
                    self.feedback = self.actuator.feedback()
                    if observe is not None:
                        observe(self.feedback)
                autonomous = self.pipeline(frames)
                fault_of = getattr(self.pipeline, "fault", None)
                pipeline_fault = fault_of() if fault_of is not None else ""
            except Exception as exc:  # anything: a stage that raises must not leave the last command standing
                self.error, self.error_at_ns = exc, frames.stamp_ns
                self.error_text = "".join(traceback.format_exception(exc))
                log.error("the pipeline raised at %.2f s: %s", frames.stamp_ns * 1e-9, exc)
        if self.error is not None:
            pipeline_fault = f"the pipeline raised {type(self.error).__name__}: {self.error}"
        pipeline_s = time.perf_counter() - t0
        self.step_s.append(pipeline_s)
        self.faults = self.watchdogs.check(frames, pipeline_fault, pipeline_s)
        operator = self.operator(frames.stamp_ns)
        if self.actuator is not None and self.actuator.estop:
            operator = replace(operator, estop=True, source="emergency-stop circuit")
        command = self.supervisor.step(frames.stamp_ns, self.faults, operator, autonomous)
        if self.actuator is not None:
            self.actuator.state = self.supervisor.state
        return command

    @property
    def error_line(self) -> str | None:
        """The pipeline's exception in one line, for the result (None when it never raised)."""
        return f"{type(self.error).__name__}: {self.error}" if self.error is not None else None

    def outputs(self) -> dict[str, dict[str, Any]]:
        pipeline_outputs = getattr(self.pipeline, "outputs", None)
        result: dict[str, dict[str, Any]] = dict(pipeline_outputs()) if pipeline_outputs is not None else {}
        result["supervisor"] = {"state": self.supervisor.state, "faults": len(self.faults),
                                "reason": self.supervisor.reason.replace(",", ";")}
        if self.actuator is not None:
            feedback = self.feedback or VehicleFeedback(0)
            result["kart"] = {**self.actuator.outputs(), **feedback_columns(feedback)}
        return result


def feedback_columns(feedback: VehicleFeedback) -> dict[str, float]:
    """What the pipeline was told the kart measured, as the ``kart`` topic's columns (NaN: nothing fresh), so a
    replay can tell the pipeline the same."""
    return {"feedback_speed_mps": math.nan if feedback.speed_mps is None else feedback.speed_mps,
            "feedback_steer_rad": math.nan if feedback.steer_rad is None else feedback.steer_rad}


def recorded_feedback(row: dict[str, Any], stamp_ns: int) -> VehicleFeedback:
    """The inverse of :func:`feedback_columns`, for a recorded ``kart`` row."""
    def value(key: str) -> float | None:
        v = row.get(key)
        return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else None

    return VehicleFeedback(stamp_ns, value("feedback_speed_mps"), value("feedback_steer_rad"))


class ToldPipeline:
    """A pipeline told before each step what the kart measured (``observe_vehicle``), as a live drive tells it:
    ``feedback_of`` gives that for a frame set (None: nothing was measured then). With ``kart_topic``, what it was
    told is its ``kart`` output topic as well, as a drive records it."""

    def __init__(self, policy: Any, feedback_of: Callable[[FrameSet], VehicleFeedback | None],
                 kart_topic: bool = False) -> None:
        self.policy, self.feedback_of, self.kart_topic = policy, feedback_of, kart_topic
        self.feedback: VehicleFeedback | None = None

    def __call__(self, frames: FrameSet) -> ActuatorCommand:
        feedback = self.feedback_of(frames)
        if feedback is not None:
            self.feedback = feedback
            self.policy.observe_vehicle(feedback)
        return self.policy(frames)

    def outputs(self) -> dict[str, dict[str, Any]]:
        outputs_of = getattr(self.policy, "outputs", None)
        topics = dict(outputs_of()) if outputs_of is not None else {}
        if self.kart_topic and self.feedback is not None:
            topics["kart"] = dict(feedback_columns(self.feedback))
        return topics

    def __getattr__(self, name: str) -> Any:
        return getattr(self.policy, name)

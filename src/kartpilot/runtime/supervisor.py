"""The safety supervisor: one state machine decides whether commands may reach the actuators.

States: ``disarmed`` (stop), ``manual`` (the person's commands), ``autonomous`` (the pipeline's),
``paused`` (autonomous, but the dead-man button is released: stop), ``fault`` (stop, latched).

* Any fault reported by a watchdog (cameras, the loop's deadline, the pipeline's health, CAN,
  the ECUs, the operator's link) while armed, or an emergency stop at any time, leads to ``fault``
  in the same step: the command of that step is already the stop.
* ``fault`` is left only when a person asks to re-arm, no fault remains and the emergency stop is
  released; it leads to ``disarmed``, and arming again is another explicit request.
* Switching between manual and autonomous is an explicit request. Every transition is logged and
  kept with its time and reason.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand, OperatorInput

__all__ = ["STATES", "Supervisor", "SupervisorConfig", "Transition"]

log = logging.getLogger(__name__)

STATES = ("disarmed", "manual", "autonomous", "paused", "fault")
REQUESTS = ("", "manual", "autonomous", "disarm", "rearm")


@dataclass(frozen=True)
class SupervisorConfig:
    """Attributes:
        require_hold: autonomy runs only while the dead-man button is held.
        operator_required: losing the operator's link (gamepad unplugged, page closed) is a fault.
    """

    require_hold: bool = True
    operator_required: bool = True


@dataclass(frozen=True)
class Transition:
    stamp_ns: int
    state: str
    reason: str

    def to_json(self, start_ns: int = 0) -> dict[str, Any]:
        return {"t_s": round((self.stamp_ns - start_ns) * 1e-9, 4), "state": self.state, "reason": self.reason}


class Supervisor:
    """Holds the state and the transitions; :meth:`step` is called once per control period."""

    def __init__(self, config: SupervisorConfig | None = None) -> None:
        self.config = config or SupervisorConfig()
        self.state = "disarmed"
        self.reason = "started"
        self.transitions: list[Transition] = []
        self.refused = 0

    def _go(self, stamp_ns: int, state: str, reason: str) -> None:
        if state == self.state and reason == self.reason:
            return
        (log.error if state == "fault" else log.info)("supervisor: %s -> %s (%s)", self.state, state, reason)
        self.state, self.reason = state, reason
        self.transitions.append(Transition(stamp_ns, state, reason))

    def step(self, stamp_ns: int, faults: Sequence[str], operator: OperatorInput,
             autonomous: ActuatorCommand) -> ActuatorCommand:
        """The command allowed to reach the actuators at ``stamp_ns``."""
        if operator.request not in REQUESTS:
            raise ConfigError(f"unknown operator request {operator.request!r} ({', '.join(REQUESTS[1:])})")
        problems = list(faults)
        if not operator.connected and self.config.operator_required:
            problems.append(f"operator link lost ({operator.source or 'operator'})")
        if operator.estop:
            self._go(stamp_ns, "fault", f"emergency stop ({operator.source or 'input'})")
        elif self.state in ("manual", "autonomous", "paused") and problems:
            self._go(stamp_ns, "fault", "; ".join(problems))
        elif self.state == "fault":
            if operator.request == "rearm":
                if problems:
                    self.refused += 1
                    log.warning("re-arm refused: %s", "; ".join(problems))
                else:
                    self._go(stamp_ns, "disarmed", f"re-armed by the operator ({operator.source or 'input'})")
        else:
            self._request(stamp_ns, operator, problems)
        if self.state == "autonomous":
            return autonomous
        if self.state == "manual" and operator.manual is not None:
            return operator.manual
        return ActuatorCommand.stop(stamp_ns)

    def _request(self, stamp_ns: int, operator: OperatorInput, problems: list[str]) -> None:
        who = operator.source or "input"
        request = operator.request
        if request == "disarm":
            self._go(stamp_ns, "disarmed", f"disarmed by the operator ({who})")
            return
        if request in ("manual", "autonomous") and self.state != request and not (
                request == "autonomous" and self.state == "paused"):
            if problems:
                self.refused += 1
                log.warning("arming %s refused: %s", request, "; ".join(problems))
                return
            self._go(stamp_ns, request, f"{request} requested by the operator ({who})")
        if self.config.require_hold:
            if self.state == "autonomous" and not operator.hold:
                self._go(stamp_ns, "paused", f"hold button released ({who})")
            elif self.state == "paused" and operator.hold:
                self._go(stamp_ns, "autonomous", f"hold button pressed ({who})")

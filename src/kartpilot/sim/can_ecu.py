"""The kart's ECUs, simulated behind the CAN bus.

:class:`SimEcus` reads the frames kartpilot sends, exactly as the steer, drive and brake ECUs would:
decoded with the same DBC, with a wrong checksum or a counter that did not move dropped. It drives
the simulator with the last command it accepted, brakes by itself when the heartbeat has been missing
for ``heartbeat_timeout_s`` (the ECU side of failing safe), and reports each ECU's status back on the
bus. Every command it applies is kept with its time, so a test can see when the first stop arrived.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import can

from kartpilot.actuation.can_bus import STATUS_MESSAGES, decode, encode, load_dbc
from kartpilot.core.errors import ActuationError
from kartpilot.core.types import ActuatorCommand, CommandSink

__all__ = ["AppliedCommand", "SimEcus"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AppliedCommand:
    """What the actuators were given at ``stamp_ns``, and why: ``command`` (from the bus) or
    ``ecu-timeout`` (the ECUs braked on their own)."""

    stamp_ns: int
    command: ActuatorCommand
    source: str


class SimEcus:
    def __init__(self, bus: can.BusABC, vehicle: CommandSink, clock: Callable[[], int], dbc: str = "",
                 heartbeat_timeout_s: float = 0.1, ecus: tuple[str, ...] = ("steer", "drive", "brake"),
                 measured: Callable[[], tuple[float, float]] | None = None) -> None:
        self.bus, self.vehicle, self.clock = bus, vehicle, clock
        self.db = load_dbc(dbc or None)
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.ecus = ecus
        self.measured = measured  # (steer_rad, speed_mps) of the simulated kart
        self.silent = False  # an ECU fault injection: the ECUs stop reporting
        self.estop = False
        self.applied: list[AppliedCommand] = []
        self.rejected_frames = 0
        self._values: dict[str, dict[str, float]] = {}
        self._counters: dict[str, int] = {}
        self._heartbeat_ns: int | None = None
        self._start_ns = clock()
        self._status_counter = 0

    def _read(self) -> None:
        while (frame := self.bus.recv(timeout=0.0)) is not None:
            try:
                name, values = decode(self.db, frame)
            except ActuationError as exc:
                self.rejected_frames += 1
                log.warning("simulated ECU dropped a frame: %s", exc)
                continue
            if self._counters.get(name) == values["Counter"]:
                self.rejected_frames += 1  # the counter did not move: a stale repeat
                continue
            self._counters[name] = int(values["Counter"])
            self._values[name] = values
            if name == "Heartbeat":
                self._heartbeat_ns = self.clock()

    def command(self) -> tuple[ActuatorCommand, str]:
        """The command the ECUs apply now, and its source."""
        now = self.clock()
        last = self._heartbeat_ns if self._heartbeat_ns is not None else self._start_ns
        if (now - last) * 1e-9 > self.heartbeat_timeout_s or not {"SteerCommand", "ThrottleCommand",
                                                                    "BrakeCommand"} <= set(self._values):
            return ActuatorCommand.stop(now), "ecu-timeout"
        steer = self._values["SteerCommand"]
        throttle = self._values["ThrottleCommand"]
        brake = self._values["BrakeCommand"]
        return ActuatorCommand(now, float(steer["SteerAngle"]) if steer["Enable"] else 0.0,
                               float(throttle["Throttle"]) if throttle["Enable"] else 0.0,
                               float(brake["Brake"])), "command"

    def step(self) -> ActuatorCommand:
        """Read the bus, apply the command to the vehicle, report the status."""
        self._read()
        command, source = self.command()
        if self.estop:
            command, source = ActuatorCommand.stop(command.stamp_ns), "estop-circuit"
        self.applied.append(AppliedCommand(command.stamp_ns, command, source))
        if not self.silent:
            self._report(source)
        self.vehicle.send(command)
        return command

    def _report(self, source: str) -> None:
        self._status_counter = (self._status_counter + 1) % 16
        steer, speed = self.measured() if self.measured is not None else (0.0, 0.0)
        fault = 1 if source == "ecu-timeout" and self._heartbeat_ns is not None else 0
        values = {"steer": {"Fault": fault, "SteerMeasured": steer},
                  "drive": {"Fault": fault, "Speed": speed},
                  "brake": {"Fault": fault, "EStop": int(self.estop),
                            "BrakeMeasured": self._values.get("BrakeCommand", {}).get("Brake", 1.0)}}
        for ecu in self.ecus:
            self.bus.send(encode(self.db, STATUS_MESSAGES[ecu], values[ecu], self._status_counter))

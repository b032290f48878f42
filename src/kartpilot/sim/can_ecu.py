"""The kart's ECUs, simulated behind the CAN bus.

Each class reads the frames kartpilot sends, exactly as the kart's ECUs would, and reports back on
the bus; :meth:`step` returns the command the simulated kart's actuators execute now. Every command
the ECUs accept is kept with its time and source, so a test can see when the first stop arrived.

* :class:`KartpilotEcus`: our own DBC (``rc-kart``): a wrong checksum or a counter that did not move
  is dropped, and the ECUs brake by themselves when the heartbeat has been missing for a while.
* :class:`RdwEcus`: the RDW kart's ECUs as the organiser documents them: the motor ECU goes idle after
  200 ms without ``0x330`` (throttle 0, the ``Idle`` flag in ``0x730``), ignores a frame whose gear is 3
  or more; the steering ECU goes to its failsafe (holds its angle, reports an error in ``0x720``) when
  the steering sensor is out of range or silent for 0.2 s; the brake actuator travels to its target at
  a finite speed; speed (``0x440``), the steering sensor (``0x1E5``) and the ECUs' feedback go out at
  their own rates. The rates and the brake's travel time are our assumptions (config), not the
  organiser's figures.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can

from kartpilot.actuation.can_bus import PeriodicSchedule
from kartpilot.actuation.kartpilot_protocol import STATUS_MESSAGES, decode, encode, load_dbc
from kartpilot.actuation.rdw_protocol import SENSOR_RANGE, decode_rdw, load_rdw_dbc
from kartpilot.core.errors import ActuationError, ConfigError
from kartpilot.core.types import ActuatorCommand
from kartpilot.core.vehicle import SteeringCalibration

__all__ = ["ECU_FAULTS", "AppliedCommand", "KartpilotEcus", "RdwEcuConfig", "RdwEcus", "SimulatedEcus"]

log = logging.getLogger(__name__)

Measured = Callable[[], tuple[float, float]]  # (steer_rad, speed_mps) of the simulated kart
ECU_FAULTS = ("heartbeat-loss", "ecu-error", "steering-sensor-loss", "steering-sensor-range")


@dataclass(frozen=True)
class AppliedCommand:
    """What the actuators were told to do at ``stamp_ns``, and why: ``command`` (from the bus), or what
    the ECUs did on their own (``ecu-timeout``, ``motor-idle``, ``steering-failsafe``, ``estop-circuit``)."""

    stamp_ns: int
    command: ActuatorCommand
    source: str


class SimulatedEcus:
    """What both simulations share: the clock, the kept commands, the faults a test can switch on
    (``FAULTS``: the kinds of :data:`ECU_FAULTS` these ECUs can simulate)."""

    FAULTS: frozenset[str] = frozenset({"heartbeat-loss"})

    def __init__(self, bus: can.BusABC, clock: Callable[[], int], measured: Measured | None) -> None:
        self.bus, self.clock = bus, clock
        self.measured = measured or (lambda: (0.0, 0.0))
        self.applied: list[AppliedCommand] = []
        self.rejected_frames = 0
        self.silent = False  # the ECUs stop reporting
        self.estop = False

    def inject(self, kind: str) -> None:
        """Break the ECUs the way ``kind`` says (one of :data:`ECU_FAULTS`)."""
        if kind == "heartbeat-loss":
            self.silent = True
        else:
            raise ConfigError(f"the {type(self).__name__} cannot simulate {kind}")

    def step(self) -> ActuatorCommand:
        raise NotImplementedError


class KartpilotEcus(SimulatedEcus):
    """Our own DBC's steer, drive and brake ECUs (see the module's docstring)."""

    FAULTS = frozenset({"heartbeat-loss", "ecu-error"})

    def __init__(self, bus: can.BusABC, clock: Callable[[], int], dbc: str = "", heartbeat_timeout_s: float = 0.1,
                 ecus: tuple[str, ...] = ("steer", "drive", "brake"), measured: Measured | None = None,
                 status_rate_hz: float = 50.0) -> None:
        super().__init__(bus, clock, measured)
        self.db = load_dbc(dbc or None)
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.ecus = ecus
        self.fault_code = 0
        self._values: dict[str, dict[str, float]] = {}
        self._counters: dict[str, int] = {}
        self._heartbeat_ns: int | None = None
        self._start_ns = clock()
        self._status_counter = 0
        self._status_timer = PeriodicSchedule(round(1e9 / status_rate_hz))

    def inject(self, kind: str) -> None:
        if kind == "ecu-error":
            self.fault_code = 4  # "actuator"
        else:
            super().inject(kind)

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
        """Read the bus, report the status, return the command the actuators execute."""
        self._read()
        command, source = self.command()
        if self.estop:
            command, source = ActuatorCommand.stop(command.stamp_ns), "estop-circuit"
        self.applied.append(AppliedCommand(command.stamp_ns, command, source))
        if not self.silent and self._status_timer.due(command.stamp_ns):
            self._report(source)
        return command

    def _report(self, source: str) -> None:
        self._status_counter = (self._status_counter + 1) % 16
        steer, speed = self.measured()
        fault = 1 if source == "ecu-timeout" and self._heartbeat_ns is not None else self.fault_code
        values = {"steer": {"Fault": fault, "SteerMeasured": steer},
                  "drive": {"Fault": fault, "Speed": speed},
                  "brake": {"Fault": fault, "EStop": int(self.estop),
                            "BrakeMeasured": self._values.get("BrakeCommand", {}).get("Brake", 1.0)}}
        for ecu in self.ecus:
            self.bus.send(encode(self.db, STATUS_MESSAGES[ecu], values[ecu], self._status_counter))


@dataclass(frozen=True)
class RdwEcuConfig:
    """The simulated RDW kart's timing. Attributes:
        motor_idle_s: the motor ECU goes idle this long after the last ``0x330`` (the organiser's 200 ms).
        sensor_failsafe_s: the steering ECU's failsafe after the sensor has been silent this long (0.2 s).
        brake_travel_s: the brake actuator's time from released to full (assumed).
        speed_rate_hz, sensor_rate_hz, feedback_rate_hz: how often ``0x440``, ``0x1E5`` and the ECUs'
            ``0x710``/``0x720``/``0x730`` go out (assumed).
    """

    motor_idle_s: float = 0.2
    sensor_failsafe_s: float = 0.2
    brake_travel_s: float = 0.4
    speed_rate_hz: float = 50.0
    sensor_rate_hz: float = 100.0
    feedback_rate_hz: float = 20.0


@dataclass
class _RdwState:
    brake_target: float = 0.0
    brake_position: float = 0.0
    steer_value: float = 0.0
    throttle: float = 0.0
    gear: int = 0
    motor_ns: int | None = None
    sensor_silent_since_ns: int | None = None
    failsafe: int = 0  # 0 none, 1 sensor silent, 2 sensor out of range
    held_steer_rad: float = 0.0
    values: dict[str, Any] = field(default_factory=dict)


class RdwEcus(SimulatedEcus):
    """The RDW kart's brake, steering and motor ECUs and its two sensors (see the module's docstring).

    Args:
        steering: the simulated kart's true steering calibration (which the stack may not know exactly).
        measured: the simulated kart's (steer_rad, speed_mps).
    """

    FAULTS = frozenset(ECU_FAULTS)

    def __init__(self, bus: can.BusABC, clock: Callable[[], int], steering: SteeringCalibration,
                 measured: Measured | None = None, config: RdwEcuConfig | None = None) -> None:
        super().__init__(bus, clock, measured)
        self.steering = steering
        self.config = config or RdwEcuConfig()
        self.db = load_rdw_dbc()
        self.state = _RdwState()
        self.sensor_silent = False
        self.sensor_offset_counts = 0.0
        self.steering_error = 0
        self.speed_reports: list[tuple[int, float, float]] = []  # (stamp_ns, true m/s, km/h sent in 0x440)
        self._last_ns: int | None = None
        self._timers = {name: PeriodicSchedule(round(1e9 / rate)) for name, rate in (
            ("speed", self.config.speed_rate_hz), ("sensor", self.config.sensor_rate_hz),
            ("feedback", self.config.feedback_rate_hz))}

    def inject(self, kind: str) -> None:
        if kind == "ecu-error":
            self.steering_error = 3
        elif kind == "steering-sensor-loss":
            self.sensor_silent = True
        elif kind == "steering-sensor-range":
            self.sensor_offset_counts = 2.0 * SENSOR_RANGE
        else:
            super().inject(kind)

    def _read(self, now: int) -> None:
        s = self.state
        while (frame := self.bus.recv(timeout=0.0)) is not None:
            try:
                decoded = decode_rdw(self.db, frame)
            except ActuationError:
                decoded = None
            if decoded is None:
                self.rejected_frames += 1
                continue
            name, values = decoded
            if name == "BrakeCommand":
                s.brake_target = min(max(values["BrakePercent"], 0.0), 100.0) / 100.0
            elif name == "SteeringCommand":
                s.steer_value = min(max(float(values["SteeringTarget"]), -1.25), 1.25)
            elif name == "MotorCommand":
                if values["Gear"] >= 3:
                    self.rejected_frames += 1  # the motor ECU ignores the frame
                    continue
                s.throttle, s.gear, s.motor_ns = min(max(values["ThrottlePercent"], 0.0), 100.0) / 100.0, \
                    int(values["Gear"]), now

    def _sensor_counts(self, steer_rad: float) -> float:
        return self.steering.counts_of(steer_rad) + self.sensor_offset_counts

    def step(self) -> ActuatorCommand:
        """Read the bus, run the ECUs' rules, report what is due; the command the actuators execute now."""
        now = self.clock()
        dt = 0.0 if self._last_ns is None else max(now - self._last_ns, 0) * 1e-9
        self._last_ns = now
        self._read(now)
        s, config = self.state, self.config
        steer_rad, speed_mps = self.measured()
        counts = self._sensor_counts(steer_rad)
        if self.sensor_silent and s.sensor_silent_since_ns is None:
            s.sensor_silent_since_ns = now
        was = s.failsafe
        if abs(counts) > SENSOR_RANGE:
            s.failsafe = 2
        elif self.sensor_silent and (now - (s.sensor_silent_since_ns or now)) * 1e-9 >= config.sensor_failsafe_s:
            s.failsafe = 1
        if s.failsafe and not was:
            s.held_steer_rad = steer_rad
        idle = s.motor_ns is None or (now - s.motor_ns) * 1e-9 > config.motor_idle_s
        step = dt / config.brake_travel_s
        s.brake_position = min(max(s.brake_target, s.brake_position - step), s.brake_position + step)
        target_steer = s.held_steer_rad if s.failsafe else self.steering.steer_of_value(s.steer_value)
        throttle = 0.0 if idle or s.gear != 1 else s.throttle
        source = "steering-failsafe" if s.failsafe else "motor-idle" if idle else "command"
        if self.estop:
            throttle, source = 0.0, "estop-circuit"
        self.applied.append(AppliedCommand(now, ActuatorCommand(now, target_steer, throttle, s.brake_target), source))
        if not self.silent:
            self._report(now, counts, speed_mps, idle, throttle)
        return ActuatorCommand(now, target_steer, throttle, s.brake_position)

    def _report(self, now: int, counts: float, speed_mps: float, idle: bool, throttle: float) -> None:
        s = self.state
        frames: list[tuple[str, dict[str, float]]] = []
        if self._timers["speed"].due(now):
            kmh = round(max(speed_mps, 0.0) * 36.0) / 10.0
            frames.append(("Speed", {"Speed": kmh}))
            self.speed_reports.append((now, speed_mps, kmh))
        if self._timers["sensor"].due(now) and not self.sensor_silent:
            frames.append(("SteeringSensor", {"SteeringCounts": max(min(round(counts), 32767), -32768)}))
        if self._timers["feedback"].due(now):
            target_counts = self._sensor_counts(self.steering.steer_of_value(s.steer_value))
            steering_error = self.steering_error or s.failsafe
            frames += [
                ("BrakeFeedback", {"BrakePosition": round(s.brake_position * 1000),
                                   "BrakeTarget": round(s.brake_target * 1000),
                                   "BrakeDirection": int(s.brake_target > s.brake_position), "BrakeSpeed": 0,
                                   "BrakeError": 0}),
                ("SteeringFeedback", {"SteeringAngle": max(min(round(counts), 32767), -32768),
                                      "SteeringTargetCounts": max(min(round(target_counts), 32767), -32768),
                                      "SteeringDirection": 0, "SteeringError": steering_error}),
                ("MotorFeedback", {"ThrottleDac": round(throttle * 255), "Braking": int(s.brake_position > 0.05),
                                   "Gear": s.gear, "Idle": int(idle)}),
            ]
        for name, values in frames:
            message = self.db.get_message_by_name(name)
            data = message.encode(values, strict=False)
            self.bus.send(can.Message(arbitration_id=message.frame_id, data=bytes(data), is_extended_id=False))

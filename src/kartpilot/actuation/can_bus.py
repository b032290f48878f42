"""Commands to the kart's ECUs over CAN, and what the kart reports back.

The kart's description says which protocol its actuators speak (:mod:`kartpilot.core.vehicle`):
``rdw``, the RDW Self Driving Challenge kart's (:mod:`.rdw_protocol`), or ``kartpilot``, our own DBC
for self-built karts (:mod:`.kartpilot_protocol`). Both are encoded with cantools and sent with
python-can, on its virtual bus (tests, the simulator) or SocketCAN (``can0``, or ``vcan0`` on a
bench). The rest of the stack never sees a frame: it sends an :class:`ActuatorCommand` and reads
faults and a :class:`~kartpilot.core.types.VehicleFeedback`.

:class:`CanActuator` holds the bus, the latest command and the protocol's view of the kart. It sends
on a fixed schedule (``send_rate_hz``, 25 Hz as the organiser's sample: the periodic frames are what
keeps the RDW motor ECU from idling), except that a stop goes out at once. :meth:`CanActuator.tick`
does the periodic work: live, a sender thread calls it; in the simulator, the simulated bus's clock
does. When the loop has given no command for ``command_timeout_s`` (0.1 s, before the RDW motor
ECU's own 200 ms idle), the actuator sends the stop by itself.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Literal, Protocol

import can
import cantools

from kartpilot.actuation.kartpilot_protocol import KartpilotProtocol, check_ecus, load_dbc
from kartpilot.actuation.rdw_protocol import RdwConfig, RdwProtocol, load_rdw_dbc
from kartpilot.core.errors import ActuationError, ConfigError
from kartpilot.core.types import ActuatorCommand, VehicleFeedback
from kartpilot.core.vehicle import SteeringCalibration, VehicleParams

__all__ = [
    "ActuatorLimits",
    "CanActuator",
    "CanConfig",
    "KartProtocol",
    "PeriodicSchedule",
    "fan_out_frames",
    "limit_command",
    "make_protocol",
    "open_bus",
    "protocol_database",
]

log = logging.getLogger(__name__)

FrameLog = Callable[[int, int, bytes, str], None]  # stamp_ns, id, data, "tx"/"rx" (RecordingWriter.write_can)


def fan_out_frames(logs: list[FrameLog]) -> FrameLog | None:
    """One CAN frame log that writes to each of ``logs`` (the recording, the view); None for none."""
    if not logs:
        return None

    def log_frame(stamp_ns: int, arbitration_id: int, data: bytes, direction: str) -> None:
        for frame_log in logs:
            frame_log(stamp_ns, arbitration_id, data, direction)
    return log_frame


class KartProtocol(Protocol):
    """What a kart's protocol does for the actuator: frames for a command, and the kart's reports."""

    name: str

    def command_frames(self, command: ActuatorCommand, state: str) -> list[can.Message]: ...

    def receive(self, stamp_ns: int, frame: can.Message) -> None: ...

    @property
    def estop(self) -> bool: ...

    def faults(self, now_ns: int, state: str) -> list[str]: ...

    def feedback(self, now_ns: int) -> VehicleFeedback: ...

    def outputs(self) -> dict[str, float | int | str]: ...


@dataclass(frozen=True)
class CanConfig:
    """Attributes:
        interface, channel: python-can's interface and channel (``virtual``/any name, ``socketcan``/``can0``).
        bitrate: the bus's bit rate (ignored by the virtual bus and by SocketCAN, where ``ip link`` sets it).
        protocol: ``vehicle`` (what the kart's description says), ``rdw`` or ``kartpilot``.
        send_rate_hz: commands are repeated at this rate (the organiser's sample: every 0.04 s).
        command_timeout_s: when the loop has given no command for this long, the actuator sends the stop
            by itself (below the RDW motor ECU's 200 ms idle, so our stop is the first).
        dbc, status_timeout_s, ecus: the ``kartpilot`` protocol's DBC file (empty: the shipped
            ``kart.dbc``), how long an ECU's status may be missing, and the ECUs expected.
        rdw: the ``rdw`` protocol's gear, steering speed and watchdogs.
    """

    interface: str = "virtual"
    channel: str = "kartpilot"
    bitrate: int = 500_000
    protocol: Literal["vehicle", "rdw", "kartpilot"] = "vehicle"
    send_rate_hz: float = 25.0
    command_timeout_s: float = 0.1
    dbc: str = ""
    status_timeout_s: float = 0.1
    ecus: tuple[str, ...] = ("steer", "drive", "brake")
    rdw: RdwConfig = field(default_factory=RdwConfig)

    def __post_init__(self) -> None:
        check_ecus(self.ecus)
        for name in ("send_rate_hz", "status_timeout_s", "command_timeout_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"can.{name} must be a positive number, got {value}")


def _protocol_name(config: CanConfig, vehicle: VehicleParams) -> str:
    """The protocol the kart speaks; a DBC file given for the ``rdw`` protocol is an error, not ignored."""
    name = vehicle.protocol if config.protocol == "vehicle" else config.protocol
    if name == "rdw" and config.dbc:
        raise ConfigError(f"can.dbc ({config.dbc}) is the kartpilot protocol's DBC, but the {vehicle.name} speaks "
                          "rdw, whose messages the organiser fixes and kartpilot ships (actuation/rdw.dbc): drop "
                          "can.dbc, or set can.protocol: kartpilot to drive with it")
    return name


def make_protocol(config: CanConfig, vehicle: VehicleParams, steering: SteeringCalibration | None = None,
                  start_ns: int = 0) -> KartProtocol:
    """The protocol the kart speaks (``config.protocol``, or the vehicle's); ``steering`` overrides the
    vehicle's calibration (a rig file's)."""
    name = _protocol_name(config, vehicle)
    if name == "rdw":
        return RdwProtocol(steering or vehicle.steering, config.rdw, start_ns)
    return KartpilotProtocol(config.dbc, config.ecus, config.status_timeout_s, start_ns)


def protocol_database(config: CanConfig, vehicle: VehicleParams) -> cantools.database.can.Database:
    """The messages of the protocol the kart speaks (as :func:`make_protocol` picks it), to decode its traffic."""
    name = _protocol_name(config, vehicle)
    return load_rdw_dbc() if name == "rdw" else load_dbc(config.dbc)


@dataclass(frozen=True)
class ActuatorLimits:
    """What the actuators may be asked for, narrowing the kart's own range and rate (0: the kart's).
    A stop (brake) is never rate limited."""

    max_steer_rad: float = 0.0
    max_steer_rate_radps: float = 0.0
    max_throttle: float = 1.0
    max_throttle_rise_per_s: float = 2.0

    def __post_init__(self) -> None:
        for name in ("max_steer_rad", "max_steer_rate_radps", "max_throttle", "max_throttle_rise_per_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"limits.{name} must be a number >= 0, got {value}")
        if self.max_throttle > 1:
            raise ConfigError(f"limits.max_throttle must be at most 1, got {self.max_throttle}")

    def for_vehicle(self, vehicle: VehicleParams) -> ActuatorLimits:
        """These limits within the kart's steering range and rate."""
        def narrow(limit: float, own: float) -> float:
            return min(limit, own) if limit > 0 else own

        return replace(self, max_steer_rad=narrow(self.max_steer_rad, vehicle.max_steer_rad),
                       max_steer_rate_radps=narrow(self.max_steer_rate_radps, vehicle.steer_rate_radps))


def limit_command(previous: ActuatorCommand | None, command: ActuatorCommand, limits: ActuatorLimits,
                  dt_s: float) -> ActuatorCommand:
    """Clamp to the limits; limit the steer's rate and the throttle's rise; braking drops the throttle.
    ``limits`` must be resolved for the kart (:meth:`ActuatorLimits.for_vehicle`): 0 allows no steer."""
    steer = min(max(command.steer_rad, -limits.max_steer_rad), limits.max_steer_rad)
    throttle = min(max(command.throttle, 0.0), limits.max_throttle)
    brake = min(max(command.brake, 0.0), 1.0)
    if not all(math.isfinite(v) for v in (command.steer_rad, command.throttle, command.brake)):
        return ActuatorCommand.stop(command.stamp_ns)  # a NaN never reaches an actuator
    if previous is not None:
        step = limits.max_steer_rate_radps * max(dt_s, 0.0)
        steer = min(max(steer, previous.steer_rad - step), previous.steer_rad + step)
        throttle = min(throttle, previous.throttle + limits.max_throttle_rise_per_s * max(dt_s, 0.0))
    if brake > 0.0:
        throttle = 0.0
    return ActuatorCommand(command.stamp_ns, steer, throttle, brake)


def open_bus(config: CanConfig) -> can.BusABC:
    """The configured python-can bus; an interface that cannot be opened is named in the error."""
    kwargs: dict[str, Any] = {"interface": config.interface, "channel": config.channel}
    if config.interface not in ("virtual", "socketcan"):
        kwargs["bitrate"] = config.bitrate
    if config.interface == "virtual":
        kwargs["receive_own_messages"] = False
    try:
        return can.Bus(**kwargs)
    except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
        raise ActuationError(f"cannot open CAN interface {config.interface} channel {config.channel}: {exc}") from exc


@dataclass
class PeriodicSchedule:
    """A fixed grid of times one period apart: :meth:`due` says yes once per period, catches up by one
    period after a late call and starts anew after a whole period missed; :meth:`restart` puts the next
    time one period from now. The actuator's sends and the simulated ECUs' reports keep their rates by it."""

    period_ns: int
    next_ns: int | None = None

    def due(self, now_ns: int) -> bool:
        if self.next_ns is None or now_ns - self.next_ns >= self.period_ns:
            self.restart(now_ns)
            return True
        if now_ns >= self.next_ns:
            self.next_ns += self.period_ns
            return True
        return False

    def restart(self, now_ns: int) -> None:
        self.next_ns = now_ns + self.period_ns


class CanActuator:
    """The command sink on the kart's bus.

    ``send`` takes the loop's command (limited in range and rate); a harder brake than before goes out at
    once, anything else on the next periodic send. ``tick`` sends the latest command every
    ``1 / send_rate_hz`` and latches the stop when the loop has gone quiet; ``start`` runs ``tick`` in a
    thread (live). ``poll`` reads the kart's frames; ``faults`` and ``feedback`` say what they mean.
    """

    def __init__(self, bus: can.BusABC, protocol: KartProtocol, config: CanConfig, limits: ActuatorLimits,
                 clock: Callable[[], int] = time.monotonic_ns, log_frame: FrameLog | None = None) -> None:
        """``limits`` must be resolved for the kart (:meth:`ActuatorLimits.for_vehicle`)."""
        self.bus = bus
        self.protocol = protocol
        self.config = config
        self.limits = limits
        self.clock = clock
        self.log_frame = log_frame
        self.state = "disarmed"  # the supervisor's state (the kartpilot protocol's heartbeat sends it)
        self.last_command: ActuatorCommand | None = None
        self.frames_sent = 0
        self.tx_errors = 0
        self.rx_errors = 0
        self.quiet_stops = 0
        self._tx_fault = ""
        self._schedule = PeriodicSchedule(round(1e9 / config.send_rate_hz))
        self._last_loop_ns: int | None = None
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- sending ------------------------------------------------------------------------------------------
    def send(self, command: ActuatorCommand) -> None:
        """Take the loop's command; a stop (or any harder brake) is transmitted at once."""
        now = self.clock()
        with self._lock:
            previous = self.last_command
            dt = (now - self._last_loop_ns) * 1e-9 if self._last_loop_ns is not None else 0.0
            self._last_loop_ns = now
            self.last_command = limit_command(previous, command, self.limits, dt)
            if previous is None or self.last_command.brake > previous.brake:
                self._schedule.restart(now)
                self._transmit(now)

    def tick(self) -> None:
        """The periodic work: the stop when the loop is quiet, the latest command when due, the kart's frames."""
        now = self.clock()
        with self._lock:
            if self.last_command is not None:
                quiet_s = (now - self._last_loop_ns) * 1e-9 if self._last_loop_ns is not None else 0.0
                if quiet_s > self.config.command_timeout_s and not self.last_command.is_stop:
                    log.error("no command from the loop for %.2f s: sending the stop command", quiet_s)
                    self.quiet_stops += 1
                    self.last_command = ActuatorCommand.stop(now)
                    self._schedule.restart(now)
                    self._transmit(now)
                elif self._schedule.due(now):
                    self._transmit(now)
        self.poll()

    def _transmit(self, now: int) -> None:
        """Send the latest command's frames now (a send out of turn restarts the schedule first)."""
        command = self.last_command
        if command is None:
            return
        ok = True
        for frame in self.protocol.command_frames(command, self.state):
            try:
                self.bus.send(frame, timeout=0.005)
            except can.CanError as exc:
                ok = False
                self.tx_errors += 1
                if not self._tx_fault:
                    log.error("CAN transmit failed: %s", exc)
                self._tx_fault = f"CAN transmit failed ({exc})"
                break
            self.frames_sent += 1
            if self.log_frame is not None:
                self.log_frame(now, frame.arbitration_id, bytes(frame.data), "tx")
        if ok:
            self._tx_fault = ""

    def start(self) -> CanActuator:
        """Live: a thread calls :meth:`tick` every few milliseconds."""
        self._thread = threading.Thread(target=self._run, name="can-sender", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        interval = min(0.005, 0.25 / self.config.send_rate_hz)
        while not self._stop.wait(interval):
            self.tick()

    def close(self) -> None:
        """Send the stop command one last time and close the bus."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        try:
            with self._lock:
                self.last_command = ActuatorCommand.stop(self.clock())
                self._transmit(self.clock())
        finally:
            self.bus.shutdown()

    # -- receiving ----------------------------------------------------------------------------------------
    def poll(self) -> None:
        """Read every frame waiting on the bus and let the protocol keep what the kart reports."""
        while True:
            try:
                frame = self.bus.recv(timeout=0.0)
            except can.CanError as exc:
                self.rx_errors += 1
                log.warning("CAN receive failed: %s", exc)
                return
            if frame is None:
                return
            now = self.clock()
            if self.log_frame is not None:
                self.log_frame(now, frame.arbitration_id, bytes(frame.data), "rx")
            try:
                with self._lock:
                    self.protocol.receive(now, frame)
            except ActuationError as exc:
                self.rx_errors += 1
                log.warning("%s", exc)

    @property
    def estop(self) -> bool:
        """True while the kart reports its emergency-stop circuit open (where its protocol can say so)."""
        return self.protocol.estop

    def traffic(self) -> dict[str, object]:
        """What went over the bus, for a drive's result."""
        return {"protocol": self.protocol.name, "frames_sent": self.frames_sent, "tx_errors": self.tx_errors,
                "rx_errors": self.rx_errors, "quiet_stops": self.quiet_stops}

    def faults(self) -> list[str]:
        """What is wrong with the bus and the kart now (empty: all is well)."""
        with self._lock:
            found = [self._tx_fault] if self._tx_fault else []
            return found + self.protocol.faults(self.clock(), self.state)

    def feedback(self) -> VehicleFeedback:
        """The kart's measured speed and steering, where fresh."""
        with self._lock:
            return self.protocol.feedback(self.clock())

    def outputs(self) -> dict[str, float | int | str]:
        """What the kart last reported, for the recording's ``kart`` topic."""
        with self._lock:
            return self.protocol.outputs()

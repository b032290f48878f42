"""Commands to the kart's ECUs over CAN, and the ECUs' status back.

The messages are defined in a DBC file (``kart.dbc``, shipped with the package; a team with other
ECUs points ``can.dbc`` at its own), encoded and decoded with cantools and sent with python-can,
on its virtual bus (tests, the simulator) or SocketCAN (``can0``, or ``vcan0`` on a bench).

Every frame carries a rolling 4-bit ``Counter`` and a ``Checksum`` byte: the sum of the other
bytes and both bytes of the frame ID, masked to 8 bits and inverted. A receiver drops frames
whose checksum is wrong or whose counter did not move.

Pure functions do the work (:func:`limit_command`, :func:`command_frames`, :func:`encode`,
:func:`decode`); :class:`CanActuator` holds the bus, the last command and what it has heard from
each ECU, and reports faults: transmit errors (bus-off), an ECU whose status stops arriving, an
ECU reporting a fault, frames with bad checksums.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import can
import cantools

from kartpilot.core.errors import ActuationError, ConfigError
from kartpilot.core.types import ActuatorCommand

__all__ = [
    "DBC_PATH",
    "ActuatorLimits",
    "CanActuator",
    "CanConfig",
    "checksum",
    "command_frames",
    "decode",
    "encode",
    "limit_command",
    "load_dbc",
    "open_bus",
]

log = logging.getLogger(__name__)

DBC_PATH = Path(__file__).with_name("kart.dbc")
COMMAND_MESSAGES = ("SteerCommand", "ThrottleCommand", "BrakeCommand")
STATUS_MESSAGES = {"steer": "SteerStatus", "drive": "DriveStatus", "brake": "BrakeStatus"}
STATE_CODES = {"disarmed": 0, "manual": 1, "autonomous": 2, "paused": 3, "fault": 4}

FrameLog = Callable[[int, int, bytes, str], None]  # stamp_ns, id, data, "tx"/"rx" (RecordingWriter.write_can)


@dataclass(frozen=True)
class CanConfig:
    """Attributes:
        interface, channel: python-can's interface and channel (``virtual``/any name, ``socketcan``/``can0``).
        bitrate: the bus's bit rate (ignored by the virtual bus and by SocketCAN, where ``ip link`` sets it).
        dbc: the DBC file (empty: the shipped ``kart.dbc``).
        send_rate_hz: the live sender repeats the latest command at this rate.
        min_spacing_ms: never two command sets closer than this (an ECU is not flooded).
        status_timeout_s: an ECU whose status has not arrived for this long is reported.
        ecus: the ECUs whose status is expected (``steer``, ``drive``, ``brake``).
        command_timeout_s: live, when the loop has given no command for this long, the sender
            sends the stop command by itself.
    """

    interface: str = "virtual"
    channel: str = "kartpilot"
    bitrate: int = 500_000
    dbc: str = ""
    send_rate_hz: float = 50.0
    min_spacing_ms: float = 2.0
    status_timeout_s: float = 0.1
    ecus: tuple[str, ...] = ("steer", "drive", "brake")
    command_timeout_s: float = 0.2

    def __post_init__(self) -> None:
        unknown = set(self.ecus) - set(STATUS_MESSAGES)
        if unknown:
            raise ConfigError(f"can.ecus: unknown ECU(s) {', '.join(sorted(unknown))} ({', '.join(STATUS_MESSAGES)})")
        if self.send_rate_hz <= 0 or self.status_timeout_s <= 0 or self.command_timeout_s <= 0:
            raise ConfigError("can: send_rate_hz, status_timeout_s and command_timeout_s must be positive")


@dataclass(frozen=True)
class ActuatorLimits:
    """What the actuators may be asked for: range and rates. A stop (brake) is never rate limited."""

    max_steer_rad: float = 0.4
    max_steer_rate_radps: float = 3.0
    max_throttle: float = 1.0
    max_throttle_rise_per_s: float = 2.0


def limit_command(previous: ActuatorCommand | None, command: ActuatorCommand, limits: ActuatorLimits,
                  dt_s: float) -> ActuatorCommand:
    """Clamp to the limits; limit the steer's rate and the throttle's rise; braking drops the throttle."""
    steer = min(max(command.steer_rad, -limits.max_steer_rad), limits.max_steer_rad)
    throttle = min(max(command.throttle, 0.0), limits.max_throttle)
    brake = min(max(command.brake, 0.0), 1.0)
    if not all(math.isfinite(v) for v in (steer, throttle, brake)):
        return ActuatorCommand.stop(command.stamp_ns)  # a NaN never reaches an actuator
    if previous is not None:
        step = limits.max_steer_rate_radps * max(dt_s, 0.0)
        steer = min(max(steer, previous.steer_rad - step), previous.steer_rad + step)
        throttle = min(throttle, previous.throttle + limits.max_throttle_rise_per_s * max(dt_s, 0.0))
    if brake > 0.0:
        throttle = 0.0
    return ActuatorCommand(command.stamp_ns, steer, throttle, brake)


def load_dbc(path: str | Path | None = None) -> cantools.database.can.Database:
    """The kart's messages (the shipped DBC by default); every message needs Counter and Checksum."""
    path = Path(path) if path else DBC_PATH
    if not path.is_file():
        raise ConfigError(f"DBC file not found: {path}")
    try:
        db = cantools.database.load_file(str(path))
    except Exception as exc:  # cantools raises a variety of parser errors
        raise ConfigError(f"{path} is not a valid DBC file: {exc}") from exc
    if not isinstance(db, cantools.database.can.Database):
        raise ConfigError(f"{path} is not a CAN database")
    needed = [*COMMAND_MESSAGES, "Heartbeat", *STATUS_MESSAGES.values()]
    for name in needed:
        try:
            message = db.get_message_by_name(name)
        except KeyError as exc:
            raise ConfigError(f"{path} lacks the message {name}") from exc
        signals = {s.name for s in message.signals}
        if not {"Counter", "Checksum"} <= signals:
            raise ConfigError(f"{path}: message {name} needs Counter and Checksum signals")
    return db


def _checksum_byte(message: Any) -> int:
    signal = message.get_signal_by_name("Checksum")
    return int(signal.start) // 8


def checksum(frame_id: int, data: bytes, skip: int) -> int:
    """(sum of the bytes but ``skip`` + both bytes of the frame ID) & 0xFF, inverted."""
    total = sum(b for i, b in enumerate(data) if i != skip) + (frame_id & 0xFF) + ((frame_id >> 8) & 0xFF)
    return (total & 0xFF) ^ 0xFF


def encode(db: cantools.database.can.Database, name: str, values: dict[str, Any], counter: int) -> can.Message:
    """One frame of message ``name``, with its counter and checksum."""
    message = db.get_message_by_name(name)
    data = bytearray(message.encode({**values, "Counter": counter % 16, "Checksum": 0}, strict=False))
    skip = _checksum_byte(message)
    data[skip] = checksum(message.frame_id, bytes(data), skip)
    return can.Message(arbitration_id=message.frame_id, data=bytes(data), is_extended_id=False)


def decode(db: cantools.database.can.Database, frame: can.Message) -> tuple[str, dict[str, Any]]:
    """(message name, signal values); raises ActuationError for an unknown frame or a wrong checksum."""
    try:
        message = db.get_message_by_frame_id(frame.arbitration_id)
    except KeyError as exc:
        raise ActuationError(f"unknown CAN frame {frame.arbitration_id:#x}") from exc
    data = bytes(frame.data)
    skip = _checksum_byte(message)
    if len(data) != message.length or data[skip] != checksum(message.frame_id, data, skip):
        raise ActuationError(f"{message.name}: wrong checksum or length")
    values = message.decode(data, decode_choices=False)
    assert isinstance(values, dict)  # a plain (not multiplexed-container) message
    return message.name, dict(values)


def command_frames(db: cantools.database.can.Database, command: ActuatorCommand, state: str,
                   counter: int) -> list[can.Message]:
    """The steer, throttle and brake commands and the heartbeat, for one send."""
    enable = 0 if command.brake >= 1.0 and command.throttle == 0.0 else 1
    return [
        encode(db, "SteerCommand", {"SteerAngle": command.steer_rad, "Enable": enable}, counter),
        encode(db, "ThrottleCommand", {"Throttle": command.throttle, "Enable": enable}, counter),
        encode(db, "BrakeCommand", {"Brake": command.brake, "Enable": 1}, counter),
        encode(db, "Heartbeat", {"State": STATE_CODES.get(state, STATE_CODES["fault"])}, counter),
    ]


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
class _EcuSeen:
    last_ns: int | None = None
    fault: int = 0
    counter: int | None = None
    values: dict[str, Any] = field(default_factory=dict)


class CanActuator:
    """The command sink on the kart's bus. ``send`` transmits at once (the loop's rate); ``start`` adds a
    sender thread that repeats the latest command at ``send_rate_hz`` and sends the stop command by itself
    when the loop has gone quiet for ``command_timeout_s``."""

    def __init__(self, bus: can.BusABC, config: CanConfig | None = None, limits: ActuatorLimits | None = None,
                 clock: Callable[[], int] = time.monotonic_ns, log_frame: FrameLog | None = None) -> None:
        self.bus = bus
        self.config = config or CanConfig()
        self.limits = limits or ActuatorLimits()
        self.db = load_dbc(self.config.dbc or None)
        self.clock = clock
        self.log_frame = log_frame
        self.state = "disarmed"  # the supervisor's state, sent in the heartbeat
        self.last_command: ActuatorCommand | None = None
        self.frames_sent = 0
        self.tx_errors = 0
        self.rx_errors = 0
        self.skipped_sends = 0
        self._tx_fault = ""
        self._counter = 0
        self._last_tx_ns: int | None = None
        self._last_loop_ns: int | None = None
        self._ecus = {name: _EcuSeen() for name in self.config.ecus}
        self._start_ns = clock()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- sending ------------------------------------------------------------------------------------------
    def send(self, command: ActuatorCommand) -> None:
        """Limit and transmit ``command`` (the stop command is never held back by the spacing)."""
        now = self.clock()
        with self._lock:
            self._last_loop_ns = now
            previous = self.last_command
            dt = (now - self._last_tx_ns) * 1e-9 if self._last_tx_ns is not None else 0.0
            limited = limit_command(previous, command, self.limits, dt)
            self.last_command = limited
            urgent = limited.brake > 0 and (previous is None or previous.brake < limited.brake)
            self._transmit(now, urgent)

    def _transmit(self, now: int, urgent: bool = False) -> None:
        command = self.last_command
        if command is None:
            return
        if (not urgent and self._last_tx_ns is not None
                and (now - self._last_tx_ns) < self.config.min_spacing_ms * 1e6):
            self.skipped_sends += 1
            return
        self._counter = (self._counter + 1) % 16
        ok = True
        for frame in command_frames(self.db, replace(command, stamp_ns=now), self.state, self._counter):
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
        self._last_tx_ns = now

    def start(self) -> CanActuator:
        """Live: repeat the latest command at ``send_rate_hz``; stop by itself when the loop goes quiet."""
        self._thread = threading.Thread(target=self._run, name="can-sender", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        period = 1.0 / self.config.send_rate_hz
        while not self._stop.wait(period):
            now = self.clock()
            with self._lock:
                if self.last_command is None:
                    continue
                quiet = self._last_loop_ns is not None and (now - self._last_loop_ns) * 1e-9 > \
                    self.config.command_timeout_s
                if quiet and self.last_command.brake < 1.0:
                    log.error("no command from the loop for %.2f s: sending the stop command",
                              (now - self._last_loop_ns) * 1e-9 if self._last_loop_ns else 0.0)
                    self.last_command = ActuatorCommand.stop(now)
                    self._transmit(now, urgent=True)
                elif self._last_tx_ns is None or (now - self._last_tx_ns) * 1e-9 >= period * 0.9:
                    self._transmit(now)
            self.poll()

    def close(self) -> None:
        """Send the stop command one last time and close the bus."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        try:
            with self._lock:
                self.last_command = ActuatorCommand.stop(self.clock())
                self._transmit(self.clock(), urgent=True)
        finally:
            self.bus.shutdown()

    # -- receiving ----------------------------------------------------------------------------------------
    def poll(self) -> None:
        """Read every frame waiting on the bus and keep what each ECU reports."""
        names = {self.db.get_message_by_name(m).frame_id: ecu for ecu, m in STATUS_MESSAGES.items()
                 if ecu in self._ecus}
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
            ecu = names.get(frame.arbitration_id)
            if ecu is None:
                continue
            try:
                _, values = decode(self.db, frame)
            except ActuationError as exc:
                self.rx_errors += 1
                log.warning("%s", exc)
                continue
            seen = self._ecus[ecu]
            if seen.counter is not None and values["Counter"] == seen.counter:
                continue  # a repeated frame is not news
            seen.counter, seen.last_ns, seen.fault, seen.values = values["Counter"], now, int(values["Fault"]), values

    @property
    def estop(self) -> bool:
        """True while the brake ECU reports the emergency-stop circuit open."""
        brake = self._ecus.get("brake")
        return bool(brake is not None and brake.values.get("EStop", 0))

    def ecu_values(self, ecu: str) -> dict[str, Any]:
        return dict(self._ecus[ecu].values)

    def faults(self) -> list[str]:
        """What is wrong with the bus and the ECUs now (empty: all is well)."""
        now = self.clock()
        found = [self._tx_fault] if self._tx_fault else []
        message = self.db.get_message_by_name("SteerStatus")
        choices: dict[Any, Any] = dict(message.get_signal_by_name("Fault").choices or {})
        for ecu, seen in self._ecus.items():
            since = seen.last_ns if seen.last_ns is not None else self._start_ns
            if (now - since) * 1e-9 > self.config.status_timeout_s:
                found.append(f"no status from the {ecu} ECU for {(now - since) * 1e-9:.2f} s")
            elif seen.fault:
                found.append(f"the {ecu} ECU reports {choices.get(seen.fault, seen.fault)}")
        return found

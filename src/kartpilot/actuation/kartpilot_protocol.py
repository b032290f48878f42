"""kartpilot's own CAN protocol, for self-built karts such as the ``rc-kart``.

The messages are defined in a DBC file (``kart.dbc``, shipped with the package; a team with other
ECUs points ``can.dbc`` at its own), encoded and decoded with cantools. Every frame carries a rolling
4-bit ``Counter`` and a ``Checksum`` byte: the sum of the other bytes and both bytes of the frame ID,
masked to 8 bits and inverted. A receiver drops frames whose checksum is wrong or whose counter did
not move. kartpilot sends a ``Heartbeat`` with the supervisor's state; an ECU that misses it brakes.

Pure functions do the encoding (:func:`checksum`, :func:`encode`, :func:`decode`, :func:`command_frames`);
:class:`KartpilotProtocol` keeps what each ECU last reported and says what is wrong.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import cantools

from kartpilot.core.errors import ActuationError, ConfigError
from kartpilot.core.types import ActuatorCommand, VehicleFeedback

__all__ = [
    "DBC_PATH",
    "STATUS_MESSAGES",
    "KartpilotProtocol",
    "check_ecus",
    "checksum",
    "command_frames",
    "decode",
    "encode",
    "load_dbc",
]

DBC_PATH = Path(__file__).with_name("kart.dbc")
COMMAND_MESSAGES = ("SteerCommand", "ThrottleCommand", "BrakeCommand")
STATUS_MESSAGES = {"steer": "SteerStatus", "drive": "DriveStatus", "brake": "BrakeStatus"}
STATE_CODES = {"disarmed": 0, "manual": 1, "autonomous": 2, "paused": 3, "fault": 4}


def check_ecus(ecus: tuple[str, ...]) -> None:
    """The ECUs named must be ones whose status the DBC defines (``can.ecus``)."""
    unknown = set(ecus) - set(STATUS_MESSAGES)
    if unknown:
        raise ConfigError(f"can.ecus: unknown ECU(s) {', '.join(sorted(unknown))} ({', '.join(STATUS_MESSAGES)})")


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
    enable = 0 if command.is_stop else 1
    return [
        encode(db, "SteerCommand", {"SteerAngle": command.steer_rad, "Enable": enable}, counter),
        encode(db, "ThrottleCommand", {"Throttle": command.throttle, "Enable": enable}, counter),
        encode(db, "BrakeCommand", {"Brake": command.brake, "Enable": 1}, counter),
        encode(db, "Heartbeat", {"State": STATE_CODES.get(state, STATE_CODES["fault"])}, counter),
    ]


@dataclass
class _EcuSeen:
    last_ns: int | None = None
    fault: int = 0
    counter: int | None = None
    values: dict[str, Any] = field(default_factory=dict)


class KartpilotProtocol:
    """Our DBC on the bus: commands with counter and checksum, the heartbeat, each ECU's status.

    Args:
        dbc: the DBC file (empty: the shipped ``kart.dbc``).
        ecus: the ECUs whose status is expected (``steer``, ``drive``, ``brake``).
        status_timeout_s: an ECU whose status has not arrived for this long is a fault.
        start_ns: when listening started (an ECU never heard from is silent since then).
    """

    name = "kartpilot"

    def __init__(self, dbc: str = "", ecus: tuple[str, ...] = ("steer", "drive", "brake"),
                 status_timeout_s: float = 0.1, start_ns: int = 0) -> None:
        check_ecus(ecus)
        self.db = load_dbc(dbc or None)
        self.status_timeout_s = status_timeout_s
        self._counter = 0
        self._start_ns = start_ns
        self._ecus = {name: _EcuSeen() for name in ecus}
        self._status_ids = {self.db.get_message_by_name(m).frame_id: ecu for ecu, m in STATUS_MESSAGES.items()
                            if ecu in self._ecus}
        choices: Any = self.db.get_message_by_name("SteerStatus").get_signal_by_name("Fault").choices
        self._fault_names: dict[Any, Any] = dict(choices or {})

    def command_frames(self, command: ActuatorCommand, state: str) -> list[can.Message]:
        self._counter = (self._counter + 1) % 16
        return command_frames(self.db, command, state, self._counter)

    def receive(self, stamp_ns: int, frame: can.Message) -> None:
        """Keep an ECU's status; a status with a wrong checksum raises ActuationError, other ids are ignored."""
        ecu = self._status_ids.get(frame.arbitration_id)
        if ecu is None:
            return
        _, values = decode(self.db, frame)
        seen = self._ecus[ecu]
        if seen.counter is not None and values["Counter"] == seen.counter:
            return  # a repeated frame is not news
        seen.counter, seen.last_ns, seen.fault, seen.values = values["Counter"], stamp_ns, int(values["Fault"]), values

    @property
    def estop(self) -> bool:
        """True while the brake ECU reports the emergency-stop circuit open."""
        brake = self._ecus.get("brake")
        return bool(brake is not None and brake.values.get("EStop", 0))

    def ecu_values(self, ecu: str) -> dict[str, Any]:
        return dict(self._ecus[ecu].values)

    def faults(self, now_ns: int, state: str) -> list[str]:
        found = []
        for ecu, seen in self._ecus.items():
            since = seen.last_ns if seen.last_ns is not None else self._start_ns
            if (now_ns - since) * 1e-9 > self.status_timeout_s:
                found.append(f"no status from the {ecu} ECU for {(now_ns - since) * 1e-9:.2f} s")
            elif seen.fault:
                found.append(f"the {ecu} ECU reports {self._fault_names.get(seen.fault, seen.fault)}")
        return found

    def _fresh(self, ecu: str, signal: str, now_ns: int) -> float | None:
        seen = self._ecus.get(ecu)
        if seen is None or seen.last_ns is None or (now_ns - seen.last_ns) * 1e-9 > self.status_timeout_s:
            return None
        return float(seen.values[signal])

    def feedback(self, now_ns: int) -> VehicleFeedback:
        return VehicleFeedback(now_ns, self._fresh("drive", "Speed", now_ns), self._fresh("steer", "SteerMeasured",
                                                                                          now_ns))

    def outputs(self) -> dict[str, float | int | str]:
        """The ECUs' last reports, for the recording's ``kart`` topic (NaN: not heard yet)."""
        values: dict[str, float | int | str] = {}
        for ecu, seen in self._ecus.items():
            for signal in self.db.get_message_by_name(STATUS_MESSAGES[ecu]).signals:
                if signal.name not in ("Counter", "Checksum"):
                    values[f"{ecu}_{signal.name}"] = float(seen.values.get(signal.name, math.nan))
        return values

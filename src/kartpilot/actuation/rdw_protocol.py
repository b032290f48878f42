"""The RDW Self Driving Challenge kart's CAN protocol, byte for byte.

The electric go-kart the RDW lends to Self Driving Challenge teams has three actuator ECUs (brake,
steering, motor) and two sensors on a 500 kbit/s bus with standard 11-bit IDs. The organiser
documents the frames in its public sample code and wiki; ``rdw.dbc`` (shipped with the package)
writes them down for cantools:

* commands, repeated every 0.04 s: ``0x110`` brake (byte 0, 0 to 100 %), ``0x220`` steering (a
  float32 little-endian target in [-1.25, 1.25], positive steers **right**; bytes 4 to 7 the steering
  speed), ``0x330`` motor (byte 0 throttle %, byte 2 gear: 0 neutral, 1 forward, 2 reverse; a gear of
  3 or more makes the ECU ignore the frame);
* from the kart: ``0x440`` speed (big-endian, 0.1 km/h), ``0x1E5`` steering sensor (bytes 1 and 2,
  big-endian int16, valid -800 to 800; out of range or silent for 0.2 s sends the steering ECU to its
  failsafe), and the ECUs' feedback ``0x710`` (brake), ``0x720`` (steering), ``0x730`` (motor, with
  its idle flag after 200 ms without ``0x330``).

There is no counter, checksum or heartbeat: the periodic commands are the heartbeat. The stack's
``steer_rad`` (positive left) becomes the ECU's value through the kart's
:class:`~kartpilot.core.vehicle.SteeringCalibration`; throttle and brake become whole percent.
:class:`RdwProtocol` keeps what the kart last said and turns it into faults and measured feedback.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import can
import cantools

from kartpilot.core.errors import ActuationError, ConfigError
from kartpilot.core.types import ActuatorCommand, VehicleFeedback
from kartpilot.core.vehicle import SteeringCalibration

__all__ = [
    "FEEDBACK",
    "GEARS",
    "RDW_DBC_PATH",
    "RdwConfig",
    "RdwProtocol",
    "decode_rdw",
    "load_rdw_dbc",
    "rdw_command_frames",
]

RDW_DBC_PATH = Path(__file__).with_name("rdw.dbc")
GEARS = {"neutral": 0, "forward": 1, "reverse": 2}
SENSOR_RANGE = 800
# what the kart reports: name in the config -> (message, what a person calls it)
FEEDBACK = {"speed": ("Speed", "speed"), "steering_sensor": ("SteeringSensor", "steering sensor"),
            "brake_ecu": ("BrakeFeedback", "brake ECU feedback"),
            "steering_ecu": ("SteeringFeedback", "steering ECU feedback"),
            "motor_ecu": ("MotorFeedback", "motor ECU feedback")}
ARMED = ("manual", "autonomous", "paused")


@dataclass(frozen=True)
class RdwConfig:
    """Attributes:
        steering_speed: bytes 4 to 7 of the steering command (the organiser's sample sends 00 00 C3 00,
            49920); 0 sends a 4-byte frame, and the ECU uses its default of 50000 steps/s.
        gear: ``forward`` unless a person asks otherwise; ``reverse`` goes out only while the kart is
            stopped (measured speed under ``reverse_below_mps``), neutral until then.
        sensor_timeout_s: the steering sensor silent this long is a fault (the ECU's own failsafe: 0.2 s).
        feedback_timeout_s: any other expected frame silent this long is a fault.
        expect: which of the kart's frames must keep arriving (speed, steering_sensor, brake_ecu,
            steering_ecu, motor_ecu); a kart that lacks one can leave it out.
    """

    steering_speed: int = 0xC300
    gear: Literal["forward", "neutral", "reverse"] = "forward"
    reverse_below_mps: float = 0.1
    sensor_timeout_s: float = 0.2
    feedback_timeout_s: float = 0.5
    expect: tuple[str, ...] = ("speed", "steering_sensor", "brake_ecu", "steering_ecu", "motor_ecu")

    def __post_init__(self) -> None:
        unknown = set(self.expect) - set(FEEDBACK)
        if unknown:
            raise ConfigError(f"can.rdw.expect: unknown frame(s) {', '.join(sorted(unknown))} "
                              f"({', '.join(FEEDBACK)})")
        if not 0 <= self.steering_speed < 2**32:
            raise ConfigError(f"can.rdw.steering_speed must be 0 to 2^32 - 1, got {self.steering_speed}")
        for name in ("reverse_below_mps", "sensor_timeout_s", "feedback_timeout_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"can.rdw.{name} must be a positive number, got {value}")


def load_rdw_dbc() -> cantools.database.can.Database:
    """The RDW kart's messages (``rdw.dbc``, shipped with the package)."""
    db = cantools.database.load_file(str(RDW_DBC_PATH))
    assert isinstance(db, cantools.database.can.Database)
    return db


def _percent(fraction: float) -> int:
    return round(min(max(fraction, 0.0), 1.0) * 100)


def rdw_command_frames(db: cantools.database.can.Database, steer_value: float, throttle: float, brake: float,
                       gear: str, steering_speed: int) -> list[can.Message]:
    """The brake (0x110), steering (0x220) and motor (0x330) frames for one send.

    Args:
        steer_value: the steering ECU's value, positive right, clamped to [-1.25, 1.25].
        throttle, brake: 0 to 1, sent as whole percent.
        gear: ``neutral``, ``forward`` or ``reverse`` (nothing else can be encoded: a gear of 3 or more
            would make the ECU ignore the frame).
        steering_speed: bytes 4 to 7 of the steering frame; 0 sends the 4-byte frame.
    """
    if gear not in GEARS:
        raise ActuationError(f"gear {gear!r} is not one of {', '.join(GEARS)}")
    if not math.isfinite(steer_value):
        raise ActuationError("the steering value is not a number")
    value = min(max(steer_value, -1.25), 1.25)
    steering = db.get_message_by_name("SteeringCommand").encode({"SteeringTarget": value,
                                                                 "SteeringSpeed": steering_speed})
    if steering_speed == 0:
        steering = steering[:4]
    frames = [
        (0x110, db.get_message_by_name("BrakeCommand").encode({"BrakePercent": _percent(brake)})),
        (0x220, steering),
        (0x330, db.get_message_by_name("MotorCommand").encode({"ThrottlePercent": _percent(throttle),
                                                               "Reserved": 0, "Gear": GEARS[gear]})),
    ]
    return [can.Message(arbitration_id=i, data=bytes(d), is_extended_id=False) for i, d in frames]


def decode_rdw(db: cantools.database.can.Database, frame: can.Message) -> tuple[str, dict[str, Any]] | None:
    """(message name, values) of one of the kart's frames; None for an id the protocol does not define.

    A steering command of 4 bytes (the ECU's default speed) decodes with ``SteeringSpeed`` 0. A shorter frame
    gives the signals whose bytes it holds (the teams' decoders read the speed from the first two bytes of 0x440
    whatever its length, and a team's kart simulator sends 2-byte speed frames); one that holds no signal's
    bytes raises ActuationError, which the bus counts as a receive error.
    """
    try:
        message = db.get_message_by_frame_id(frame.arbitration_id)
    except KeyError:
        return None
    data = bytes(frame.data)
    if message.name == "SteeringCommand" and len(data) == 4:
        data += bytes(4)
    held = [signal.name for signal in message.signals if _last_byte(signal) < len(data)]
    if not held:
        raise ActuationError(f"{message.name} ({frame.arbitration_id:#x}): {len(data)} bytes hold none of its "
                             f"signals ({message.length} expected)")
    values = message.decode(data[:message.length].ljust(message.length, b"\0"), decode_choices=False, scaling=True)
    assert isinstance(values, dict)
    return message.name, {name: values[name] for name in held}


def _last_byte(signal: cantools.database.can.Signal) -> int:
    """The last byte a signal's bits reach (Intel: counting up from its start bit; Motorola: its start bit is
    the most significant, and the bits run down the byte and on into the next ones)."""
    if signal.byte_order == "little_endian":
        return (signal.start + signal.length - 1) // 8
    first_bits = signal.start % 8 + 1
    rest = max(signal.length - first_bits, 0)
    return signal.start // 8 + -(-rest // 8)


class RdwProtocol:
    """The RDW kart on the bus: what to send for a command, and what its frames say.

    Args:
        steering: the kart's steering calibration (steer_rad <-> ECU value <-> sensor counts).
        config: gear, steering speed, watchdog timeouts.
        start_ns: when listening started (a frame never heard is silent since then).
    """

    name = "rdw"

    def __init__(self, steering: SteeringCalibration, config: RdwConfig | None = None, start_ns: int = 0) -> None:
        self.steering = steering
        self.config = config or RdwConfig()
        self.db = load_rdw_dbc()
        self._start_ns = start_ns
        self._seen: dict[str, tuple[int, dict[str, Any]]] = {}
        self._by_message = {message: key for key, (message, _) in FEEDBACK.items()}
        self._frame_ids = {key: self.db.get_message_by_name(message).frame_id for key, (message, _) in FEEDBACK.items()}
        self._timeout_s = {key: self.config.sensor_timeout_s if key == "steering_sensor" else
                           self.config.feedback_timeout_s for key in FEEDBACK}
        self.raw: dict[str, str] = {}

    def gear(self) -> str:
        """The gear to send: reverse only once the kart is known to stand still."""
        if self.config.gear != "reverse":
            return self.config.gear
        speed = self._fresh("speed", "Speed", None)
        return "reverse" if speed is not None and speed / 3.6 < self.config.reverse_below_mps else "neutral"

    def command_frames(self, command: ActuatorCommand, state: str) -> list[can.Message]:
        return rdw_command_frames(self.db, self.steering.value_of(command.steer_rad), command.throttle, command.brake,
                                  self.gear(), self.config.steering_speed)

    def receive(self, stamp_ns: int, frame: can.Message) -> None:
        """Keep what one of the kart's frames says (our own commands and unknown ids are ignored)."""
        decoded = decode_rdw(self.db, frame)
        if decoded is None:
            return
        name, values = decoded
        key = self._by_message.get(name)
        if key is not None:
            self._seen[key] = (stamp_ns, values)
            self.raw[key] = bytes(frame.data).hex()

    @property
    def estop(self) -> bool:
        """The RDW kart's emergency stop cuts its power; nothing on the bus says so."""
        return False

    def _fresh(self, key: str, signal: str, now_ns: int | None) -> float | None:
        seen = self._seen.get(key)
        if seen is None:
            return None
        if now_ns is not None and (now_ns - seen[0]) * 1e-9 > self._timeout_s[key]:
            return None
        value = seen[1].get(signal)  # a short frame may not hold it
        return None if value is None else float(value)

    def faults(self, now_ns: int, state: str) -> list[str]:
        found = []
        for key in self.config.expect:
            since = self._seen[key][0] if key in self._seen else self._start_ns
            if (now_ns - since) * 1e-9 > self._timeout_s[key]:
                found.append(f"no {FEEDBACK[key][1]} ({self._frame_ids[key]:#x}) for {(now_ns - since) * 1e-9:.2f} s")
        counts = self._fresh("steering_sensor", "SteeringCounts", None)
        if counts is not None and abs(counts) > SENSOR_RANGE:
            found.append(f"steering sensor out of range ({counts:.0f} counts, valid -{SENSOR_RANGE} to {SENSOR_RANGE})")
        for key, signal, who in (("steering_ecu", "SteeringError", "steering"), ("brake_ecu", "BrakeError", "brake")):
            error = self._fresh(key, signal, None)
            if error:
                found.append(f"the {who} ECU reports error {error:.0f}")
        idle = self._fresh("motor_ecu", "Idle", None)
        if idle and state in ARMED:
            found.append("the motor ECU is idle (it saw no motor command for 200 ms)")
        return found

    def sensor_counts(self, now_ns: int) -> float | None:
        """The steering sensor's latest counts, where fresh (the steering calibration's raw reading)."""
        return self._fresh("steering_sensor", "SteeringCounts", now_ns)

    def feedback(self, now_ns: int) -> VehicleFeedback:
        speed_kmh = self._fresh("speed", "Speed", now_ns)
        counts = self._fresh("steering_sensor", "SteeringCounts", now_ns)
        steer = self.steering.steer_of_counts(counts) if counts is not None and abs(counts) <= SENSOR_RANGE else None
        return VehicleFeedback(now_ns, None if speed_kmh is None else speed_kmh / 3.6, steer)

    def outputs(self) -> dict[str, float | int | str]:
        """What the kart last said, decoded, for the recording's ``kart`` topic (NaN: not heard yet); the raw
        bytes of the brake ECU's feedback too, whose fields the organiser documents least."""
        values: dict[str, float | int | str] = {}
        for key in FEEDBACK:
            message = self.db.get_message_by_name(FEEDBACK[key][0])
            seen = self._seen.get(key)
            for signal in message.signals:
                values[signal.name] = float(seen[1][signal.name]) if seen is not None else math.nan
        counts = values["SteeringCounts"]
        values["steer_measured_rad"] = (self.steering.steer_of_counts(float(counts))
                                        if isinstance(counts, float) and math.isfinite(counts) else math.nan)
        values["brake_raw"] = self.raw.get("brake_ecu", "")
        return values

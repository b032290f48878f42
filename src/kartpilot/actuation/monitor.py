"""What is on the kart's bus, message by message: the bench view a team debugs its kart with.

:func:`summarise_traffic` turns frames (live from a bus, or a recording's ``can.csv``) into one
:class:`TrafficRow` per message id and direction: its name in the protocol, how many, the rate, the
longest gap, the last decoded values and what is wrong with them (a frame that does not decode, a
steering sensor out of range, an ECU's error flag, the motor ECU idle, a gear it would ignore).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import can

from kartpilot.actuation.kartpilot_protocol import decode, load_dbc
from kartpilot.actuation.rdw_protocol import SENSOR_RANGE, decode_rdw, load_rdw_dbc
from kartpilot.core.errors import ActuationError, ConfigError

__all__ = ["TrafficRow", "format_traffic", "summarise_traffic"]

Frame = tuple[int, str, int, bytes]  # stamp_ns, "tx"/"rx", id, data (RecordingReader.can_frames)


@dataclass
class TrafficRow:
    """One message id in one direction. Rates and gaps are over the frames seen."""

    frame_id: int
    direction: str
    name: str = "?"
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    max_gap_ns: int = 0
    values: dict[str, Any] = field(default_factory=dict)
    raw: str = ""
    faults: list[str] = field(default_factory=list)

    @property
    def rate_hz(self) -> float:
        return (self.count - 1) / ((self.last_ns - self.first_ns) * 1e-9) if self.count > 1 and \
            self.last_ns > self.first_ns else math.nan


def _decoder(protocol: str) -> Callable[[can.Message], tuple[str, dict[str, Any]] | None]:
    if protocol == "rdw":
        rdw = load_rdw_dbc()
        return lambda frame: decode_rdw(rdw, frame)
    if protocol == "kartpilot":
        ours = load_dbc()
        return lambda frame: decode(ours, frame)
    raise ConfigError(f"unknown protocol {protocol!r} (rdw, kartpilot)")


def _problems(name: str, values: dict[str, Any]) -> list[str]:
    """What a decoded message says is wrong (the RDW kart's flags and ranges; our DBC's fault codes)."""
    found = []
    if name == "SteeringSensor" and abs(values["SteeringCounts"]) > SENSOR_RANGE:
        found.append(f"out of range ({values['SteeringCounts']:.0f} counts)")
    if name == "MotorCommand" and values["Gear"] >= 3:
        found.append(f"gear {values['Gear']:.0f}: the motor ECU ignores this frame")
    for key in ("SteeringError", "BrakeError", "Fault"):
        if values.get(key):
            found.append(f"{key} {values[key]:.0f}")
    if name == "MotorFeedback" and values.get("Idle"):
        found.append("motor ECU idle")
    if name == "BrakeStatus" and values.get("EStop"):
        found.append("emergency stop open")
    return found


def summarise_traffic(frames: Iterable[Frame], protocol: str) -> list[TrafficRow]:
    """One row per (id, direction), in id order, from frames in time order."""
    decode_frame = _decoder(protocol)
    rows: dict[tuple[int, str], TrafficRow] = {}
    for stamp_ns, direction, frame_id, data in frames:
        row = rows.get((frame_id, direction))
        if row is None:
            row = rows[frame_id, direction] = TrafficRow(frame_id, direction, first_ns=stamp_ns, last_ns=stamp_ns)
        else:
            row.max_gap_ns = max(row.max_gap_ns, stamp_ns - row.last_ns)
            row.last_ns = stamp_ns
        row.count += 1
        row.raw = bytes(data).hex(" ")
        try:
            decoded = decode_frame(can.Message(arbitration_id=frame_id, data=bytes(data), is_extended_id=False))
        except ActuationError as exc:
            row.faults = [str(exc)]
            continue
        if decoded is None:
            row.name, row.faults = "?", ["not in the protocol"]
            continue
        row.name, row.values = decoded
        row.faults = _problems(row.name, row.values)
    return [rows[key] for key in sorted(rows)]


def format_traffic(rows: list[TrafficRow]) -> str:
    """A table: one line per message, its rate, longest gap, last values and faults."""
    if not rows:
        return "no CAN frames"
    lines = []
    for row in rows:
        values = " ".join(f"{k}={v:g}" if isinstance(v, (int, float)) else f"{k}={v}" for k, v in row.values.items()
                          if k not in ("Counter", "Checksum"))
        rate = f"{row.rate_hz:6.1f} Hz" if math.isfinite(row.rate_hz) else "     - Hz"
        faults = f"  !! {'; '.join(row.faults)}" if row.faults else ""
        lines.append(f"{row.frame_id:#05x} {row.direction} {row.name:<17} {rate} n={row.count:<6} gap max "
                     f"{row.max_gap_ns * 1e-6:5.0f} ms  {values or row.raw}{faults}")
    return "\n".join(lines)

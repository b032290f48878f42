"""``kartpilot can monitor``: the kart's CAN traffic decoded, live from a bus or from a recording."""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import asdict, replace
from pathlib import Path

from kartpilot.actuation.can_bus import open_bus
from kartpilot.actuation.monitor import TrafficRow, format_traffic, summarise_traffic
from kartpilot.core.errors import ConfigError, RecordingError
from kartpilot.core.files import write_json_atomic
from kartpilot.core.vehicle import get_vehicle
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.config import load_stack_config

__all__ = ["can_monitor"]


def _rows_json(rows: list[TrafficRow]) -> list[dict[str, object]]:
    return [{**asdict(row), "frame_id": f"{row.frame_id:#x}", "rate_hz": round(row.rate_hz, 3)
             if math.isfinite(row.rate_hz) else None} for row in rows]


def can_monitor(args: argparse.Namespace) -> int:
    """One line per message id: rate, longest gap, last decoded values and faults."""
    for name, value in (("--duration", args.duration), ("--every", args.every)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ConfigError(f"{name} {value}: must be a positive number of seconds")
    out = Path(args.json) if args.json else None
    if out is not None and (out.is_dir() or not out.parent.is_dir()):
        raise ConfigError(f"--json {out}: {'is a folder' if out.is_dir() else 'its folder does not exist'}")
    if args.recording:
        reader = RecordingReader(args.recording)
        frames = reader.can_frames()
        if not frames:
            raise RecordingError(f"{args.recording} holds no CAN traffic (no can.csv)")
        protocol = args.protocol or (get_vehicle(reader.vehicle).protocol if reader.vehicle else "rdw")
        rows = summarise_traffic(frames, protocol)
        print(f"{args.recording}: {len(frames)} frames, protocol {protocol}")
        print(format_traffic(rows))
    else:
        stack = load_stack_config(args.config)
        config = replace(stack.can, interface=args.bus or stack.can.interface,
                         channel=args.channel or stack.can.channel)
        protocol = args.protocol or "rdw"
        bus = open_bus(config)
        heard: list[tuple[int, str, int, bytes]] = []
        start = time.monotonic()
        shown = start
        rows = []
        try:
            while args.duration is None or time.monotonic() - start < args.duration:
                frame = bus.recv(timeout=0.05)
                if frame is not None:
                    heard.append((time.monotonic_ns(), "rx", frame.arbitration_id, bytes(frame.data)))
                if time.monotonic() - shown >= args.every:
                    shown = time.monotonic()
                    rows = summarise_traffic(heard, protocol)
                    print(f"--- {shown - start:6.1f} s on {config.interface} {config.channel} ({protocol})")
                    print(format_traffic(rows), flush=True)
        except KeyboardInterrupt:
            pass
        finally:
            bus.shutdown()
        rows = summarise_traffic(heard, protocol)
        print(f"--- {len(heard)} frames in {time.monotonic() - start:.1f} s on {config.interface} {config.channel}")
        print(format_traffic(rows))
    if out is not None:
        write_json_atomic(out, _rows_json(rows))
    return 0

"""``kartpilot lidar monitor``: a planar LiDAR's sweeps, live from the device or from a recording."""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict
from pathlib import Path

from kartpilot.core.errors import RecordingError
from kartpilot.core.files import write_json_atomic
from kartpilot.core.types import LaserScan
from kartpilot.record.recording import RecordingReader
from kartpilot.sensors.health import summarise_sweeps
from kartpilot.sensors.lidar import RplidarConfig, RplidarScanner

__all__ = ["lidar_monitor"]


def lidar_monitor(args: argparse.Namespace) -> int:
    """The device's information and health, then a line per ``--every`` seconds: the sweeps' rate, gaps,
    returns and problems (or one line per LiDAR of a recording). Exits non-zero when the device ended in an
    error."""
    if args.recording:
        reader = RecordingReader(args.recording)
        if not reader.lidars:
            raise RecordingError(f"{args.recording} holds no LiDAR")
        summaries = {name: summarise_sweeps(reader.scans(name)) for name in reader.lidars}
        for name, summary in summaries.items():
            print(f"{name}: {summary.line()}")
        if args.json:
            write_json_atomic(Path(args.json), {name: asdict(s) for name, s in summaries.items()})
        return 0
    config = RplidarConfig(port=args.port, baudrate=args.baudrate)
    with RplidarScanner(config).start() as scanner:
        status, code = scanner.health
        print(f"{args.port}: model {scanner.info.get('model')}, firmware {scanner.info.get('firmware')}, hardware "
              f"{scanner.info.get('hardware')}, serial {scanner.info.get('serialnumber')}; health {status} "
              f"(code {code:#06x})", flush=True)
        start = shown = time.monotonic()
        window: list[LaserScan] = []
        summary = summarise_sweeps([])
        try:
            while (args.duration is None or time.monotonic() - start < args.duration) and scanner.error is None:
                time.sleep(0.02)
                window += scanner.take()
                if time.monotonic() - shown >= args.every:
                    shown = time.monotonic()
                    summary = summarise_sweeps(window)
                    print(summary.line(), flush=True)
                    window = window[-1:]  # the last sweep stays, for the next line's gaps and frozen check
        except KeyboardInterrupt:
            pass
        if args.json:
            write_json_atomic(Path(args.json), {"lidar": asdict(summary), "error": scanner.error})
        if scanner.error:
            print(f"kartpilot: error: {scanner.error}", file=sys.stderr)
            return 1
    return 0

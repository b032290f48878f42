"""``kartpilot recordings``: what a recording holds."""

from __future__ import annotations

import argparse
import json

from kartpilot.record.info import recording_info
from kartpilot.record.recording import RecordingReader

__all__ = ["recordings_info"]


def recordings_info(args: argparse.Namespace) -> int:
    info = recording_info(RecordingReader(args.recording))
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    state = "closed properly" if info["closed"] else "NOT closed properly (cut off; everything flushed is kept)"
    print(f"{info['folder']}: {info['duration_s']:.2f} s, {state}")
    for name, camera in info["cameras"].items():
        skew = next((f", skew to {k[8:-3]} {v['median']:.2f} ms median / {v['max']:.2f} ms max"
                     for k, v in camera.items() if k.startswith("skew_to_")), "")
        print(f"  camera {name}: {camera['frames']} frames at {camera['rate_hz']} Hz, "
              f"{camera['dropped']} dropped{skew}")
    commands = info["commands"]
    if commands["count"]:
        steer = commands["steer_rad"]
        print(f"  commands: {commands['count']} at {commands['rate_hz']} Hz, steer {steer['min']:+.3f} to "
              f"{steer['max']:+.3f} rad (mean {steer['mean']:+.3f}), throttle mean {commands['throttle_mean']:.2f}, "
              f"braking {100 * commands['braking_fraction']:.0f} % of the time")
    else:
        print("  commands: none")
    if info["outputs"]:
        print("  pipeline outputs: " + ", ".join(f"{topic} ({rows} rows)" for topic, rows in info["outputs"].items()))
    if info["can_frames"]:
        print(f"  CAN frames: {info['can_frames']}")
    if info["dropped_lines"]:
        print(f"  lines dropped from the recording (queue full): {info['dropped_lines']}")
    print(f"  ground truth: {'yes' if info['has_groundtruth'] else 'no'}; stereo pair: {info['stereo_pair']}")
    return 0

"""Put the measured lane-following results into docs/lanes.md: race pace in the simulator, speed and latency,
and taped tracks on real footage.

    python benchmarks/lane_docs.py   # from docs/results/{lane_ablation,lane_race,lanes,tape_tracks}.json

Each section replaces what lies between its ``<!-- name -->`` and ``<!-- /name -->`` markers, so the page's
numbers are the measured ones (tests/test_docs_numbers.py checks).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
PAGE = ROOT / "docs" / "lanes.md"


def _load(name: str) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((RESULTS / f"{name}.json").read_text(encoding="utf-8"))
    return data


def race(results: dict[str, Any]) -> str:
    drives = results["drives"]
    reference = next(d for d in drives if d["speed_mode_kmh"] == 15 and d["follow"] == "defaults"
                     and not d["speed_loop"])
    lines = [f"One lap of {results['track']}, the {results['vehicle']} on its three cameras at "
             f"{results['camera_rate_hz']:g} Hz (`benchmarks/lane_race.py`). Seed 1 is the one the split rule "
             "and the 60 km/h settings were developed on, seeds 1 and 2 the ones the side cameras' blend was "
             "checked on; seeds 3 to 5 (tyre marks, textures and noise drawn anew) are held out. "
             "*Throttle*: open loop (a fraction of the mode's top speed, as the thesis drove), "
             "or the speed held on the kart's measured speed (`lane_policy.speed_mps`, braking too).", "",
             "| speed mode | seed | follower | throttle | verdict | driven | lap | vs 15 km/h | max off centre |",
             "|---:|---:|---|---|---|---:|---:|---:|---:|"]
    for d in drives:
        verdict = f"DQ: {d['reason']}" if d["touched"] else d["reason"]
        lap = f"{d['lap_time_s']:.1f} s" if d["lap_time_s"] is not None else "-"
        gain = (f"{100 * (1 - d['lap_time_s'] / reference['lap_time_s']):.0f} % faster"
                if d["lap_time_s"] is not None and reference["lap_time_s"] else "-")
        throttle = "speed held" if d["speed_loop"] else "open loop"
        lines.append(f"| {d['speed_mode_kmh']:g} km/h | {d['seed']}{' (held out)' if d['held_out'] else ''} | "
                     f"{d['follow']} | {throttle} | {verdict} | {d['distance_m']:.0f} m | {lap} | {gain} | "
                     f"{d['max_center_offset_m']:.2f} m |")
    return "\n".join(lines) + "\n"


def speed(results: dict[str, Any]) -> str:
    latency = results["camera_to_command_ms"]
    total = results["camera_to_command_total_ms"]
    lines = [f"On one core of this machine (OpenCV on one thread, `benchmarks/lanes.py`), at "
             f"{results['image_size'][0]}x{results['image_size'][1]}: the centre camera and the follower run at "
             f"**{results['centre_fps']:.0f} frames/s** (target 300; {results['centre_source']}), all three "
             f"cameras with the fusion at {results['three_cameras_fps']:.0f} frames/s.", "",
             "Camera to command, one centre-camera frame, stage by stage:", "",
             "| stage | ms |", "|---|---:|"]
    lines += [f"| {name} | {ms:.2f} |" for name, ms in latency.items()]
    lines += [f"| **total** | **{total:.2f}** |", "",
              f"That is {total / 1000 * 30 / 3.6 * 100:.1f} cm at 30 km/h and {total / 1000 * 60 / 3.6 * 100:.1f} cm "
              f"at 60 km/h, {100 * total / (1000 / 30):.0f} % of a 30 Hz frame period. The frame period itself "
              "(33 ms, 28 cm at 30 km/h) and the camera's exposure and USB transfer, not measured here, are the "
              "larger part of the delay. The taped-track pipeline takes "
              f"{results['tape_ms']['160x120_ms']:.2f} ms per 160x120 frame and "
              f"{results['tape_ms']['960x540_ms']:.2f} ms at 960x540."]
    return "\n".join(lines) + "\n"


def tape(results: dict[str, Any]) -> str:
    lines = ["`kartpilot lanes TUB --preset tape` against the human's `user/angle` smoothed over 0.5 s "
             "(`benchmarks/tape_tracks.py`): Pearson's r over every frame, and the share of frames where both "
             "steer to the same side among those where the smoothed human steer is beyond 0.3.", "",
             "| tub | frames | settings | held out | correlation | sign agreement | turning frames |",
             "|---|---|---|---|---:|---:|---:|"]
    for row in results["rows"]:
        held = {True: "yes", False: "no (chosen here)", None: "half"}[row["held_out"]]
        lines.append(f"| {row['tub']} | {row['part']} | {row['config']} | {held} | {row['correlation']:.3f} | "
                     f"{100 * row['sign_agreement']:.1f} % | {row['turning_frames']} |")
    lines += ["", "What a wrong measurement costs on piracer-tape-track (all frames), one input moved at a time:", "",
              "| input | default | moved to | correlation | sign agreement |", "|---|---:|---:|---:|---:|"]
    for row in results["sensitivity"]:
        lines.append(f"| `{row['key']}` | {results['defaults'][row['key']]:g} | {row['value']:.3g} | "
                     f"{row['correlation']:.3f} | {100 * row['sign_agreement']:.1f} % |")
    lines += ["", f"{results['ms_per_frame_160x120']:.2f} ms per 160x120 frame on one core."]
    return "\n".join(lines) + "\n"


def ablation(results: dict[str, Any]) -> str:
    lines = [f"Closed loop on `{results['track']}` ({results['vehicle']}, {results['mode_kmh']:g} km/h mode, "
             f"{results['rate_hz']:g} Hz, {results['seconds']:g} s, seed 1, `benchmarks/lane_ablation.py`), the "
             "thesis's rules against kartpilot's:", "",
             "| rules | referee | mean / max distance from the centre | steer rate RMS |", "|---|---|---|---|"]
    for name, row in results["rows"].items():
        verdict = f"DQ: {row['reason']}" if row["touched"] else "no DQ"
        lines.append(f"| {results['labels'][name]} | {verdict}, {row['distance_m']:.0f} m | "
                     f"{row['mean_center_offset_m']:.2f} / {row['max_center_offset_m']:.2f} m | "
                     f"{row['steer_rate_rms_radps']:.2f} rad/s |")
    thesis, ours = results["rows"]["thesis rules"], results["rows"]["kartpilot"]
    lines += ["", f"kartpilot's steer rate is {thesis['steer_rate_rms_radps'] / ours['steer_rate_rms_radps']:.1f} "
                  f"times lower (less oscillation) and its mean distance from the centre "
                  f"{100 * (1 - ours['mean_center_offset_m'] / thesis['mean_center_offset_m']):.0f} % smaller."]
    return "\n".join(lines) + "\n"


SECTIONS = {"lane-ablation": ("lane_ablation", ablation), "lane-race": ("lane_race", race),
            "lane-speed": ("lanes", speed), "tape-tracks": ("tape_tracks", tape)}


def main() -> int:
    for marker, (name, render) in SECTIONS.items():
        put_at_marker(PAGE, render(_load(name)), marker)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

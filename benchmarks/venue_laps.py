"""Closed-loop laps of the venue track (``lelystad``) on the real kart's camera model, with the real kart's preset.

Each drive is one lap of the sdc-kart (its centre camera modelled on the real one: 848x480, 0.56 m up, 6.8 deg
down) at a speed mode, through the supervisor and the simulated CAN bus, with the speed held on the kart's
measured speed (its 0x440 report, as on the real kart), and the ``kart`` lane preset: the same settings
``kartpilot lanes --preset kart`` uses on the real frames. Seed 1 is the seed the preset's follower gain and
the side cameras' reach were chosen on; seeds 2 to 5 (textures, tyre marks and camera noise drawn anew) are
held out. Drives run in separate processes, two at a time.

    python benchmarks/venue_laps.py --out docs/results/venue_laps.json
    python benchmarks/venue_laps.py --render docs/results/venue_laps.json   # into docs/real-kart.md
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from common import write_json
from kartpilot.runtime.config import load_stack_config
from kartpilot.runtime.simulate import run_supervised_drive
from kartpilot.sim.referee import RefereeConfig
from kartpilot.sim.render import RenderConfig
from kartpilot.sim.simulator import SimConfig
from vo_table import put_at_marker

TRACK = "lelystad"
DEVELOPMENT_SEEDS = (1,)
DRIVES = [(15.0, seed) for seed in (1, 2, 3, 4, 5)] + [(30.0, seed) for seed in (1, 2, 3, 4, 5)]


def one_lap(drive: tuple[float, int] | tuple[float, int, RenderConfig]) -> dict[str, Any]:
    """One lap at a speed mode on a seed (and under a sky: ``benchmarks/sunny_venue.py``)."""
    mode_kmh, seed = drive[0], drive[1]
    render = drive[2] if len(drive) > 2 else RenderConfig()
    stack = load_stack_config(None, "kart")
    stack = replace(stack, lane_policy=replace(stack.lane_policy, speed_mps=mode_kmh / 3.6))
    config = SimConfig(track=TRACK, vehicle="sdc-kart", seed=seed, camera_rate_hz=30.0, render=render,
                       speed_mode_mps=mode_kmh / 3.6, referee=RefereeConfig(laps=1), max_time_s=200.0)
    start = time.perf_counter()
    result = run_supervised_drive(config, "lanes", stack, "virtual").result
    return {"speed_mode_kmh": mode_kmh, "seed": seed, "held_out": seed not in DEVELOPMENT_SEEDS,
            "touched": result.disqualified, "reason": result.reason, "finished": result.finished,
            "distance_m": result.distance_m, "lap_time_s": result.lap_time_s,
            "mean_center_offset_m": result.mean_center_offset_m, "max_center_offset_m": result.max_center_offset_m,
            "wall_s": round(time.perf_counter() - start, 1)}


PAGE = Path(__file__).resolve().parents[1] / "docs" / "real-kart.md"


def render(results: dict[str, Any]) -> str:
    lines = [f"Measured by `benchmarks/venue_laps.py`: one lap of `{results['track']}` each, the `{results['preset']}` "
             f"preset, {results['camera_rate_hz']:g} Hz, speed {results['speed']}. Seed 1 is development; the "
             "others are held out.", "",
             "| speed mode | seed | verdict | metres | lap time | mean / max offset from the centre |",
             "|---|---|---|---|---|---|"]
    for row in results["drives"]:
        verdict = f"disqualified: {row['reason']}" if row["touched"] else str(row["reason"])
        seed = f"{row['seed']}" + (" (held out)" if row["held_out"] else " (development)")
        lap = f"{row['lap_time_s']:.1f} s" if row["lap_time_s"] is not None else "–"
        lines.append(f"| {row['speed_mode_kmh']:g} km/h | {seed} | {verdict} | {row['distance_m']:.1f} | {lap} | "
                     f"{row['mean_center_offset_m']:.2f} / {row['max_center_offset_m']:.2f} m |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="docs/results/venue_laps.json")
    parser.add_argument("--render", type=Path, help="write this JSON's table into docs/real-kart.md")
    args = parser.parse_args()
    if args.render:
        put_at_marker(PAGE, render(json.loads(args.render.read_text())), "venue-laps")
        return 0
    with multiprocessing.get_context("spawn").Pool(args.workers, maxtasksperchild=1) as pool:
        rows = pool.map(one_lap, DRIVES, chunksize=1)
    for row in rows:
        verdict = f"DQ: {row['reason']}" if row["touched"] else str(row["reason"])
        print(f"{row['speed_mode_kmh']:>4g} km/h seed {row['seed']}: {verdict}, {row['distance_m']:.1f} m, "
              f"max offset {row['max_center_offset_m']:.2f} m")
    write_json(args.out, {"track": TRACK, "vehicle": "sdc-kart", "preset": "kart", "camera_rate_hz": 30.0,
                          "speed": "held on the measured speed (CAN 0x440), simulated bus", "drives": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

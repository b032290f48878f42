"""Laps of the venue in the sun: hard shadows of roadside trees, poles, buildings and barriers across the lane, the
lane pipeline on the real kart's preset, at 15 and 30 km/h (issue 54's sunny venue), against the same laps under
the venue's overcast sky. Each lap is judged by the track's referee (a line touched disqualifies).

    python benchmarks/sunny_venue.py --out docs/results/sunny_venue.json
    python benchmarks/sunny_venue.py --render docs/results/sunny_venue.json   # into docs/scenarios.md
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
from pathlib import Path
from typing import Any

from common import write_json
from kartpilot.runtime.config import load_stack_config, sim_lane_preset
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.render import RenderConfig
from kartpilot.sim.simulator import SimConfig
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "scenarios.md"

SKIES = {
    "overcast (the venue's frames)": RenderConfig(),
    "sun from the south-east, 9 h (low: long shadows)": RenderConfig(sky="clear", time_of_day_h=9.0,
                                                                      sun_azimuth_deg=135.0, trees_spacing_m=10.0,
                                                                      shadows=True),
    "sun from the west, 16 h": RenderConfig(sky="clear", time_of_day_h=16.0, sun_azimuth_deg=250.0,
                                             trees_spacing_m=10.0, shadows=True),
}


def lap(render: RenderConfig, speed_kmh: float, seed: int) -> dict[str, Any]:
    """One lap of lelystad with the lanes pipeline at a speed mode."""
    stack = load_stack_config(None, sim_lane_preset(None, "lelystad"))
    config = SimConfig(track="lelystad", vehicle="sdc-kart", seed=seed, speed_mode_mps=speed_kmh / 3.6,
                       camera_rate_hz=15.0, render=render)
    result = run_simulation(config, "lanes", stack=stack).result
    return {"speed_kmh": speed_kmh, "seed": seed, "disqualified": result.disqualified, "reason": result.reason,
            "distance_m": result.distance_m, "mean_center_offset_m": result.mean_center_offset_m,
            "max_center_offset_m": result.max_center_offset_m}


def render_table(results: dict[str, Any]) -> str:
    lines = ["| sky | speed mode | seed | verdict | metres | centre offset mean / max m |",
             "|---|---:|---:|---|---:|---:|"]
    for row in results["rows"]:
        verdict = f"**disqualified**: {row['reason']}" if row["disqualified"] else row["reason"]
        lines.append(f"| {row['sky']} | {row['speed_kmh']:g} km/h | {row['seed']} | {verdict} | "
                     f"{row['distance_m']:.0f} | {row['mean_center_offset_m']:.2f} / "
                     f"{row['max_center_offset_m']:.2f} |")
    return "\n".join(lines) + f"\n\n*{results['date']}, `benchmarks/sunny_venue.py`*\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/results/sunny_venue.json")
    parser.add_argument("--seeds", type=int, nargs="+", default=[11])
    parser.add_argument("--render", help="put the table of this JSON into docs/scenarios.md")
    args = parser.parse_args()
    if args.render:
        put_at_marker(PAGE, render_table(json.loads(Path(args.render).read_text(encoding="utf-8"))), "sunny-venue")
        return 0
    rows = []
    for sky, render in SKIES.items():
        for speed in (15.0, 30.0):
            for seed in args.seeds:
                row = {"sky": sky, **lap(render, speed, seed)}
                print(row)
                rows.append(row)
    write_json(args.out, {"date": datetime.date.today().isoformat(),
                          "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                      "processor": platform.processor() or platform.machine()},
                          "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

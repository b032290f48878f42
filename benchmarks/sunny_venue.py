"""Laps of the venue in the sun (issue 54): hard shadows of roadside trees, poles, buildings and barriers across
the lane, the lane pipeline on the real kart's preset at 15 and 30 km/h, each lap as ``benchmarks/venue_laps.py``
drives it under the venue's overcast sky (through the supervisor and the simulated CAN bus, 30 Hz, the speed held
on the kart's measured speed), judged by the track's referee (a line touched disqualifies). Two suns: low from the
south-east in the morning, from the west in the afternoon; seeds 11 and 12 (held out: nothing was tuned in the sun).

    python benchmarks/sunny_venue.py --out docs/results/sunny_venue.json
    python benchmarks/sunny_venue.py --render docs/results/sunny_venue.json   # into docs/scenarios.md
"""

from __future__ import annotations

import argparse
import datetime
import json
import multiprocessing
import os
import platform
from pathlib import Path
from typing import Any

from common import write_json
from kartpilot.sim.render import RenderConfig
from venue_laps import one_lap
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "scenarios.md"

SKIES = {
    "sun from the south-east, 9 h (low: long shadows)": RenderConfig(
        sky="clear", time_of_day_h=9.0, sun_azimuth_deg=135.0, trees_spacing_m=10.0, shadows=True),
    "sun from the west, 16 h": RenderConfig(sky="clear", time_of_day_h=16.0, sun_azimuth_deg=250.0,
                                             trees_spacing_m=10.0, shadows=True),
}
SEEDS = (11, 12)


def render_table(results: dict[str, Any]) -> str:
    lines = ["| sky | speed mode | seed | verdict | metres | centre offset mean / max m |",
             "|---|---:|---:|---|---:|---:|"]
    for row in results["rows"]:
        verdict = f"**disqualified**: {row['reason']}" if row["touched"] else row["reason"]
        lines.append(f"| {row['sky']} | {row['speed_mode_kmh']:g} km/h | {row['seed']} | {verdict} | "
                     f"{row['distance_m']:.0f} | {row['mean_center_offset_m']:.2f} / "
                     f"{row['max_center_offset_m']:.2f} |")
    return "\n".join(lines) + f"\n\n*{results['date']}, `benchmarks/sunny_venue.py`*\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/results/sunny_venue.json")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--render", help="put the table of this JSON into docs/scenarios.md")
    args = parser.parse_args()
    if args.render:
        put_at_marker(PAGE, render_table(json.loads(Path(args.render).read_text(encoding="utf-8"))), "sunny-venue")
        return 0
    drives = [(speed, seed, render) for render in SKIES.values() for speed in (15.0, 30.0) for seed in SEEDS]
    with multiprocessing.get_context("spawn").Pool(args.workers, maxtasksperchild=1) as pool:
        laps = pool.map(one_lap, drives, chunksize=1)
    rows = [{"sky": sky, **lap} for (sky, _), lap in zip(((sky, r) for sky, r in SKIES.items()
                                                         for _ in range(2 * len(SEEDS))), laps, strict=True)]
    for row in rows:
        print(row)
    write_json(args.out, {"date": datetime.date.today().isoformat(),
                          "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                      "processor": platform.processor() or platform.machine()},
                          "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

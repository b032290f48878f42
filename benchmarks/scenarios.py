"""The event's scenarios, closed loop on the venue track, on a development seed and five held-out ones.

Each drive is one scenario (``kartpilot sim --scenario NAME --seed N``): the lane pipeline with the event's rules
on the sdc-kart's rendered cameras at 15 Hz, scored by the scenario's referee. Seed 1 is the one the rules were
developed on; seeds 2 to 6 (the props' places, the light's timing, the pedestrian's walk, textures and noise) are
held out. Drives run in separate processes, two at a time.

    python benchmarks/scenarios.py --out docs/results/scenarios.json
    python benchmarks/scenarios.py --render docs/results/scenarios.json   # into docs/scenarios.md
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import time
from pathlib import Path
from typing import Any

from common import write_json
from kartpilot.runtime.scenarios import run_scenario
from kartpilot.sim.scenarios import SCENARIOS
from vo_table import put_between_markers

PAGE = Path(__file__).resolve().parents[1] / "docs" / "scenarios.md"
DEVELOPMENT_SEEDS = (1,)
SEEDS = (1, 2, 3, 4, 5, 6)


def one(drive: tuple[str, int]) -> dict[str, Any]:
    name, seed = drive
    start = time.perf_counter()
    result = run_scenario(name, seed)
    return {**result, "held_out": seed not in DEVELOPMENT_SEEDS, "wall_s": round(time.perf_counter() - start, 1)}


def render(results: dict[str, Any]) -> str:
    seeds = sorted({r["seed"] for r in results["drives"]})
    lines = ["Measured by `benchmarks/scenarios.py` (15 km/h mode, 15 Hz; seed 1 development, the others held out). "
             "A cell is the referee's verdict; a fault is written out.", "",
             "| scenario | " + " | ".join(f"seed {s}" for s in seeds) + " |", "|---|" + "---|" * len(seeds)]
    for name in SCENARIOS:
        cells = []
        for seed in seeds:
            row = next(r for r in results["drives"] if r["name"] == name and r["seed"] == seed)
            cell = "passed" if row["passed"] else "; ".join(row["faults"])
            if "stopped_before_line_m" in row:
                cell += f" ({row['stopped_before_line_m']:.2f} m before the line)"
            cells.append(cell)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="docs/results/scenarios.json")
    parser.add_argument("--render", type=Path, help="write this JSON's table into docs/scenarios.md")
    args = parser.parse_args()
    if args.render:
        put_between_markers(PAGE, render(json.loads(args.render.read_text())), "<!-- scenarios -->",
                            "<!-- /scenarios -->")
        return 0
    drives = [(name, seed) for name in SCENARIOS for seed in SEEDS]
    with multiprocessing.get_context("spawn").Pool(args.workers, maxtasksperchild=1) as pool:
        rows = pool.map(one, drives, chunksize=1)
    for row in rows:
        print(f"{row['name']:>15} seed {row['seed']}: {'passed' if row['passed'] else '; '.join(row['faults'])}")
    write_json(args.out, {"speed_mode_kmh": 15.0, "camera_rate_hz": 15.0, "drives": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

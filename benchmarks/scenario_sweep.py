"""A pass rate, not a pass: N events of the six scenarios, each varied as the day may (the sun, shadows, the
camera's mount and exposure, the props' sides and values, the pedestrian's pace), on seeds no scenario was built
on, scored by the referee, on Ray (this machine's cores, or a cluster: ``--address HEAD:6379``). Every row is
cached by its cell's hash in ``--out``, so a sweep interrupted or extended computes only what is new.

    python benchmarks/scenario_sweep.py --events 60 --json docs/results/scenario_sweep.json
    python benchmarks/scenario_sweep.py --render docs/results/scenario_sweep.json   # into docs/scenarios.md
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
from pathlib import Path
from typing import Any

from common import camera_name, write_json
from kartpilot.core.config import config_to_dict
from kartpilot.core.files import read_json_file
from kartpilot.eval.scenarios import CAUSES, sweep_summary
from kartpilot.sim.simulator import CameraEffectsConfig
from kartpilot.sim.variation import DayRanges
from kartpilot.study.sweep import SINGLE_SCENARIOS, run_sweep, sweep_cells
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "scenarios.md"


def render(results: dict[str, Any]) -> str:
    lines = ["| scenario | events | passed | pass rate (95 % interval) | " + " | ".join(CAUSES) + " |",
             "|---|---:|---:|---|" + "---:|" * len(CAUSES)]
    for name, row in results["summary"]["scenarios"].items():
        low, high = row["interval"]
        lines.append(f"| {name} | {row['events']} | {row['passed']} | {100 * row['pass_rate']:.0f} % "
                     f"({100 * low:.0f} to {100 * high:.0f} %) | "
                     + " | ".join(str(row["causes"].get(cause, 0)) for cause in CAUSES) + " |")
    failures = results["summary"]["failures"]
    lines.append("")
    lines.append(f"*{results['events']} events on seeds {results['first_seed']} to "
                 f"{results['first_seed'] + results['events'] - 1}, {results['date']}; "
                 f"{results['wall_s'] / 60:.0f} min "
                 f"on {results['cpus']:g} cores ({results['per_event_s']:.0f} s of a core per event); "
                 f"through the {camera_name(results)} camera; `benchmarks/scenario_sweep.py`*")
    pitch = results["summary"].get("pitch", {"events": 0})
    if pitch["events"]:
        lines += ["", f"The camera's pitch measured from the lanes while driving (`kartpilot.perception.horizon`), "
                  f"over the {pitch['events']} events: the mount was off by {pitch['median_off_deg']:.2f} deg at the "
                  f"median, {pitch['max_off_deg']:.2f} at most. It was measured in "
                  f"{100 * pitch['measured_share']:.0f} % of the events, and there left "
                  f"{pitch['measured_median_error_deg']:.2f} deg at the median, "
                  f"{pitch['measured_max_error_deg']:.2f} at most; the others kept the rig's mount (over all events: "
                  f"{pitch['median_error_deg']:.2f} at the median, {pitch['max_error_deg']:.2f} at most)."]
    if failures:
        lines += ["", "| failed event | fault | cause |", "|---|---|---|"]
        for failure in failures:
            for item in failure["faults"]:
                lines.append(f"| {failure['scenario']} seed {failure['seed']} | {item['fault']} | {item['cause']} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=60)
    parser.add_argument("--first-seed", type=int, default=10_000, help="never a seed the scenarios were built on")
    parser.add_argument("--out", default="benchmarks/results/sweep", help="the cells' cache and the failures' files")
    parser.add_argument("--json", default="docs/results/scenario_sweep.json")
    parser.add_argument("--address", help="a Ray cluster's head (default: this machine's cores)")
    parser.add_argument("--cpus", type=int, help="at most this many of this machine's cores")
    parser.add_argument("--render", help="put the tables of this JSON into docs/scenarios.md")
    parser.add_argument("--summarise", action="store_true",
                        help="the JSON's summary again from the rows kept in --out (after the summary's code changed)")
    args = parser.parse_args()
    if args.render:
        put_at_marker(PAGE, render(json.loads(Path(args.render).read_text(encoding="utf-8"))), "scenario-sweep")
        return 0
    if args.summarise:
        results = json.loads(Path(args.json).read_text(encoding="utf-8"))
        by_key = {row["config_hash"]: row for row in (read_json_file(path) for path in
                                                      sorted(Path(args.out, "cells").glob("*.json")))}
        cells = sweep_cells(results["events"], results["first_seed"], DayRanges(**results["variation"]))
        rows = [dict(by_key[cell.key], scenario=cell.params["scenario"]) for cell in cells]
        for row, cell in zip(rows, cells, strict=True):
            failure = Path(args.out, "failures", f"{row['scenario']}-{cell.seed}.yaml")
            if not row.get("passed", False) and failure.is_file():
                row["file"] = str(failure)
        results["summary"] = sweep_summary(rows, SINGLE_SCENARIOS)
        write_json(args.json, results)
        return 0
    ranges = DayRanges()
    run = run_sweep(args.out, args.events, args.first_seed, ranges, address=args.address, cpus=args.cpus,
                    progress=True)
    seconds = [row.get("cell_seconds", 0.0) for row in run.rows]
    write_json(args.json, {
        "date": datetime.date.today().isoformat(), "events": args.events, "first_seed": args.first_seed,
        "scenarios": list(SINGLE_SCENARIOS), "variation": config_to_dict(ranges), "computed": run.computed,
        "camera": config_to_dict(CameraEffectsConfig()),  # the defaults each event's camera is varied from
        "cached": run.cached, "wall_s": run.wall_s, "cpus": run.cpus,
        "per_event_s": sum(seconds) / max(len(seconds), 1),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "processor": platform.processor() or platform.machine()},
        "summary": run.summary})
    for name, row in run.summary["scenarios"].items():
        print(f"{name:16s} {row['passed']}/{row['events']}  causes {row['causes']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""How a study scales with Ray's workers: one built-in study at its quick size, from nothing (no cached rows,
no cached recordings), on 1 and then 2 local CPUs; the wall time, the speed-up and the cost per cell.

    python benchmarks/study_scaling.py --study features --out docs/results/study_scaling.json
    python benchmarks/study_scaling.py --render docs/results/study_scaling.json --into README.md docs/study/index.md
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import tempfile
from pathlib import Path
from typing import Any

from common import write_json
from kartpilot.study.run import run_study
from kartpilot.study.spec import load_spec
from vo_table import put_between_markers

START, END = "<!-- study-scaling -->", "<!-- /study-scaling -->"


def measure(study: str, data: Path, cpus: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as folder:
        run = run_study(load_spec(study), Path(folder) / "study", data, quick=True, cpus=cpus)
    busy = sum(float(r.get("cell_seconds", 0.0)) for r in {r["config_hash"]: r for r in run.rows}.values())
    result = {"cpus": cpus, "wall_s": run.wall_s, "cells": run.computed, "failed": run.failed,
              "cell_seconds": busy, "seconds_per_cell": busy / max(run.computed, 1)}
    print(f"{study} --quick on {cpus} CPU(s): {run.wall_s:.0f} s for {run.computed} cells, "
          f"{result['seconds_per_cell']:.1f} s of work per cell")
    return result


def render(results: dict[str, Any]) -> str:
    one, two = (next(r for r in results["runs"] if r["cpus"] == n) for n in (1, 2))
    machine = results["machine"]
    return (f"Measured on {results['date']} ({machine['cpus']} cores, {machine['processor']}): "
            f"`kartpilot study run {results['study']} --quick` ({one['cells']} cells, from nothing) takes "
            f"{one['wall_s']:.0f} s on one Ray worker and {two['wall_s']:.0f} s on two, a speed-up of "
            f"{one['wall_s'] / two['wall_s']:.2f}. A cell costs {one['seconds_per_cell']:.1f} s of one core alone "
            f"and {two['seconds_per_cell']:.1f} s when two run side by side on this machine (its share of a "
            "simulated recording included), which is what holds the speed-up below 2 here; cells are independent, "
            "so more machines add their cores.\n")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", default="features")
    parser.add_argument("--data", default="../shared/data", type=Path)
    parser.add_argument("--out", default="docs/results/study_scaling.json")
    parser.add_argument("--render", type=Path, help="render this JSON into --into instead of measuring")
    parser.add_argument("--into", nargs="*", type=Path, default=[])
    args = parser.parse_args()
    if args.render:
        text = render(json.loads(args.render.read_text(encoding="utf-8")))
        for page in args.into:
            put_between_markers(page, text, START, END)
        return 0
    runs = [measure(args.study, args.data, cpus) for cpus in (1, 2)]
    write_json(args.out, {"date": datetime.date.today().isoformat(), "study": args.study, "quick": True,
                          "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                                      "python": platform.python_version()},
                          "runs": runs, "speedup": runs[0]["wall_s"] / runs[1]["wall_s"]})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

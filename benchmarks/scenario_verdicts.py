"""Each event's verdict, in one process, for a change's before and after: the built-in scenarios named, on the seeds
given, varied as the sweep varies them (kartpilot.study.jobs.scenario_event), driven closed loop with the kart preset.
Where benchmarks/scenario_sweep.py gives a pass rate over all six scenarios on a cluster, this is for comparing two
commits on a few hundred events of the scenarios a change is about: run it in each commit's checkout and compare the
JSONs (the commit is recorded).

    python benchmarks/scenario_verdicts.py --scenarios parking,overtake --first-seed 30001 --events 10 --json FILE
"""

from __future__ import annotations

import argparse
import datetime
import json
import subprocess
from pathlib import Path

import cv2

from common import write_json
from kartpilot.runtime.config import load_stack_config
from kartpilot.runtime.scenarios import run_scenario
from kartpilot.sim.variation import DayRanges
from kartpilot.study.jobs import scenario_event


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenarios", default="parking,overtake")
    parser.add_argument("--first-seed", type=int, required=True, help="never a seed the change was tuned on")
    parser.add_argument("--events", type=int, default=10, help="seeds per scenario")
    parser.add_argument("--json", required=True)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    stack = load_stack_config(None, "kart")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).parent).stdout.strip()
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.events):
        for name in args.scenarios.split(","):
            result = run_scenario(scenario_event(name, seed, DayRanges()), None, stack)
            rows.append({"scenario": name, "seed": seed, "passed": bool(result["passed"]),
                         "faults": list(result["faults"])})
            print(json.dumps(rows[-1]), flush=True)
    write_json(args.json, {"date": datetime.date.today().isoformat(), "commit": commit, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

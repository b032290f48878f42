"""The event's manoeuvres followed on the SDC kart's model alone (kartpilot.sim.follow): the teach-and-repeat path
follower against the manoeuvre follower the lane policy uses, on parking's S into bays and on overtakes.

What it measures is the controller's share of a manoeuvre's error (true pose, the kart's steering lag and rate, a
frame of latency, 15 Hz). These plans are what the manoeuvre follower was chosen on (its gains from a grid on the
first three bays, 2026-12-02); the held-out judge is closed loop, the scenario sweep's parking and overtake events
through the camera (benchmarks/scenario_sweep.py), which this does not replace.

    python benchmarks/manoeuvre_follow.py [--json docs/results/manoeuvre_follow.json]
"""

from __future__ import annotations

import argparse
import datetime
import math
from typing import Any

from common import write_json
from kartpilot.behaviour.manoeuvres import ParkConfig, plan_overtake, plan_park
from kartpilot.control.path_follow import PathFollowConfig
from kartpilot.core.vehicle import get_vehicle
from kartpilot.runtime.lane_policy import MANOEUVRE_FOLLOW
from kartpilot.sim.follow import follow_on_model

BAYS = ((12.0, 6.9, -2.37), (11.0, 6.5, -2.30), (13.0, 7.4, 2.40), (12.0, 6.4, -2.25), (14.0, 7.0, -2.50),
        (10.0, 7.2, 2.30))
"""(bay start ahead, free length, lateral) in metres: the first three chose the gains, the rest were not looked at."""
CARS_M = (12.0, 15.0, 20.0)
"""Distances to the car ahead, metres."""
FOLLOWERS = {"teach-and-repeat (PathFollowConfig())": PathFollowConfig(),
             "manoeuvre (MANOEUVRE_FOLLOW)": MANOEUVRE_FOLLOW}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", default="docs/results/manoeuvre_follow.json")
    args = parser.parse_args()
    kart = get_vehicle("sdc-kart")
    rows: list[dict[str, Any]] = []
    for name, config in FOLLOWERS.items():
        for k, (start, free, lateral) in enumerate(BAYS):
            path = plan_park(start, free, lateral, ParkConfig())
            if path is None:
                continue
            drive = follow_on_model(path, config, kart, ParkConfig().speed_mps, 1 / 15)
            rows.append({"follower": name, "manoeuvre": "park", "tuned_on": k < 3, "bay_m": [start, free, lateral],
                         "max_offset_m": drive.max_offset_m, "end_offset_m": drive.end_offset_m,
                         "end_yaw_deg": math.degrees(drive.end_yaw_error_rad), "end_short_m": drive.end_short_m,
                         "finished": drive.finished})
        for car in CARS_M:
            path = plan_overtake(car)
            if path is None:
                continue
            drive = follow_on_model(path, config, kart, 4.0, 1 / 15)
            rows.append({"follower": name, "manoeuvre": "overtake", "tuned_on": False, "car_m": car,
                         "max_offset_m": drive.max_offset_m, "end_offset_m": drive.end_offset_m,
                         "end_yaw_deg": math.degrees(drive.end_yaw_error_rad), "finished": drive.finished})
    print(f"{'follower':40s} {'manoeuvre':9s} {'plan':>22s} {'max off m':>9s} {'end off m':>9s} {'end yaw deg':>11s}")
    for r in rows:
        plan = (f"bay {r['bay_m'][0]:.0f}+{r['bay_m'][1]:.1f} at {r['bay_m'][2]:+.2f}" if r["manoeuvre"] == "park"
                else f"car {r['car_m']:.0f} m") + (" (tuned)" if r["tuned_on"] else "")
        print(f"{r['follower']:40s} {r['manoeuvre']:9s} {plan:>22s} {r['max_offset_m']:9.3f} {r['end_offset_m']:+9.3f} "
              f"{r['end_yaw_deg']:+11.1f}")
    write_json(args.json, {"date": datetime.date.today().isoformat(), "vehicle": "sdc-kart", "rate_hz": 15.0,
                           "delay_steps": 1, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

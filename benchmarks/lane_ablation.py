"""Lane following, the thesis's rules against kartpilot's, closed loop in the simulator.

Drives the sdc-kart on sdc-assen with the lane-following policy twice: once with the thesis's
control rules (steer = heading deviation, no offset term, no smoothing, the extreme column for a
missing side, the right-steer when both side cameras fire) and once with kartpilot's defaults.
Prints the referee's verdict, the distance from the lane centre and how much the steer oscillates
(RMS of the steer's change per second), and writes JSON.

    python benchmarks/lane_ablation.py --seconds 60 --out docs/results/lane_ablation.json
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import Any

from common import write_json
from kartpilot.control.lane_follow import LaneFollowConfig
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.lane_policy import LanePolicyConfig
from kartpilot.sim.simulator import SimConfig
from kartpilot.study.jobs import lane_drive

RULES = {"thesis rules": "thesis (heading only, no smoothing, extreme column, right-steer wins, side camera "
                         "overrides)",
         "kartpilot": "kartpilot (offset term, smoothing, rate limit, lane width, nearer side, side camera blended)"}
THESIS = LaneFollowConfig(heading_gain=1.0, offset_gain=0.0, smoothing=0.0, max_steer_rate_radps=100.0,
                          missing_side="extreme", both_sides="left_first", side_rule="override")


def drive(follow: LaneFollowConfig, seconds: float, rate_hz: float, mode_kmh: float) -> dict[str, Any]:
    config = SimConfig(track="sdc-assen", vehicle="sdc-kart", speed_mode_mps=mode_kmh / 3.6,
                       camera_rate_hz=rate_hz, max_time_s=seconds)
    stack = replace(StackConfig(), lane_policy=replace(LanePolicyConfig(), follow=follow))
    return lane_drive(stack, config)  # the lanes study's job, in this process


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--rate", type=float, default=15.0)
    parser.add_argument("--mode", type=float, default=15.0, help="speed mode, km/h")
    parser.add_argument("--out", default="docs/results/lane_ablation.json")
    args = parser.parse_args()
    rows = {"thesis rules": drive(THESIS, args.seconds, args.rate, args.mode),
            "kartpilot": drive(LaneFollowConfig(), args.seconds, args.rate, args.mode)}
    print(f"sdc-assen, sdc-kart, {args.mode:g} km/h mode, {args.rate:g} Hz, up to {args.seconds:g} s")
    print(f"{'rules':<14}{'verdict':<44}{'metres':>8}{'mean off':>10}{'max off':>9}{'steer rate rms':>16}")
    for name, row in rows.items():
        verdict = f"DQ: {row['reason']}" if row["touched"] else str(row["reason"])
        print(f"{name:<14}{verdict:<44}{row['distance_m']:>8.1f}{row['mean_center_offset_m']:>10.2f}"
              f"{row['max_center_offset_m']:>9.2f}{row['steer_rate_rms_radps']:>16.3f}")
    write_json(args.out, {"track": "sdc-assen", "vehicle": "sdc-kart", "mode_kmh": args.mode, "rate_hz": args.rate,
                          "seconds": args.seconds, "labels": RULES, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

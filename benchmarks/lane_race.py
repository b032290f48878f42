"""Lane following at race pace: whole laps of sdc-assen at the SDC kart's speed modes, closed loop.

Each drive is one lap of the sdc-kart on its three rendered cameras at 30 Hz, with kartpilot's lane policy
(the defaults, and variants of the follower's throttle rule). The referee's verdict, the lap time and the centre
offsets go to JSON; the 15 km/h mode's lap is the reference the faster modes are compared with. Seed 1 is
the seed the split rule was developed on; the other seeds (tyre marks, textures and noise drawn anew) are
held out. Drives run in separate processes, two at a time by default.

    python benchmarks/lane_race.py --out docs/results/lane_race.json
"""

from __future__ import annotations

import argparse
import multiprocessing
import time
from dataclasses import replace
from typing import Any

from common import write_json
from kartpilot.runtime.config import StackConfig
from kartpilot.sim.referee import RefereeConfig
from kartpilot.sim.simulator import SimConfig
from kartpilot.study.jobs import lane_drive

# (speed mode km/h, seed, the follower's settings over the defaults)
DEFAULTS: dict[str, Any] = {}
STEER_RULE = {"speed_plan": "steer"}  # the thesis's two fixed throttles
UNSURE_SLOWER = {"full_confidence": 0.5}  # the speed plan also slows when the detection is unsure
DRIVES = [(15.0, 1, DEFAULTS), (30.0, 1, DEFAULTS), (30.0, 2, DEFAULTS), (30.0, 3, DEFAULTS), (60.0, 1, DEFAULTS),
          (15.0, 1, STEER_RULE), (30.0, 1, STEER_RULE), (30.0, 1, UNSURE_SLOWER)]


def one_lap(drive: tuple[float, int, dict[str, Any]]) -> dict[str, Any]:
    mode_kmh, seed, follow = drive
    stack = StackConfig()
    stack = replace(stack, lane_policy=replace(stack.lane_policy, follow=replace(stack.lane_policy.follow,
                                                                                  **follow)))
    config = SimConfig(track="sdc-assen", vehicle="sdc-kart", seed=seed, camera_rate_hz=30.0,
                       speed_mode_mps=mode_kmh / 3.6, referee=RefereeConfig(laps=1))
    start = time.perf_counter()
    row = lane_drive(stack, config)
    label = ", ".join(f"{k}: {v}" for k, v in follow.items()) or "defaults"
    return {"speed_mode_kmh": mode_kmh, "seed": seed, "follow": label, "held_out": seed != 1,
            "wall_s": time.perf_counter() - start, **row}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="docs/results/lane_race.json")
    args = parser.parse_args()
    with multiprocessing.get_context("spawn").Pool(args.workers, maxtasksperchild=1) as pool:
        rows = pool.map(one_lap, DRIVES, chunksize=1)
    print("sdc-assen, sdc-kart, three cameras at 30 Hz, one lap")
    print(f"{'mode':>6}{'seed':>6}  {'follower':<24}{'verdict':<46}{'metres':>8}{'lap s':>8}{'max off':>9}")
    for row in rows:
        verdict = f"DQ: {row['reason']}" if row["touched"] else str(row["reason"])
        lap = f"{row['lap_time_s']:.1f}" if row["lap_time_s"] is not None else "-"
        print(f"{row['speed_mode_kmh']:>6g}{row['seed']:>6}  {row['follow']:<24}{verdict:<46}"
              f"{row['distance_m']:>8.1f}{lap:>8}{row['max_center_offset_m']:>9.2f}")
    write_json(args.out, {"track": "sdc-assen", "vehicle": "sdc-kart", "camera_rate_hz": 30.0, "drives": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

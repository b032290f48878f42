"""Lane following at race pace: whole laps of sdc-assen at the SDC kart's speed modes, closed loop.

Each drive is one lap of the sdc-kart on its three rendered cameras at 30 Hz, with kartpilot's lane policy
(the defaults, and variants of the follower's throttle rule). The referee's verdict, the lap time and the
centre offsets go to JSON; the 15 km/h mode's lap is the reference the faster modes are compared with. Seed 1
is the seed the split rule and the 60 km/h settings were developed on, and seeds 1 and 2 the ones the side
cameras' blend was checked on; seeds 3 to 5 (tyre marks, textures and noise drawn anew) are held out.
Open-loop drives run the policy on the simulator directly; the speed-loop drives hold the speed on the kart's
measured speed, which comes from its CAN report, so they drive through the simulated bus (as ``kartpilot drive
--sim``). Drives run in separate processes, two at a time by default; ``--keep`` drives only what the output
does not hold yet.

    python benchmarks/lane_race.py --out docs/results/lane_race.json
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
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.simulate import run_supervised_drive
from kartpilot.sim.referee import RefereeConfig
from kartpilot.sim.simulator import SimConfig
from kartpilot.study.jobs import lane_drive

# (speed mode km/h, seed, the follower's settings over the defaults, lane_policy.speed_mps or 0 for open loop)
DEFAULTS: dict[str, Any] = {}
STEER_RULE = {"speed_plan": "steer"}  # the thesis's two fixed throttles
UNSURE_SLOWER = {"full_confidence": 0.5}  # the speed plan also slows when the detection is unsure
RACE_60 = {"throttle_turn": 0.4, "throttle_split": 0.4}  # chosen on seed 1 after 0.6 touched a line at 152 m
DEVELOPMENT_SEEDS = (1, 2)
Drive = tuple[float, int, dict[str, Any], float]
DRIVES: list[Drive] = [
    (15.0, 1, DEFAULTS, 0.0), (30.0, 1, DEFAULTS, 0.0), (30.0, 2, DEFAULTS, 0.0), (30.0, 3, DEFAULTS, 0.0),
    (30.0, 4, DEFAULTS, 0.0), (30.0, 5, DEFAULTS, 0.0),
    (60.0, 1, DEFAULTS, 0.0), (15.0, 1, STEER_RULE, 0.0), (30.0, 1, STEER_RULE, 0.0), (30.0, 1, UNSURE_SLOWER, 0.0),
    # the speed held on the kart's measured speed (its 0x440 report, through the simulated CAN bus), braking too
    (30.0, 1, DEFAULTS, 30 / 3.6), (30.0, 3, DEFAULTS, 30 / 3.6),
    (60.0, 1, DEFAULTS, 60 / 3.6), (60.0, 1, RACE_60, 60 / 3.6), (60.0, 2, RACE_60, 60 / 3.6),
    (60.0, 3, RACE_60, 60 / 3.6),
]


def key(drive: Drive) -> str:
    mode_kmh, seed, follow, speed_mps = drive
    label = ", ".join(f"{k}: {v}" for k, v in follow.items()) or "defaults"
    loop = f"speed held at {speed_mps:.2f} m/s x throttle" if speed_mps > 0 else "open-loop throttle"
    return f"{mode_kmh:g} km/h | seed {seed} | {label} | {loop}"


def one_lap(drive: Drive) -> dict[str, Any]:
    mode_kmh, seed, follow, speed_mps = drive
    stack = StackConfig()
    policy = replace(stack.lane_policy, speed_mps=speed_mps, follow=replace(stack.lane_policy.follow, **follow))
    stack = replace(stack, lane_policy=policy)
    config = SimConfig(track="sdc-assen", vehicle="sdc-kart", seed=seed, camera_rate_hz=30.0,
                       speed_mode_mps=mode_kmh / 3.6, referee=RefereeConfig(laps=1))
    start = time.perf_counter()
    if speed_mps > 0:  # the measured speed comes from the kart's CAN report: drive through the bus
        result = run_supervised_drive(replace(config, max_time_s=400.0), "lanes", stack, "virtual").result
        row = {"touched": result.disqualified, "reason": result.reason, "distance_m": result.distance_m,
               "sim_time_s": result.sim_time_s, "finished": result.finished, "lap_time_s": result.lap_time_s,
               "mean_center_offset_m": result.mean_center_offset_m,
               "max_center_offset_m": result.max_center_offset_m}
    else:
        row = lane_drive(stack, config)
    return {"key": key(drive), "speed_mode_kmh": mode_kmh, "seed": seed,
            "follow": ", ".join(f"{k}: {v}" for k, v in follow.items()) or "defaults",
            "speed_loop": speed_mps > 0, "held_out": seed not in DEVELOPMENT_SEEDS,
            "wall_s": time.perf_counter() - start, **row}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="docs/results/lane_race.json")
    parser.add_argument("--keep", action="store_true", help="keep the drives the output already holds (same "
                                                            "settings) and drive only the others")
    args = parser.parse_args()
    out = Path(args.out)
    done = {row["key"]: row for row in json.loads(out.read_text(encoding="utf-8"))["drives"]} if (
        args.keep and out.is_file()) else {}
    todo = [drive for drive in DRIVES if key(drive) not in done]
    with multiprocessing.get_context("spawn").Pool(args.workers, maxtasksperchild=1) as pool:
        fresh = {row["key"]: row for row in pool.map(one_lap, todo, chunksize=1)}
    rows = [done.get(key(drive)) or fresh[key(drive)] for drive in DRIVES]
    print("sdc-assen, sdc-kart, three cameras at 30 Hz, one lap")
    print(f"{'mode':>6}{'seed':>6}  {'follower':<24}{'verdict':<46}{'metres':>8}{'lap s':>8}{'max off':>9}")
    for row in rows:
        verdict = f"DQ: {row['reason']}" if row["touched"] else str(row["reason"])
        lap = f"{row['lap_time_s']:.1f}" if row["lap_time_s"] is not None else "-"
        follower = row["follow"] + (", speed loop" if row["speed_loop"] else "")
        print(f"{row['speed_mode_kmh']:>6g}{row['seed']:>6}  {follower:<24}{verdict:<46}"
              f"{row['distance_m']:>8.1f}{lap:>8}{row['max_center_offset_m']:>9.2f}")
    write_json(args.out, {"track": "sdc-assen", "vehicle": "sdc-kart", "camera_rate_hz": 30.0, "drives": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Simulator speed: stereo pairs rendered per second, and the real-time factor of closed-loop runs.

For each bundled track, the rc-kart's stereo pair (960x540) is rendered along the route's centre
line (render + read-back into NumPy, then with the sensor effects), and a closed-loop run is timed:
with the stereo pair rendered, and physics and referee only. Prints a table and writes JSON.

    python benchmarks/sim_render.py --out benchmarks/results/sim_render.json
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from typing import Any

from common import write_json
from kartpilot.core.vehicle import get_vehicle
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.render import Renderer
from kartpilot.sim.simulator import SimConfig, Simulator, camera_poses_on_route
from kartpilot.sim.track import bundled_tracks, load_track


def render_rate(track_name: str, pairs: int) -> dict[str, float]:
    track = load_track(track_name)
    vehicle = get_vehicle("rc-kart")
    cams = {name: vehicle.camera(name) for name in ("left", "right")}
    # one pose per 5 cm route sample, as at 1.5 m/s and 30 Hz
    poses = [camera_poses_on_route(track, cams, k) for k in range(pairs)]
    build_start = time.perf_counter()
    with Renderer(track, cams) as renderer:
        build_s = time.perf_counter() - build_start
        renderer.render(poses[0])
        start = time.perf_counter()
        for pose in poses:
            renderer.render(pose)
        raw = pairs / (time.perf_counter() - start)
    config = SimConfig(track=track_name, vehicle="rc-kart", cameras=("left", "right"))
    with Simulator(config) as sim:
        sim.read()
        start = time.perf_counter()
        for _ in range(pairs):
            sim.read()
        with_effects = pairs / (time.perf_counter() - start)
    return {"scene_build_s": build_s, "pairs_per_s_render": raw, "pairs_per_s_with_sensor_effects": with_effects}


def closed_loop(track_name: str, render: bool, max_time_s: float) -> dict[str, Any]:
    config = SimConfig(track=track_name, vehicle="rc-kart", cameras=("left", "right"), render_images=render,
                       max_time_s=max_time_s)
    run = run_simulation(config, driver_config=CenterlineDriverConfig(speed_mps=1.5))
    result = run.result
    return {"sim_time_s": result.sim_time_s, "wall_time_s": result.wall_time_s,
            "real_time_factor": result.sim_time_s / result.wall_time_s, "steps": run.steps,
            "stage_ms": run.stage_ms}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=120)
    parser.add_argument("--loop-seconds", type=float, default=10.0, help="simulated seconds of the rendered loop")
    parser.add_argument("--out", default="benchmarks/results/sim_render.json")
    args = parser.parse_args()
    rows: dict[str, dict[str, Any]] = {}
    for name in bundled_tracks():
        rows[name] = {
            **render_rate(name, args.pairs),
            "closed_loop_rendered": closed_loop(name, True, args.loop_seconds),
            "closed_loop_physics_only": closed_loop(name, False, 0.0),
        }
    print(f"rc-kart stereo pair, 960x540, {args.pairs} pairs per track, 30 Hz camera/control rate")
    print(f"{'track':<12}{'pairs/s':>10}{'+effects':>10}{'RTF rendered':>14}{'RTF physics':>13}")
    for name, row in rows.items():
        print(f"{name:<12}{row['pairs_per_s_render']:>10.1f}{row['pairs_per_s_with_sensor_effects']:>10.1f}"
              f"{row['closed_loop_rendered']['real_time_factor']:>14.2f}"
              f"{row['closed_loop_physics_only']['real_time_factor']:>13.1f}")
    result = {"tracks": rows, "pairs_min": float(min(r["pairs_per_s_render"] for r in rows.values())),
              "machine": {"cpus": os.cpu_count(), "python": platform.python_version()}}
    print(f"slowest track: {result['pairs_min']:.1f} stereo pairs/s (target: at least 25)")
    print("RTF: simulated seconds per wall-clock second (above 1: faster than real time)")
    write_json(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

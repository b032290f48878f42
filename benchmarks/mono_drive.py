"""One camera around sdc-assen, closed loop: monocular VO plus place fixes following a taught lap.

The SDC kart's centre camera alone (10 Hz, roadside buildings on). A lap driven on the centre line at
5 m/s is the teaching drive: it gives the reference path and the place database (positions from the
simulator's truth, as a survey would). Then the ``mono-vo`` pipeline drives the lap through the
supervisor and the virtual CAN bus with the speed PI at 5 m/s, once at noon and once at dusk (another
light than the database's). Prints, per run, how far the kart got and how close to the centre line it stayed,
the localiser's error against the truth (across the track and in heading), the per-stage
milliseconds and the frames per second; writes JSON, and puts its table into docs/mono-vo.md.

    python benchmarks/mono_drive.py --out docs/results/mono_drive.json
    python benchmarks/mono_drive.py --render docs/results/mono_drive.json   # into docs/mono-vo.md
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import platform
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

import numpy as np

from common import write_json
from kartpilot.odometry.mono_localizer import place_ground_poses
from kartpilot.odometry.places import PlaceDatabase, build_places
from kartpilot.planning.reference_path import PathConfig
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.drive import WatchdogConfig
from kartpilot.runtime.path_policy import DriveConfig
from kartpilot.runtime.pipelines import Route
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation, run_supervised_drive
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.render import RenderConfig
from kartpilot.sim.simulator import SimConfig
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "mono-vo.md"
SIM = SimConfig(track="sdc-assen", vehicle="sdc-kart-steep", cameras=("center",), camera_rate_hz=10.0,
                render=RenderConfig(scenery_spacing_m=15.0))


def localisation_errors(log: Path, recording: Path, database: PlaceDatabase) -> dict[str, float]:
    """The fused pose of every step against the simulator's truth: along and across the true heading, and in
    heading."""
    reader = RecordingReader(recording)
    truth = reader.groundtruth()
    assert truth is not None, "a simulated drive has ground truth"
    camera = reader.cameras["center"]
    true = place_ground_poses(truth.poses, camera.pose_body_cam_array, database.poses_world_cam[0])
    along, across, heading = [], [], []
    with log.open() as handle:
        for row in csv.DictReader(handle):
            if row["pose_status"] != "ok":
                continue
            i = int(np.argmin(np.abs(truth.stamps_s - int(row["stamp_ns"]) * 1e-9)))
            x, y, yaw = true[i]
            dx, dy = float(row["x_m"]) - x, float(row["y_m"]) - y
            along.append(abs(math.cos(yaw) * dx + math.sin(yaw) * dy))
            across.append(abs(-math.sin(yaw) * dx + math.cos(yaw) * dy))
            heading.append(abs(math.degrees(math.remainder(float(row["yaw_rad"]) - yaw, math.tau))))
    a, h, g = np.array(across), np.array(heading), np.array(along)
    return {"along_track_p50_m": float(np.median(g)), "along_track_p90_m": float(np.percentile(g, 90)),
            "cross_track_p50_m": float(np.median(a)), "cross_track_p90_m": float(np.percentile(a, 90)),
            "cross_track_max_m": float(a.max()), "heading_p50_deg": float(np.median(h)),
            "heading_p90_deg": float(np.percentile(h, 90))}


def render(results: dict[str, Any]) -> str:
    """The closed-loop table of docs/mono-vo.md."""
    lines = [f"Measured by `benchmarks/mono_drive.py` (a lap taught on the centre line at 5 m/s, "
             f"{results['places']} places, through the supervisor and the virtual CAN bus):", "",
             "| run | distance | disqualified | centre offset max | localisation vs truth: across the track median / "
             "90 % | heading median / 90 % | step |", "|---|---|---|---|---|---|---|"]
    for name, label in (("noon", "noon, speed PI at 5 m/s"), ("dusk", "dusk (18:30), speed PI at 5 m/s")):
        run = results[name]
        stages = run["pipeline_stage_ms"]
        lines.append(f"| {label} | {run['distance_m']:.0f} m | {'yes' if run['disqualified'] else 'no'} | "
                     f"{run['max_center_offset_m']:.2f} m | {run['cross_track_p50_m']:.3f} / "
                     f"{run['cross_track_p90_m']:.3f} m | {run['heading_p50_deg']:.2f} / {run['heading_p90_deg']:.2f} "
                     f"deg | {run['step_ms']:.0f} ms (VO {stages.get('localize.vo', math.nan):.0f}, places "
                     f"{stages.get('localize.places', math.nan):.0f}): {run['fps']:.0f} frames/s |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=215.0, help="the taught drive (215: a lap)")
    parser.add_argument("--out", default="docs/results/mono_drive.json")
    parser.add_argument("--render", type=Path, help="write this JSON's table into docs/mono-vo.md")
    args = parser.parse_args()
    if args.render:
        put_at_marker(PAGE, render(json.loads(args.render.read_text())), "mono-drive")
        return
    results: dict[str, object] = {"machine": platform.processor() or platform.machine(), "seconds": args.seconds}
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        run_simulation(replace(SIM, max_time_s=args.seconds, seed=1), "centerline",
                       driver_config=CenterlineDriverConfig(speed_mps=5.0),
                       outputs=SessionOutputs(record_dir=Path(tmp) / "teach"))
        teach = RecordingReader(Path(tmp) / "teach")
        taught = teach.camera_poses("center")
        assert taught is not None, "a simulated drive has ground truth"
        database = build_places(teach.posed_frames("center", taught), teach.cameras["center"], "center")
        print(f"taught {args.seconds:g} s, {len(database)} places, in {time.perf_counter() - start:.0f} s")
        results["places"] = len(database)
        path = PathConfig(cruise_speed_mps=5.0, max_lateral_accel_mps2=2.0)
        for name, seed, hour in (("noon", 2, 13.0), ("dusk", 3, 18.5)):
            folder = Path(tmp) / f"run{seed}"
            sim = replace(SIM, seed=seed, max_time_s=args.seconds + 25.0,
                          render=replace(SIM.render, time_of_day_h=hour))
            start = time.perf_counter()
            stack = StackConfig(drive=DriveConfig(path=path), watchdogs=WatchdogConfig(overrun_factor=4.0))
            run = run_supervised_drive(sim, "mono-vo", stack, bus="virtual", route=Route(places=database),
                                       outputs=SessionOutputs(record_dir=folder / "rec",
                                                              drive_log=folder / "drive_log.csv"))
            wall_s = time.perf_counter() - start
            p = run.payload
            stages = cast(dict[str, float], p.get("pipeline_stage_ms") or {})
            step_ms = float(stages.get("localize", math.nan)) + float(stages.get("control", 0.0))
            errors = localisation_errors(folder / "drive_log.csv", folder / "rec", database)
            summary = {"distance_m": p["distance_m"], "disqualified": p["disqualified"], "reason": p["reason"],
                       "stop_reason": p.get("stop_reason", ""), "max_center_offset_m": p["max_center_offset_m"],
                       "place_fixes": p["relocalised_frames"], "bridged_frames": p["bridged_frames"],
                       "lost_frames": p["lost_frames"], "error": p.get("error"), **errors,
                       "pipeline_stage_ms": stages, "loop_stage_ms": p["stage_ms"], "step_ms": step_ms,
                       "fps": 1e3 / step_ms, "wall_s": wall_s}
            ended = f"disqualified: {p['reason']}" if p["disqualified"] else f"{p['reason']} ({summary['stop_reason']})"
            print(f"\n{name}: {p['distance_m']:.0f} m, {ended}; centre offset max {p['max_center_offset_m']:.2f} m")
            print(f"  localisation vs truth: along the track median {errors['along_track_p50_m']:.3f} m, 90 % "
                  f"{errors['along_track_p90_m']:.3f} m")
            print(f"  localisation vs truth: across the track median {errors['cross_track_p50_m']:.3f} m, 90 % "
                  f"{errors['cross_track_p90_m']:.3f} m; heading median {errors['heading_p50_deg']:.2f} deg, 90 % "
                  f"{errors['heading_p90_deg']:.2f} deg")
            print(f"  per step (ms): {stages}; {1e3 / step_ms:.0f} frames per second")
            results[name] = summary
    write_json(args.out, results)


if __name__ == "__main__":
    main()

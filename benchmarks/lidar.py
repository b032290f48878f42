"""What the LiDAR's processing costs a sweep on one core (issue 58's bound: 2 ms), and what simulating one costs.

The sweeps are the simulator's, of the 2026 kart (an RPLIDAR A2 at 10 Hz: 800 beams) driven along sdc-assen between
its tyre walls with a car and two people on it (hundreds of returns a sweep: the busy case); each is put through
what the lane pipeline does with a sweep (``perception.scan.lidar_view``: the returns on the body frame and their
clusters), the tracker, the free-space questions of the rules, and the camera's detections placed by it. The
medians and the 99th percentiles of each stage, in milliseconds, to JSON; ``--docs`` puts the table in
docs/lidar.md.

    python benchmarks/lidar.py --out docs/results/lidar.json
    python benchmarks/lidar.py --docs
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common import write_json
from kartpilot.perception.objects import Detection
from kartpilot.perception.scan import ScanTracker, corridor_free_m, lidar_view, locate_detections, side_clear
from kartpilot.sim.drivers import CenterlineDriver, CenterlineDriverConfig
from kartpilot.sim.simulator import SimConfig, Simulator
from kartpilot.sim.track import Prop
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "lidar.md"
MARKER = "lidar-cost"


def sweeps(track: str, props: tuple[Prop, ...], seconds: float) -> tuple[list[Any], list[Any], list[float]]:
    """The sweeps of a drive along ``track``'s centre line at 3 m/s with ``props`` on it, the kart's poses, and the
    seconds each simulated sweep took."""
    config = SimConfig(track=track, vehicle="sdc-kart-2026", seed=1, props=props, render_images=False,
                       camera_rate_hz=15.0, max_time_s=seconds)
    out, poses, costs = [], [], []
    with Simulator(config) as sim:
        driver = CenterlineDriver(sim, CenterlineDriverConfig(speed_mps=3.0))
        while not sim.done:
            start = time.perf_counter()
            frames = sim.read()
            if frames is None:
                break
            if "lidar" in frames.scans:
                costs.append(time.perf_counter() - start)
                out.append(frames.scans["lidar"])
                poses.append((sim.state.x_m, sim.state.y_m, sim.state.yaw_rad))
            sim.send(driver(frames))
    return out, poses, costs


def measure(scans: list[Any], poses: list[Any], repeats: int) -> dict[str, list[float]]:
    from kartpilot.core.vehicle import get_vehicle

    mount = get_vehicle("sdc-kart-2026").lidar
    assert mount is not None
    stages: dict[str, list[float]] = {"view (points and clusters)": [], "tracker": [], "free space and side": [],
                                      "detections placed": [], "all": []}
    camera = [Detection("car", (300, 200, 400, 260), 0.9, distance_m=12.0, lateral_m=0.0),
              Detection("person", (10, 200, 30, 260), 0.9, distance_m=8.0, lateral_m=2.0)]
    for _ in range(repeats):
        tracker = ScanTracker()
        for scan, pose in zip(scans, poses, strict=True):
            t0 = time.perf_counter()
            view = lidar_view(scan, mount)
            t1 = time.perf_counter()
            tracker.update(scan.stamp_ns, list(view.clusters), pose)
            t2 = time.perf_counter()
            corridor_free_m(view.points_m, -0.9, 0.9, 1.5, 41.5)
            side_clear(view.points_m, -2.3, 2.5, -4.2, -1.8)
            t3 = time.perf_counter()
            locate_detections(camera, list(view.clusters), mount)
            t4 = time.perf_counter()
            for key, seconds in zip(stages, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t4 - t0), strict=True):
                stages[key].append(seconds * 1e3)
    return stages


def render(results: dict[str, Any]) -> str:
    lines = [f"On {results['machine']} ({results['date']}, `benchmarks/lidar.py`), one core, "
             f"{results['sweeps']} simulated sweeps of {results['beams']} beams (sdc-assen between its tyre walls, a "
             f"car and two people on it: {results['returns_median']:.0f} returns and "
             f"{results['clusters_median']:.0f} objects a sweep at the median, up to {results['returns_max']:.0f} "
             f"and {results['clusters_max']:.0f}), each processed "
             f"{results['repeats']} times:", "", "| stage | median ms | p99 ms |", "|---|---:|---:|"]
    lines += [f"| {name} | {row['median_ms']:.3f} | {row['p99_ms']:.3f} |" for name, row in results["stages"].items()]
    lines += ["", f"Simulating a sweep (ray casting against the props and barriers in reach, every sweep of the "
                  f"drives): median {results['simulate_median_ms']:.1f} ms, p99 {results['simulate_p99_ms']:.1f} ms."]
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=15.0, help="each course's drive, s")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default="docs/results/lidar.json")
    parser.add_argument("--docs", action="store_true", help="only put the table from --out into the docs")
    args = parser.parse_args()
    if not args.docs:
        cv2.setNumThreads(1)
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
        # sdc-assen between its tyre walls (hundreds of returns a sweep), a car and two people on it; the event's
        # own course (lelystad) has nothing standing beside its road within the sensor's 12 m for most of a lap
        props = (Prop(kind="car", s_m=45.0, offset_m=0.0), Prop(kind="person", s_m=30.0, offset_m=2.5),
                 Prop(kind="person", s_m=60.0, offset_m=-2.0))
        scans, poses, costs = sweeps("sdc-assen", props, args.seconds)
        # the sweeps that saw something (an empty one, in open space, costs next to nothing and would only pull the
        # median down)
        seen = [k for k, scan in enumerate(scans) if np.isfinite(scan.ranges_m).any()]
        scans, poses = [scans[k] for k in seen], [poses[k] for k in seen]
        stages = measure(scans, poses, args.repeats)
        from kartpilot.core.vehicle import get_vehicle

        mount = get_vehicle("sdc-kart-2026").lidar
        assert mount is not None
        results = {"machine": f"{os.cpu_count()} cores, {sys.platform}, Python {sys.version.split()[0]}",
                   "date": time.strftime("%Y-%m-%d"), "sweeps": len(scans), "beams": len(scans[0].ranges_m),
                   "repeats": args.repeats,
                   "clusters_median": float(np.median([len(lidar_view(s, mount).clusters) for s in scans])),
                   "clusters_max": float(max(len(lidar_view(s, mount).clusters) for s in scans)),
                   "returns_median": float(np.median([np.isfinite(s.ranges_m).sum() for s in scans])),
                   "returns_max": float(max(np.isfinite(s.ranges_m).sum() for s in scans)),
                   "stages": {k: {"median_ms": float(np.median(v)), "p99_ms": float(np.percentile(v, 99))}
                              for k, v in stages.items()},
                   "simulate_median_ms": float(np.median(costs) * 1e3),
                   "simulate_p99_ms": float(np.percentile(costs, 99) * 1e3)}
        for name, row in results["stages"].items():
            print(f"{name}: median {row['median_ms']:.3f} ms, p99 {row['p99_ms']:.3f} ms")
        write_json(args.out, results)
    put_at_marker(PAGE, render(json.loads(Path(args.out).read_text(encoding="utf-8"))), MARKER)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

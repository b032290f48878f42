"""What the feature grid buys stereo VO: the same number of ORB features, spread by a budget per cell of the
thesis's grid (the defaults, 4 x 12) or taken where the corners are strongest (1 x 1), on KITTI 06 (the clip the
defaults were tuned on) and the small kart's utrack drives (seed 1 tuned on, seed 3 held out; recorded by
``vo_accuracy.py`` into ``--cache``). Per run: the end drift, the end rotation, the inliers a frame, and the
frames per second on this machine.

    python benchmarks/feature_grid.py --data ../shared/data --out docs/results/feature_grid.json
    python benchmarks/feature_grid.py --render docs/results/feature_grid.json   # into docs/stereo-vo.md
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from common import write_json
from kartpilot.eval.trajectory_metrics import evaluate_trajectory
from kartpilot.odometry.run import run_vo
from kartpilot.odometry.stereo_vo import StereoVO, StereoVOConfig
from kartpilot.record.recording import RecordingStereoSource
from kartpilot.sensors.base import StereoSource
from kartpilot.sensors.kitti import KittiOdometrySource
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "stereo-vo.md"
GRIDS = {"grid 4 x 12 (defaults)": (4, 12), "no grid (1 x 1)": (1, 1)}


def one(source: StereoSource, rows: int, cols: int) -> dict[str, Any]:
    config = StereoVOConfig()
    config = replace(config, features=replace(config.features, grid_rows=rows, grid_cols=cols))
    inliers: list[int] = []
    run = run_vo(source.frame_sets(), StereoVO(source.rig, config), source.name,
                 on_frame=lambda estimate: inliers.append(getattr(estimate, "inliers", 0)))
    truth = source.ground_truth()
    assert truth is not None
    metrics = evaluate_trajectory(truth, run.trajectory)
    return {"end_drift_percent": metrics.end_drift_percent, "end_rotation_deg": metrics.end_rotation_deg,
            "median_inliers": float(np.median(inliers[1:])), "frames_per_second": run.frames_per_second,
            "bridged_frames": run.bridged_frames}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--cache", type=Path, default=ROOT / "benchmarks" / "results" / "recordings")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "feature_grid.json")
    parser.add_argument("--render", type=Path, help="write this JSON's table into docs/stereo-vo.md")
    args = parser.parse_args()
    if args.render:
        put_at_marker(PAGE, render(json.loads(args.render.read_text())), "feature-grid")
        return 0
    sources: list[tuple[str, str, StereoSource]] = []
    if (args.data / "kitti-odometry").is_dir():
        sources.append(("KITTI 06", "tuned on", KittiOdometrySource(args.data / "kitti-odometry", "06")))
    for seed, kind in ((1, "tuned on"), (3, "held out")):
        folder = args.cache / f"utrack-rc-stereo-80s-{seed}"
        if (folder / "manifest.json").is_file():
            sources.append((f"utrack, seed {seed}", kind, RecordingStereoSource(folder)))
    rows = []
    for name, kind, source in sources:
        for grid, (r, c) in GRIDS.items():
            row = {"sequence": name, "kind": kind, "grid": grid, **one(source, r, c)}
            print(row)
            rows.append(row)
    write_json(args.out, {"rows": rows})
    return 0


def render(results: dict[str, Any]) -> str:
    lines = ["Measured by `benchmarks/feature_grid.py` (2500 ORB features either way; frames/s on a 2-core machine):",
             "", "| sequence | | features | end drift | end rotation | inliers a frame (median) | bridged | frames/s |",
             "|---|---|---|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['sequence']} | {r['kind']} | {r['grid']} | {r['end_drift_percent']:.2f} % | "
              f"{r['end_rotation_deg']:.2f}° | {r['median_inliers']:.0f} | {r['bridged_frames']} | "
              f"{r['frames_per_second']:.0f} |" for r in results["rows"]]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())

"""Stereo VO's pieces, each taken out or put in on its own, on every real clip with truth and on simulated bends.

The keyframe commit (174a3ac) brought five things at once: keyframes (each frame tracked against the last
keyframe's points, stereo on keyframes only), KLT as the default temporal matching, the attitude prior, the
motion model's prediction as KLT's starting point, and the motion check on the mean velocity since the keyframe.
Each row here is the defaults with one of them changed; the columns are the real clips of
:mod:`kartpilot.eval.vo_clips` (KITTI 06 whole and every 2nd and 3rd frame, EuRoC MH_01 whole and every 2nd frame)
and the simulated utrack drives (rc-kart stereo, 160 m with a 130-degree bend; seed 1 tuned the keyframes, the
others are held out) recorded once into ``--cache`` by ``benchmarks/vo_accuracy.py``'s recorder.

    python benchmarks/vo_ablation.py --data ../shared/data --out docs/results/vo_ablation.json
    python benchmarks/vo_ablation.py --render docs/results/vo_ablation.json   # into docs/stereo-vo.md
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import cv2

from common import write_json
from kartpilot.core.config import merge_config
from kartpilot.eval.vo_clips import real_clips, score_stereo, score_stereo_source
from kartpilot.odometry.stereo_vo import StereoVOConfig
from kartpilot.record.recording import RecordingStereoSource
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "stereo-vo.md"

VARIANTS: dict[str, dict[str, Any]] = {
    "defaults": {},
    "attitude prior 1 deg (174a3ac's)": {"attitude_prior_deg": 1.0},
    "no keyframes: descriptors frame to frame (before 174a3ac)": {"keyframes": False},
    "no keyframes, KLT frame to frame (174a3ac's default matching)": {"keyframes": False, "temporal_matching": "klt"},
    "no motion-model prediction for KLT": {"keyframe_prediction": False},
    "no motion check": {"motion_check": False},
    "no retracking from the keyframe's image": {"keyframe_retrack": False},
}
"""Each row: the defaults with these ``stereo_vo`` settings over them."""


def simulated(cache: Path, seeds: list[int]) -> list[tuple[str, Path]]:
    """The utrack recordings of ``seeds`` in the cache (``benchmarks/vo_accuracy.py`` records them)."""
    found = [(seed, cache / f"utrack-rc-stereo-80s-{seed}") for seed in seeds]
    return [(f"utrack seed {seed}" + (" (tuned)" if seed == 1 else ""), folder) for seed, folder in found
            if (folder / "manifest.json").is_file()]


def run(data: Path, cache: Path, seeds: list[int]) -> dict[str, Any]:
    clips = real_clips(data)
    drives = simulated(cache, seeds)
    rows = []
    for name, overrides in VARIANTS.items():
        config = merge_config(StereoVOConfig(), overrides, "stereo_vo")
        start = time.perf_counter()
        cells = [{"kind": "real", **score_stereo(clip, data, config)} for clip in clips]
        cells += [{"kind": "simulated", "clip": label, **score_stereo_source(RecordingStereoSource(folder), config)}
                  for label, folder in drives]
        print(f"{name:62s} " + "  ".join(f"{c['end_drift_percent']:5.2f}" for c in cells)
              + f"   ({time.perf_counter() - start:.0f} s)")
        rows.append({"variant": name, "overrides": overrides, "cells": cells})
    return {"date": datetime.date.today().isoformat(),
            "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                        "python": platform.python_version(), "opencv": cv2.__version__},
            "defaults": {k: getattr(StereoVOConfig(), k) for k in ("keyframes", "temporal_matching",
                                                                      "attitude_prior_deg", "keyframe_prediction",
                                                                      "motion_check", "keyframe_retrack")},
            "rows": rows}


def render(results: dict[str, Any]) -> str:
    """The table: end drift (% of the distance) per variant and clip, bridged frames where there were any."""
    clips = [(c["kind"], c["clip"]) for c in results["rows"][0]["cells"]]
    lines = [f"Measured on {results['date']} by `benchmarks/vo_ablation.py` ({results['machine']['cpus']} cores, "
             f"OpenCV {results['machine']['opencv']}): stereo VO's end drift, % of the distance driven, with the "
             "defaults (" + ", ".join(f"`{k}: {v}`" for k, v in results["defaults"].items()) + ") and with one "
             "piece changed per row. Real clips first, then simulated; a number in brackets counts bridged frames.",
             "", "| variant | " + " | ".join(f"{clip} ({kind})" for kind, clip in clips) + " |",
             "|---|" + "---:|" * len(clips)]
    for row in results["rows"]:
        lines.append(f"| {row['variant']} | " + " | ".join(
            f"{c['end_drift_percent']:.2f} %" + (f" ({c['bridged_frames']})" if c["bridged_frames"] else "")
            for c in row["cells"]) + " |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--cache", type=Path, default=ROOT / "benchmarks" / "results" / "recordings")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "vo_ablation.json")
    parser.add_argument("--render", type=Path, help="write this JSON's table into docs/stereo-vo.md")
    args = parser.parse_args()
    if args.render:
        put_at_marker(PAGE, render(json.loads(args.render.read_text())), "vo-ablation")
        return 0
    cv2.setNumThreads(1)
    write_json(args.out, run(args.data, args.cache, args.seeds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Which of the real camera's effects costs simulated stereo VO its accuracy: the rc-kart's stereo on utrack through
the kart presets' real camera, then with one effect at a time switched off (rolling shutter, exposure blur, MJPG,
sensor noise, auto-exposure, the rectification residual), and through the perfect camera. Each drive recorded once
into ``--cache`` (as ``benchmarks/honest_camera.py`` does) and scored with the stereo VO defaults.

    python benchmarks/camera_ablation.py --seeds 3 --out docs/results/camera_ablation.json
    python benchmarks/camera_ablation.py --render docs/results/camera_ablation.json   # into docs/simulator.md

Seed 1 tuned the keyframes; 2 and 3 are held out (none of the effects' values were set on them: they come from
the real clips, ``benchmarks/honest_camera.py``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2

from common import write_json
from kartpilot.eval.vo_clips import score_stereo_source
from kartpilot.record.recording import RecordingStereoSource
from kartpilot.sim.simulator import CameraEffectsConfig, SimConfig, perfect_camera, real_camera
from vo_accuracy import record_once
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "simulator.md"

VARIANTS: dict[str, dict[str, Any]] = {
    "real": {},
    "no rolling shutter": {"rolling_shutter_s": 0.0},
    "no exposure blur": {"exposure_blur_samples": 0},
    "no MJPG": {"jpeg_quality": 0},
    "no noise": {"noise_sigma": 0.0, "shot_noise": 0.0},
    "no auto-exposure": {"auto_exposure_s": 0.0},
    "no rectification residual": {"rectification_residual_px": 0.0},
}
"""The real camera and each effect switched off alone (the perfect camera has them all off)."""


def effects_of(variant: str) -> CameraEffectsConfig:
    return perfect_camera() if variant == "perfect" else replace(real_camera("rc-kart"), **VARIANTS[variant])


def row(cache: Path, seed: int, variant: str, seconds: float) -> dict[str, Any]:
    config = SimConfig(track="utrack", vehicle="rc-kart", cameras=("left", "right"), camera_rate_hz=10.0,
                       max_time_s=seconds, seed=seed, effects=effects_of(variant))
    name = f"utrack-rc-stereo-{seconds:g}s-{seed}-" + variant.replace(" ", "-")
    folder = record_once(cache / name, config, 2.0)
    return {"seed": seed, "camera": variant, **score_stereo_source(RecordingStereoSource(folder))}


def render(results: dict[str, Any]) -> str:
    seeds = sorted({r["seed"] for r in results["rows"]})
    lines = ["| camera | " + " | ".join(f"utrack seed {s} end drift %" for s in seeds) + " |",
             "|---|" + "---:|" * len(seeds)]
    for variant in [*VARIANTS, "perfect"]:
        cells = [next((f"{r['end_drift_percent']:.2f}" for r in results["rows"]
                       if r["seed"] == s and r["camera"] == variant), "-") for s in seeds]
        lines.append(f"| {variant} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + (f"\n\n*{results['date']}, utrack {results['seconds']:g} s at 2 m/s, stereo VO "
                               f"defaults, `benchmarks/camera_ablation.py`*\n")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="3", help="comma-separated utrack seeds")
    parser.add_argument("--seconds", type=float, default=80.0, help="each drive's length")
    parser.add_argument("--variants", default=",".join([*VARIANTS, "perfect"]))
    parser.add_argument("--cache", default="benchmarks/results/recordings", help="simulated recordings, kept")
    parser.add_argument("--out", default="docs/results/camera_ablation.json")
    parser.add_argument("--render", help="put the table of this JSON into docs/simulator.md")
    args = parser.parse_args()
    if args.render:
        put_at_marker(PAGE, render(json.loads(Path(args.render).read_text())), "camera-ablation")
        return 0
    cv2.setNumThreads(1)
    rows = []
    for seed in (int(s) for s in args.seeds.split(",")):
        for variant in args.variants.split(","):
            rows.append(row(Path(args.cache), seed, variant, args.seconds))
            print(json.dumps(rows[-1]), flush=True)
    write_json(args.out, {"date": datetime.date.today().isoformat(), "seconds": args.seconds, "rows": rows,
                          "machine": {"cpus": os.cpu_count(), "python": platform.python_version()}})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

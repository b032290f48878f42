"""Stereo VO speed: per-stage milliseconds and end-to-end frames per second.

Runs on KITTI sequence 06 from ``--data`` when present (else the synthetic
sequence), with frames preloaded so disk reads are not timed, over several
repeats; prints a table and writes JSON.

    python benchmarks/stereo_vo.py --data ../shared/data --out benchmarks/results/stereo_vo.json
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import cv2
import numpy as np

from common import write_json
from kartpilot.odometry.stereo_vo import StereoVO, StereoVOConfig
from kartpilot.runtime.demo_source import default_stereo_source


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="benchmarks/results/stereo_vo.json")
    args = parser.parse_args()
    source, fallback = default_stereo_source(args.data)
    if fallback:
        print(fallback)
    frames = [f for f in source.frame_sets() if not isinstance(f, int)]
    per_run_fps = []
    stage_samples: dict[str, list[float]] = {}
    for _ in range(args.repeats):
        vo = StereoVO(source.rig, StereoVOConfig())
        start = time.perf_counter()
        for frame in frames:
            estimate = vo.process(frame)
            if estimate.status != "init":
                for stage, ms in estimate.diagnostics.timing_ms.items():
                    stage_samples.setdefault(stage, []).append(ms)
        per_run_fps.append(len(frames) / (time.perf_counter() - start))
        vo.close()
    stages = {stage: float(np.median(values)) for stage, values in stage_samples.items()}
    result = {
        "source": source.name,
        "image_size": [source.rig.camera.width_px, source.rig.camera.height_px],
        "frames": len(frames),
        "repeats": args.repeats,
        "fps_median": float(np.median(per_run_fps)),
        "fps_runs": per_run_fps,
        "stage_ms_median": stages,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "opencv": cv2.__version__,
                    "opencv_threads": cv2.getNumThreads()},
    }
    print(f"stereo VO on {source.name} ({result['image_size'][0]}x{result['image_size'][1]}), "
          f"{len(frames)} frames x {args.repeats}")
    for stage, ms in sorted(stages.items(), key=lambda item: -item[1]):
        print(f"  {stage:<16}{ms:8.2f} ms")
    print(f"  {'total':<16}{1000.0 / result['fps_median']:8.2f} ms  ->  {result['fps_median']:.1f} frames/s")
    write_json(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

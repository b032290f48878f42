"""The simulated camera held to real ones: the same measurements on real clips and on simulated drives through a
perfect camera (``--perfect-camera``, :func:`kartpilot.sim.simulator.perfect_camera`) and through the vehicle's
real camera (the kart presets' default, :func:`kartpilot.sim.simulator.real_camera`), and what each does to VO.

Measured on the real clips (none of them tuned anything here): a rectified pair's vertical offset and the frame to
frame brightness steps, and stereo VO's drift. Simulated: the rc-kart's stereo on utrack (seed 1 tuned the
keyframes, 2 and 3 held out) and the sdc-kart's centre camera on sdc-assen with monocular VO (seed 3, held out),
each drive recorded once per camera into ``--cache``.

    python benchmarks/honest_camera.py --data ../shared/data --out docs/results/honest_camera.json
    python benchmarks/honest_camera.py --render docs/results/honest_camera.json   # into docs/simulator.md
    python benchmarks/honest_camera.py --render docs/results/honest_camera_20261127.json \
        --marker honest-camera-trilinear   # the table before the texture filter changed
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common import write_json
from kartpilot.core.vehicle import get_vehicle
from kartpilot.eval.camera_realism import brightness_steps_percent, vertical_offset_px
from kartpilot.eval.trajectory_metrics import evaluate_trajectory
from kartpilot.eval.vo_clips import real_clips, score_stereo, score_stereo_source
from kartpilot.odometry.mono_vo import GroundConfig, MonoVO, MonoVOConfig
from kartpilot.odometry.run import run_vo
from kartpilot.record.recording import RecordingReader, RecordingStereoSource
from kartpilot.record.replay import RecordingFrameSource
from kartpilot.sensors.base import StereoSource
from kartpilot.sensors.euroc import EurocSource
from kartpilot.sensors.kitti import KittiOdometrySource
from kartpilot.sim.simulator import SimConfig, real_camera
from vo_accuracy import record_once, simulated_camera
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "simulator.md"


def camera_figures(source: StereoSource, every: int = 5, count: int = 20) -> dict[str, float]:
    """The pair's vertical offset (median over ``count`` pairs, every ``every``-th frame) and the brightness steps
    of the left camera over the whole clip, in one pass over it."""
    offsets: list[float] = []

    def lefts() -> Iterator[np.ndarray]:
        for k, frames in enumerate(source.frame_sets()):
            if isinstance(frames, int):
                continue
            if k % every == 0 and len(offsets) < count:
                offsets.append(vertical_offset_px(frames.images["left"], frames.images["right"])[0])
            yield frames.images["left"]

    steps = brightness_steps_percent(lefts())
    return {"vertical_offset_px": float(np.nanmedian(offsets)), "brightness_steps_percent": steps}


def real_rows(data: Path) -> list[dict[str, Any]]:
    rows = []
    sources = {"kitti-06": lambda: KittiOdometrySource(data / "kitti-odometry", "06"),
               "euroc-mh01": lambda: EurocSource(data / "euroc-mh01-moving")}
    for clip in real_clips(data):
        if clip.stride != 1:
            continue
        row = {"kind": "real", "camera": "real", **score_stereo(clip, data), **camera_figures(sources[clip.label]())}
        print(row)
        rows.append(row)
    return rows


def simulated_rows(cache: Path) -> list[dict[str, Any]]:
    rows = []
    for camera in ("perfect", "real"):
        effects, suffix = simulated_camera(camera)
        for seed in (1, 2, 3):
            config = SimConfig(track="utrack", vehicle="rc-kart", cameras=("left", "right"), camera_rate_hz=10.0,
                               max_time_s=80.0, seed=seed, effects=effects)
            folder = record_once(cache / f"utrack-rc-stereo-80s-{seed}{suffix}", config, 2.0)
            source = RecordingStereoSource(folder)
            row = {"kind": "simulated", "camera": camera, "clip": f"utrack seed {seed}" + (" (tuned)" if seed == 1
                                                                                          else ""),
                   "vo": "stereo", **score_stereo_source(source), **camera_figures(source)}
            print(row)
            rows.append(row)
        config = SimConfig(track="sdc-assen", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=10.0,
                           max_time_s=70.0, seed=3, effects=effects)
        folder = record_once(cache / f"assen-sdc-centre-70s-3{suffix}", config, 4.0)
        reader = RecordingReader(folder)
        lens = reader.cameras["center"]
        height = float(lens.pose_body_cam_array[2, 3])
        vo = MonoVO(lens, MonoVOConfig(ground=GroundConfig(camera_height_m=height)), "center",
                    get_vehicle("sdc-kart"))
        run = run_vo(iter(RecordingFrameSource(folder, ["center"]).read, None), vo, folder.name)
        truth = reader.camera_poses("center")
        assert truth is not None, f"{folder} has no ground truth"
        metrics = evaluate_trajectory(truth, run.trajectory)
        images = (frames.images["center"] for frames in iter(RecordingFrameSource(folder, ["center"]).read, None))
        row = {"kind": "simulated", "camera": camera, "clip": "sdc-assen seed 3", "vo": "mono",
               "end_drift_percent": metrics.end_drift_percent, "ate_rmse_m": metrics.ate_rmse_m,
               "distance_m": metrics.path_length_m, "bridged_frames": run.bridged_frames,
               "frames_per_second": run.frames_per_second, "vertical_offset_px": float("nan"),
               "brightness_steps_percent": brightness_steps_percent(images)}
        print(row)
        rows.append(row)
    return rows


def render(results: dict[str, Any]) -> str:
    lines = ["| clip | kind | camera | VO | end drift % | ATE m | pair's vertical offset px | brightness step % |",
             "|---|---|---|---|---:|---:|---:|---:|"]
    for row in results["rows"]:
        offset = row.get("vertical_offset_px", float("nan"))
        lines.append(f"| {row['clip']} | {row['kind']} | {row['camera']} | {row.get('vo', 'stereo')} | "
                     f"{row['end_drift_percent']:.2f} | {row['ate_rmse_m']:.3f} | "
                     + ("-" if offset != offset else f"{offset:+.2f}")
                     + f" | {row['brightness_steps_percent']:.2f} |")
    return "\n".join(lines) + f"\n\n*{results['date']}, {results['machine']['cpus']} cores, " \
                              f"`benchmarks/honest_camera.py`*\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--cache", default="benchmarks/results/recordings", help="simulated recordings, kept")
    parser.add_argument("--out", default="docs/results/honest_camera.json")
    parser.add_argument("--render", help="put the table of this JSON into docs/simulator.md")
    parser.add_argument("--marker", default="honest-camera", help="where in docs/simulator.md (with --render)")
    args = parser.parse_args()
    if args.render:
        put_at_marker(PAGE, render(json.loads(Path(args.render).read_text(encoding="utf-8"))), args.marker)
        return 0
    rows = real_rows(Path(args.data)) + simulated_rows(Path(args.cache))
    write_json(args.out, {"date": datetime.date.today().isoformat(),
                          "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                                      "python": platform.python_version(), "opencv": cv2.__version__},
                          "effects": {vehicle: real_camera(vehicle).__dict__ for vehicle in ("rc-kart", "sdc-kart")},
                          "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

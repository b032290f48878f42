"""Speed of the waypoint-following pipeline (the small kart's autonomous mode), per frame.

A short drive of utrack (rc-kart stereo pair, 960x540) is taught in the simulator and turned into a
reference path and a visual map; then the pipeline (stereo VO, relocalisation against the map,
path following) runs over the same frames, preloaded, so only the pipeline is timed. Prints the
per-stage milliseconds and frames per second, writes JSON.

    python benchmarks/drive.py --out benchmarks/results/drive.json
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from common import write_json
from kartpilot.control.path_follow import PathFollowConfig
from kartpilot.core.geometry import ground_poses
from kartpilot.core.types import FrameSet
from kartpilot.core.vehicle import get_vehicle
from kartpilot.odometry.localizer import StereoVOLocalizer
from kartpilot.odometry.run import run_teach
from kartpilot.planning.reference_path import PathConfig, build_reference_path
from kartpilot.record.recording import RecordingStereoSource
from kartpilot.runtime.path_policy import PathFollowPolicy
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.simulator import SimConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="length of the taught drive")
    parser.add_argument("--out", default="benchmarks/results/drive.json")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    vehicle = get_vehicle("rc-kart")
    body_cam = vehicle.camera("left").pose_body_cam_array
    with tempfile.TemporaryDirectory() as folder:
        teach = Path(folder) / "teach"
        config = SimConfig(track="utrack", vehicle="rc-kart", cameras=("left", "right"), camera_rate_hz=15.0,
                           max_time_s=args.seconds, seed=1)
        run_simulation(config, "centerline", CenterlineDriverConfig(speed_mps=2.0),
                       outputs=SessionOutputs(record_dir=teach))
        source = RecordingStereoSource(teach)
        vo_run, visual_map = run_teach(source, body_cam)
        path = build_reference_path(ground_poses(vo_run.trajectory.poses, body_cam)[:, :2], PathConfig())
        frames = [source.frame(i) for i in range(len(source))]
    localizer = StereoVOLocalizer(source.rig, body_cam, visual_map=visual_map)
    policy = PathFollowPolicy(localizer, path, PathFollowConfig(), vehicle.wheelbase_m, vehicle.max_steer_rad, 15.0)
    step_ms = []
    try:
        for frame in frames:
            start = time.perf_counter()
            policy(FrameSet(frame.index, frame.stamp_ns, {"left": frame.left, "right": frame.right}))
            step_ms.append((time.perf_counter() - start) * 1e3)
    finally:
        policy.close()
    count = len(frames)
    stages = {f"localize.{k}": v / count for k, v in localizer.timing_ms.items()}
    stages["control"] = 1e3 * policy.stage_s["control"] / count
    median = float(np.median(step_ms))
    stage_ms = {k: round(v, 3) for k, v in stages.items()}
    result = {
        "frames": count, "image_size": [int(frames[0].left.shape[1]), int(frames[0].left.shape[0])],
        "keyframes": len(visual_map), "relocalised_frames": localizer.relocalisations,
        "stage_ms_mean": stage_ms,
        "step_ms_median": round(median, 2), "step_ms_p95": round(float(np.percentile(step_ms, 95)), 2),
        "frames_per_second": round(1000.0 / median, 1),
        "machine": {"processor": platform.processor() or platform.machine(), "python": platform.python_version(),
                    "opencv_threads": 1},
    }
    for name, ms in stage_ms.items():
        print(f"{name:28s} {ms:7.2f} ms")
    print(f"step: median {median:.1f} ms, p95 {result['step_ms_p95']} ms -> {result['frames_per_second']} frames/s "
          f"({count} frames, {localizer.relocalisations} relocalised against {len(visual_map)} keyframes)")
    write_json(args.out, result)


if __name__ == "__main__":
    main()

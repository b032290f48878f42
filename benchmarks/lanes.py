"""Lane-following speed on one core: the centre-camera pipeline, and all three cameras with fusion.

Centre camera: the real road photos at 960x540 (``../shared/data/road-lanes/udacity-p1``, or simulated
frames when absent). Three cameras: the sdc-kart's cameras re-made at 960x540 and rendered by the
simulator on sdc-assen. Frames are preloaded; OpenCV runs on one thread. Prints per-stage ms and
frames per second, the centre camera's camera-to-command time stage by stage (MJPEG decode to CAN frames),
and the taped-track pipeline's time per frame, and writes JSON.

    python benchmarks/lanes.py --data ../shared/data --out benchmarks/results/lanes.json
"""

from __future__ import annotations

import argparse
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common import write_json
from kartpilot.actuation.rdw_protocol import load_rdw_dbc, rdw_command_frames
from kartpilot.control.lane_follow import LaneFollowConfig, LaneFollowState, lane_follow_step
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.types import FrameSet
from kartpilot.core.vehicle import get_vehicle
from kartpilot.perception import lanes as lanes_module
from kartpilot.perception.lanes import LaneConfig, detect_lanes
from kartpilot.perception.tape import detect_tape_track
from kartpilot.runtime.lane_policy import LanePolicy
from kartpilot.sim.render import Renderer
from kartpilot.sim.simulator import camera_poses_on_route
from kartpilot.sim.track import load_track

W, H = 960, 540


def kart_cameras_960() -> dict[str, PinholeCamera]:
    """The sdc-kart's cameras with the same poses and fields of view, at 960x540."""
    out = {}
    for name, cam in get_vehicle("sdc-kart").cameras:
        f = cam.fx_px * W / cam.width_px
        out[name] = PinholeCamera(f, f, (W - 1) / 2, (H - 1) / 2, W, H, (), cam.pose_body_cam)
    return out


def simulated_frames(cameras: dict[str, PinholeCamera], count: int) -> list[FrameSet]:
    track = load_track("sdc-assen")
    frames = []
    with Renderer(track, cameras) as renderer:
        for k in range(count):
            images = renderer.render(camera_poses_on_route(track, cameras, 40 * k))
            frames.append(FrameSet(k, k, images))
    return frames


def timed(function: Callable[[Any], object], items: Sequence[Any], repeats: int) -> float:
    start = time.perf_counter()
    for _ in range(repeats):
        for item in items:
            function(item)
    return (time.perf_counter() - start) / (repeats * len(items))


def camera_to_command_ms(images: Sequence[np.ndarray], config: LaneConfig, follow: LaneFollowConfig,
                         repeats: int) -> dict[str, float]:
    """Per stage, what a centre-camera frame costs from the camera's bytes to the CAN frames: the USB camera's
    MJPEG decoded, the pipeline's stages (``perception.lanes``'s own steps), the follower, the RDW frames
    encoded. The camera's exposure and the USB transfer happen before and are not measured here."""
    db = load_rdw_dbc()
    jpegs = [cv2.imencode(".jpg", im, [cv2.IMWRITE_JPEG_QUALITY, 85])[1] for im in images]
    h = images[0].shape[0]
    top = round(config.roi_top * h)
    regions = [lanes_module._lane_gray(im[top:], config.yellow_boost) for im in images]
    observations = [detect_lanes(im, config) for im in images]
    decisions = [lane_follow_step(follow, LaneFollowState(), o)[0] for o in observations]
    stages = {
        "MJPEG decode": timed(lambda b: cv2.imdecode(b, cv2.IMREAD_COLOR), jpegs, repeats),
        "grey (region of interest)": timed(lambda im: lanes_module._lane_gray(im[top:], config.yellow_boost),
                                           images, repeats),
        "blur, Canny, Hough": timed(lambda r: lanes_module._hough_segments(r, config, W, top), regions, repeats),
        "filters and merge": timed(lambda im: detect_lanes(im, config), images, repeats),
        "follower": timed(lambda o: lane_follow_step(follow, LaneFollowState(), o), observations, repeats),
        "CAN frames (RDW)": timed(lambda d: rdw_command_frames(db, -d.steer_rad, d.throttle, d.brake, "forward", 0),
                                  decisions,
                                  repeats),
    }
    # detect_lanes includes the grey and Hough stages: what is left is the filters and the merge
    stages["filters and merge"] -= stages["grey (region of interest)"] + stages["blur, Canny, Hough"]
    return {name: 1000 * max(seconds, 0.0) for name, seconds in stages.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--out", default="benchmarks/results/lanes.json")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    cameras = kart_cameras_960()
    sim_frames = simulated_frames(cameras, 20)
    photos = sorted((Path(args.data) / "road-lanes" / "udacity-p1").glob("*.jpg"))
    centre_images = [cv2.imread(str(p)) for p in photos] or [f.images["center"] for f in sim_frames]
    source = "udacity-p1 photos" if photos else "simulated frames"
    config, follow = LaneConfig(), LaneFollowConfig()

    def centre_step(image: np.ndarray) -> None:
        lane_follow_step(follow, LaneFollowState(), detect_lanes(image, config))

    centre_s = timed(centre_step, centre_images, args.repeats)
    stage = {
        "grayscale": timed(lambda im: cv2.cvtColor(im, cv2.COLOR_BGR2GRAY), centre_images, args.repeats),
        "detect_lanes": timed(lambda im: detect_lanes(im, config), centre_images, args.repeats),
    }
    policy = LanePolicy(cameras)
    fused_s = timed(policy, sim_frames, max(1, args.repeats // 2))
    latency = camera_to_command_ms(centre_images, config, follow, args.repeats)
    tape_small = [cv2.resize(im, (160, 120), interpolation=cv2.INTER_AREA) for im in centre_images]
    tape = {"160x120_ms": 1000 * timed(detect_tape_track, tape_small, args.repeats * 5),
            "960x540_ms": 1000 * timed(detect_tape_track, centre_images, args.repeats)}
    result = {
        "image_size": [W, H], "centre_source": source, "opencv_threads": cv2.getNumThreads(),
        "centre_fps": 1.0 / centre_s, "centre_ms": 1000 * centre_s,
        "three_cameras_fps": 1.0 / fused_s, "three_cameras_ms": 1000 * fused_s,
        "stage_ms": {k: 1000 * v for k, v in stage.items()},
        "camera_to_command_ms": latency, "camera_to_command_total_ms": sum(latency.values()),
        "tape_ms": tape,
        "machine": {"python": platform.python_version(), "opencv": cv2.__version__},
    }
    print(f"lane following at {W}x{H}, one OpenCV thread")
    for name, ms in result["stage_ms"].items():
        print(f"  {name:<24}{ms:8.2f} ms")
    print(f"  centre camera + control  {result['centre_ms']:8.2f} ms -> {result['centre_fps']:.0f} "
          f"frames/s (target 300)")
    print(f"  three cameras + fusion   {result['three_cameras_ms']:8.2f} ms -> {result['three_cameras_fps']:.0f} "
          f"frames/s (target 150)")
    print("  camera to command, centre camera (one frame at 30 Hz):")
    for name, ms in latency.items():
        print(f"    {name:<30}{ms:8.2f} ms")
    total = result["camera_to_command_total_ms"]
    print(f"    {'total':<30}{total:8.2f} ms = {total / 1000 * 30 / 3.6 * 100:.1f} cm at 30 km/h, "
          f"{100 * total / (1000 / 30):.0f} % of a 30 Hz frame")
    print(f"  taped track (detect_tape_track): {tape['160x120_ms']:.3f} ms at 160x120, {tape['960x540_ms']:.2f} ms "
          f"at 960x540")
    write_json(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

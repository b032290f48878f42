"""The subcommands' bodies: load inputs, call a library function, print and write results."""

from __future__ import annotations

import argparse
import json
import math
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from kartpilot.core.errors import ConfigError
from kartpilot.core.trajectory import Trajectory, read_trajectory, write_trajectory
from kartpilot.eval.disparity import bad_pixel_rate, disparity_search_range_px, load_middlebury_pair
from kartpilot.eval.plots import plot_trajectories
from kartpilot.eval.trajectory_metrics import TrajectoryMetrics, evaluate_trajectory
from kartpilot.odometry.run import OdometryRun, run_stereo_vo
from kartpilot.odometry.stereo_vo import StereoVOConfig
from kartpilot.perception.stereo import BlockMatchConfig, compute_disparity
from kartpilot.record.recording import RecordingStereoSource
from kartpilot.runtime.config import load_stack_config
from kartpilot.runtime.simulate import SimRun, run_simulation
from kartpilot.sensors.base import StereoSource
from kartpilot.sensors.euroc import EurocSource
from kartpilot.sensors.kitti import KittiOdometrySource
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.referee import RunResult
from kartpilot.sim.simulator import SimConfig
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource

__all__ = ["demo", "disparity", "evaluate", "odometry", "run_and_report", "simulate"]


def _open_source(args: argparse.Namespace) -> StereoSource:
    if args.source == "kitti":
        return KittiOdometrySource(args.root, args.sequence)
    if args.source == "euroc":
        return EurocSource(args.root)
    if args.source == "recording":
        return RecordingStereoSource(args.root)
    return SyntheticStereoSource(SyntheticStereoConfig(frames=args.frames, seed=args.seed))


def _write_json(path: str | Path, data: dict[str, Any]) -> None:
    def clean(value: Any) -> Any:
        if isinstance(value, float) and not math.isfinite(value):
            return None
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(v) for v in value]
        if isinstance(value, np.generic):
            return clean(value.item())
        return value

    Path(path).write_text(json.dumps(clean(data), indent=2) + "\n")


def run_and_report(source: StereoSource, config: StereoVOConfig, out: str | Path | None, fmt: str | None,
                   plot: str | Path | None, progress: bool) -> tuple[OdometryRun, TrajectoryMetrics | None]:
    """Run VO, write the trajectory, print the summary and (with ground truth) the metrics."""
    with tqdm(total=len(source), desc=f"VO {source.name}", unit="frame", disable=not progress or None,
              leave=False) as bar:
        run = run_stereo_vo(source, config, on_frame=lambda _: bar.update(1))
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        write_trajectory(out, run.trajectory, fmt)  # type: ignore[arg-type]
    print(run.summary())
    print("stage ms: " + ", ".join(f"{k} {v:.1f}" for k, v in run.stage_ms().items()))
    ground_truth = source.ground_truth()
    metrics = None
    if ground_truth is not None and len(ground_truth) >= 2:
        metrics = evaluate_trajectory(ground_truth, run.trajectory)
        print(metrics.table())
    if plot is not None:
        plot_trajectories(ground_truth, run.trajectory, plot, title=source.name)
    return run, metrics


def odometry(args: argparse.Namespace) -> int:
    config = load_stack_config(args.config).stereo_vo
    source = _open_source(args)
    run, metrics = run_and_report(source, config, args.out, args.format, args.plot, not args.no_progress)
    print(f"trajectory written to {args.out}")
    if args.json:
        _write_json(args.json, {
            "source": source.name, "frames": len(run.estimates), "bridged_frames": run.bridged_frames,
            "unreadable_frames": list(run.unreadable_frames), "frames_per_second": run.frames_per_second,
            "stage_ms": run.stage_ms(), "metrics": metrics.as_dict() if metrics else None})
    return 0


def evaluate(args: argparse.Namespace) -> int:
    reference = read_trajectory(args.gt, args.format)
    estimate = read_trajectory(args.est, args.format)
    untimed = reference.stamps_s[-1] == len(reference) - 1 and estimate.stamps_s[-1] == len(estimate) - 1
    if len(reference) != len(estimate) and untimed:
        # KITTI pose files carry no timestamps: compare the common prefix frame by frame
        count = min(len(reference), len(estimate))
        reference = Trajectory(reference.stamps_s[:count], reference.poses[:count])
        estimate = Trajectory(estimate.stamps_s[:count], estimate.poses[:count])
    metrics = evaluate_trajectory(reference, estimate)
    print(metrics.table())
    if args.plot:
        plot_trajectories(reference, estimate, args.plot)
    if args.json:
        _write_json(args.json, metrics.as_dict())
    return 0


def disparity(args: argparse.Namespace) -> int:
    left, right, truth = load_middlebury_pair(args.pair)
    config = BlockMatchConfig(method=args.method, num_disparities=disparity_search_range_px(truth),
                              block_size=15 if args.method == "bm" else 5, wls=args.wls)
    score = bad_pixel_rate(compute_disparity(left, right, config), truth, args.threshold)
    print(f"{Path(args.pair).name}: {args.method}{' + WLS' if args.wls else ''} bad-{args.threshold:g} "
          f"{score.bad_percent:.1f} % (no estimate on {score.invalid_percent:.1f} %) over "
          f"{score.pixels_with_truth} pixels")
    return 0


def _print_result(result: RunResult, run: SimRun) -> None:
    verdict = f"DISQUALIFIED: {result.reason}" if result.disqualified else result.reason
    lap = f"{result.lap_time_s:.2f} s" if result.lap_time_s is not None else "-"
    print(f"{verdict} | {result.distance_m:.1f} m driven, lap {lap}, cones hit {result.cones_hit}, "
          f"centre offset mean {result.mean_center_offset_m:.3f} m / max {result.max_center_offset_m:.3f} m | "
          f"sim {result.sim_time_s:.1f} s in {result.wall_time_s:.1f} s wall, {run.steps} steps")


def simulate(args: argparse.Namespace) -> int:
    stack = load_stack_config(args.config)
    config, driver = stack.sim, stack.centerline_driver
    overrides = {"track": args.track, "vehicle": args.vehicle, "seed": args.seed, "camera_rate_hz": args.rate}
    config = replace(config, **{k: v for k, v in overrides.items() if v is not None})
    if args.cameras:
        config = replace(config, cameras=tuple(c.strip() for c in args.cameras.split(",") if c.strip()))
    if args.laps is not None:
        config = replace(config, referee=replace(config.referee, laps=args.laps))
    if args.no_cones:
        config = replace(config, show_cones=False)
    if args.no_render:
        if args.record or args.video:
            raise ConfigError("--no-render cannot record images or a video")
        config = replace(config, render_images=False)
    driver_overrides = {"speed_mps": args.speed, "weave_amplitude_m": args.weave, "edge_offset_m": args.edge_offset}
    driver = replace(driver, **{k: v for k, v in driver_overrides.items() if v is not None})
    run = run_simulation(config, args.driver, driver, args.commands, args.record, args.video, args.result,
                         progress=not args.no_progress)
    _print_result(run.result, run)
    for label, path in (("recording", args.record), ("video", args.video), ("result", args.result)):
        if path:
            print(f"{label} written to {path}")
    return 0


def demo(args: argparse.Namespace) -> int:
    """Closed loop in the simulator: drive straight20 with the rc-kart, record it, then run stereo VO on the
    recording and score it against the simulator's ground truth."""
    out = Path(args.out)
    record = out / "straight20-run"
    if record.exists():
        shutil.rmtree(record)
    config = SimConfig(track="straight20", vehicle="rc-kart", cameras=("left", "right", "center"), seed=1)
    print("driving straight20 with the rc-kart (centerline driver, 1.0 m/s), recording every camera ...")
    run = run_simulation(config, "centerline", CenterlineDriverConfig(speed_mps=1.0), record_dir=record,
                         video_path=out / "straight20.mp4", progress=True)
    _print_result(run.result, run)
    print("stereo VO on the recording, against the simulator's ground truth:")
    _, metrics = run_and_report(RecordingStereoSource(record), StereoVOConfig(), out / "trajectory.txt", "kitti",
                                out / "trajectory.png", progress=True)
    if metrics is not None:
        _write_json(out / "metrics.json", metrics.as_dict())
    print(f"wrote {record}, {out / 'straight20.mp4'}, {out / 'trajectory.txt'}, {out / 'trajectory.png'}")
    return 0

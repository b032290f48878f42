"""The subcommands' bodies: load inputs, call a library function, print and write results."""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from tqdm import tqdm

from kartpilot.calibration.rig import load_rig
from kartpilot.cli.drive_commands import with_default_speed_mode
from kartpilot.cli.values import report_left_out
from kartpilot.control.lane_follow import LaneFollowState, heading_follow_step, lane_follow_step
from kartpilot.core.errors import ConfigError, DataError
from kartpilot.core.files import write_csv_atomic, write_text_atomic
from kartpilot.core.geometry import mount_pose, transform_points
from kartpilot.core.trajectory import Trajectory, read_trajectory, write_trajectory
from kartpilot.core.types import FrameSet
from kartpilot.core.vehicle import get_vehicle
from kartpilot.eval.disparity import bad_pixel_rate, disparity_search_range_px, load_middlebury_pair
from kartpilot.eval.plots import plot_trajectories
from kartpilot.eval.steering import steer_agreement
from kartpilot.eval.trajectory_metrics import evaluate_trajectory
from kartpilot.odometry.mono_localizer import MonoLocalizer
from kartpilot.odometry.mono_vo import MonoVO
from kartpilot.odometry.places import load_places
from kartpilot.odometry.run import run_mono_localizer, run_vo
from kartpilot.odometry.stereo_vo import VO_STAGES, StereoVO
from kartpilot.odometry.vo import VisualOdometry, VOStep
from kartpilot.perception.continuity import with_scene_starts
from kartpilot.perception.lanes import LaneObservation, LaneStages, detect_lanes, draw_lanes
from kartpilot.perception.stereo import BlockMatchConfig, compute_disparity
from kartpilot.perception.tape import detect_tape_track, draw_tape_track
from kartpilot.record.recording import RecordingStereoSource
from kartpilot.record.replay import VIDEO_SUFFIXES, open_frames
from kartpilot.record.video import VideoFile
from kartpilot.runtime.config import load_stack_config, sim_lane_preset
from kartpilot.runtime.faults import SOURCE_FAULTS, parse_injection
from kartpilot.runtime.scenarios import run_scenario
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import SimRun, run_simulation
from kartpilot.sensors.base import StereoSource, read_ahead
from kartpilot.sensors.donkeycar import DonkeyTub
from kartpilot.sensors.euroc import EurocSource
from kartpilot.sensors.kitti import KittiOdometrySource
from kartpilot.sim.referee import RunResult
from kartpilot.sim.scenarios import scenario_or_file, write_scenario_file
from kartpilot.sim.simulator import perfect_camera
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource

if TYPE_CHECKING:
    from kartpilot.record.rerun_view import RerunView

__all__ = ["disparity", "evaluate", "lanes", "odometry", "simulate"]


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

    write_text_atomic(path, json.dumps(clean(data), indent=2) + "\n")


def _vo_for(args: argparse.Namespace, source: StereoSource) -> VisualOdometry:
    """Stereo VO, or with ``--mono`` monocular VO on the left camera scaled by the given camera height."""
    stack = load_stack_config(args.config)
    if not getattr(args, "mono", False):
        return StereoVO(source.rig, stack.stereo_vo)
    if args.camera_height is None:
        raise ConfigError("--mono needs --camera-height METRES (the camera's height above the road; 1.65 on KITTI): "
                          "the metric scale comes from the ground plane, never from the ground truth")
    config = replace(stack.mono_vo, ground=replace(stack.mono_vo.ground, camera_height_m=args.camera_height))
    return MonoVO(source.rig.camera, config)


def _place_localised(args: argparse.Namespace, source: StereoSource) -> tuple[Trajectory, dict[str, Any]]:
    """The one-camera localiser (monocular VO fused with place fixes from ``--places``) over the left camera,
    mounted ``--camera-height`` above the road and pitched ``--camera-pitch-down``: the camera's poses in the
    database's frame, one per frame (before the first fix, the motion model's), and a summary."""
    if not getattr(args, "mono", False) or args.camera_height is None:
        raise ConfigError("--places needs --mono and --camera-height METRES (the camera's mount on the kart)")
    stack = load_stack_config(args.config)
    database = load_places(args.places)
    mount = mount_pose(z_m=args.camera_height, pitch_down_deg=args.camera_pitch_down)
    camera = source.rig.camera.on_body(mount)
    localizer = MonoLocalizer(camera, database, stack.mono_vo, replace(stack.drive.mono, camera=database.camera_name))
    frames = tqdm(read_ahead(source.frame_sets((database.camera_name, "right"))), total=len(source), unit="frame",
                  desc=f"mono VO + places {source.name}", disable=args.no_progress or None, leave=False)
    run = run_mono_localizer(frames, localizer, source.name)
    print(f"{len(run.trajectory)} frames, {run.placed_frames} placed on the database, {run.place_fixes} place fixes "
          f"used, {run.rejected_fixes} rejected, {run.unreadable_frames} unreadable, {run.frames_per_second:.1f} "
          f"frames/s; scale from the ground plane and the place fixes")
    return run.trajectory, {
        "mode": "mono+places", "places": str(args.places), "placed_frames": run.placed_frames,
        "place_fixes": run.place_fixes, "rejected_fixes": run.rejected_fixes,
        "unreadable_frames": run.unreadable_frames, "frames_per_second": run.frames_per_second}


def odometry(args: argparse.Namespace) -> int:
    """VO over a source: write the trajectory, print the summary and (with ground truth) the metrics."""
    source = _open_source(args)
    if getattr(args, "places", None):
        trajectory, summary = _place_localised(args, source)
        mode = "mono+places"
    else:
        vo = _vo_for(args, source)
        mode = "mono" if isinstance(vo, MonoVO) else "stereo"
        view = SessionOutputs(view=args.view).open_view({})

        last: list[VOStep] = []

        def on_frame(step: VOStep) -> None:
            bar.update(1)
            if view is not None:
                _view_vo_step(view, step, last[0] if last else None, source)
                last[:] = [step]

        def frames() -> Iterator[FrameSet | int]:
            for item in read_ahead(source.frame_sets()):  # the next frames decoded while VO runs
                if view is not None and not isinstance(item, int):
                    view.write_frames(item)
                yield item

        with tqdm(total=len(source), desc=f"{mode} VO {source.name}", unit="frame",
                  disable=args.no_progress or None, leave=False) as bar:
            try:
                run = run_vo(frames(), vo, source.name, on_frame=on_frame)
            finally:
                if view is not None:
                    truth = source.ground_truth()
                    if truth is not None:
                        view.write_groundtruth(truth)
                    view.close()
        print(run.summary())
        print("stage ms: " + ", ".join(f"{k} {v:.1f}" for k, v in run.timing_ms.items()))
        trajectory = run.trajectory
        summary = {"mode": mode, "scale_source": run.scale_source, "bridged_frames": run.bridged_frames,
                   "unreadable_frames": list(run.unreadable_frames), "frames_per_second": run.frames_per_second,
                   "stage_ms": run.timing_ms}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    write_trajectory(args.out, trajectory, args.format)
    ground_truth = source.ground_truth()
    metrics = None
    if ground_truth is not None and len(ground_truth) >= 2:
        metrics = evaluate_trajectory(ground_truth, trajectory)
        print(metrics.table())
    if args.plot:
        plot_trajectories(ground_truth, trajectory, args.plot, title=f"{source.name} ({mode})")
    print(f"trajectory written to {args.out}")
    if args.json:
        _write_json(args.json, {"source": source.name, "frames": len(trajectory), **summary,
                                "metrics": metrics.as_dict() if metrics else None})
    return 0


def _view_vo_step(view: RerunView, step: VOStep, previous: VOStep | None, source: Any) -> None:
    """One VO step in the view: the camera's position, the count each filter stage kept, and the inliers, in
    the previous left image (where they were measured) and in the world."""
    x, y, z = (float(v) for v in step.pose_world_cam[:3, 3])
    view.write_outputs(step.stamp_ns, {"pose": {"x_m": x, "y_m": y, "z_m": z, "inliers": step.inliers,
                                                "status": step.status}})
    diagnostics = getattr(step, "diagnostics", None)
    if diagnostics is None:
        return
    view.write_outputs(step.stamp_ns, {"vo": {name: getattr(diagnostics, name) for name in VO_STAGES}})
    rig = getattr(source, "rig", None)
    if previous is None or rig is None or not len(diagnostics.inlier_pixels):
        return
    pixels, depth = diagnostics.inlier_pixels, diagnostics.inlier_depths_m
    in_camera = rig.camera.rays(pixels) * depth[:, None]
    view.write_points(previous.stamp_ns, "left", pixels, transform_points(previous.pose_world_cam, in_camera))


def evaluate(args: argparse.Namespace) -> int:
    reference = read_trajectory(args.gt, args.format)
    estimate = read_trajectory(args.est, args.format)
    untimed = reference.stamps_s[-1] == len(reference) - 1 and estimate.stamps_s[-1] == len(estimate) - 1
    if len(reference) != len(estimate) and untimed:
        raise DataError(f"the estimate has {len(estimate)} poses and the ground truth {len(reference)}, and KITTI pose "
                        "files carry no timestamps to pair them by: give one pose per frame in both (kartpilot "
                        "odometry bridges unreadable frames), or TUM files with timestamps")
    metrics = evaluate_trajectory(reference, estimate)
    if metrics.poses < max(len(reference), len(estimate)):
        print(f"paired {metrics.poses} poses by timestamp, of {len(estimate)} estimated and {len(reference)} true")
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


# the sim options a scenario sets itself (its course, the kart's driver and camera), with their defaults: given with
# --scenario they would be taken and ignored
_SCENARIO_SETS = {"track": None, "driver": "centerline", "speed_mode": None, "commands": None, "laps": None,
                  "speed": None, "weave": None, "edge_offset": None, "rate": None, "cameras": None,
                  "perfect_camera": False, "no_cones": False, "no_render": False}


def _scenario(args: argparse.Namespace) -> int:
    """One of the event's scenarios on one seed, closed loop, scored by its referee."""
    ignored = [f"--{k.replace('_', '-')}" for k, default in _SCENARIO_SETS.items() if getattr(args, k) != default]
    if ignored:
        raise ConfigError(f"--scenario sets its own course, driver and camera: {', '.join(ignored)} would be ignored "
                          "(drop it, or write it into a scenario file: docs/scenarios.md)")
    stack = load_stack_config(args.config, args.preset or "kart")
    outputs = SessionOutputs(args.record, args.result, args.video, progress=not args.no_progress, view=args.view)
    outputs.check()
    plan = scenario_or_file(args.scenario, args.seed)
    if args.save_scenario:
        print(f"scenario written to {write_scenario_file(args.save_scenario, plan)}")
    vehicle = args.vehicle or "sdc-kart"
    if vehicle not in ("sdc-kart", "sdc-kart-2026"):
        raise ConfigError(f"--scenario drives the SDC kart: --vehicle sdc-kart or sdc-kart-2026, not {vehicle}")
    injections = [parse_injection(text) for text in args.inject or []]
    wrong = [i.kind for i in injections if i.kind not in SOURCE_FAULTS]
    if wrong:
        raise ConfigError(f"--inject {wrong[0]}: a scenario takes the faults of what the kart sees "
                          f"({', '.join(SOURCE_FAULTS)}); drive --sim takes the others")
    result = run_scenario(plan, None, stack, outputs=outputs, vehicle=vehicle, injections=injections)
    if args.record:
        print(f"recorded to {args.record} (kartpilot replay {args.record} --pipeline lanes gives the same decisions)")
    verdict = "passed" if result["passed"] else "failed: " + "; ".join(result["faults"])
    print(f"scenario {result['name']}, seed {result['seed']}: {verdict}")
    for at_s, why in result.get("lidar", []):
        print(f"  LiDAR at {at_s:.2f} s: {why}" + ("" if why == "recovered" else " (the rules went on camera-only)"))
    for label, path in (("video", args.video), ("result", args.result),
                        ("Rerun view", args.view if args.view != "live" else None)):
        if path:
            print(f"{label} written to {path}")
    return 0 if result["passed"] else 1


def simulate(args: argparse.Namespace) -> int:
    if args.scenario:
        return _scenario(args)
    if args.inject:
        raise ConfigError("sim --inject works with --scenario (drive --sim takes every fault)")
    if args.commands is not None and args.driver != "commands":
        raise ConfigError(f"--commands is what --driver commands replays: with --driver {args.driver} it would be "
                          "ignored")
    stack = load_stack_config(args.config)
    config, driver = stack.sim, stack.centerline_driver
    overrides = {"track": args.track, "vehicle": args.vehicle, "seed": args.seed, "camera_rate_hz": args.rate}
    config = replace(config, **{k: v for k, v in overrides.items() if v is not None})
    if args.driver == "lanes":  # the track's lane preset unless one is asked for; the config file over it
        stack = load_stack_config(args.config, sim_lane_preset(args.preset, config.track))
    if args.cameras:
        config = replace(config, cameras=tuple(c.strip() for c in args.cameras.split(",") if c.strip()))
    if args.perfect_camera:
        config = replace(config, effects=perfect_camera())
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
    if args.speed_mode is not None:
        config = replace(config, speed_mode_mps=args.speed_mode / 3.6)
    config = with_default_speed_mode(config, args.driver)
    top = get_vehicle(config.vehicle).top_speed_mps
    if args.speed is not None and args.speed > top:
        raise ConfigError(f"--speed {args.speed:g} m/s is above the {config.vehicle}'s top speed, {top:.1f} m/s")
    run = run_simulation(config, args.driver, driver, args.commands, stack, outputs=SessionOutputs(
        args.record, args.result, args.video, progress=not args.no_progress, view=args.view))
    _print_result(run.result, run)
    for label, path in (("recording", args.record), ("video", args.video), ("result", args.result),
                        ("Rerun view", args.view if args.view != "live" else None)):
        if path:
            print(f"{label} written to {path}")
    return 0


CURVE_ROWS = (0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
"""Rows (fractions of the height; 1.0 is the last row) at which the CSV gives each curved boundary's column."""
LANE_COLUMNS = ("frame", "file", "left_x1", "left_y1", "left_x2", "left_y2", "right_x1", "right_y1", "right_x2",
                "right_y2", "left_source", "right_source", "steer", "confidence", "horizon_y",
                "left_a", "left_b", "left_c", "right_a", "right_b", "right_c",
                *(f"{side}_x_at_{round(100 * r)}pct" for side in ("left", "right") for r in CURVE_ROWS), "new_scene")
TAPE_COLUMNS = ("frame", "file", "target_bearing_rad", "target_x_m", "target_z_m", "steer", "confidence",
                "new_scene")


def _curve_cells(observation: LaneObservation) -> list[object]:
    """The horizon row, each side's curve coefficients and its columns at ``CURVE_ROWS`` (empty where none)."""
    curves = (observation.left_curve, observation.right_curve)
    horizon = next((c.horizon_y for c in curves if c is not None), None)
    cells: list[object] = ["" if horizon is None else f"{horizon:.2f}"]
    for curve in curves:
        cells += ["", "", ""] if curve is None else [f"{curve.a:.6g}", f"{curve.b:.6g}", f"{curve.c:.6g}"]
    rows = [r * (observation.height_px - 1) for r in CURVE_ROWS]
    for curve in curves:
        cells += [""] * len(rows) if curve is None else [f"{float(curve.x_at(y)):.1f}" for y in rows]
    return cells


def _centre_body_mask(rig_path: str) -> Callable[[np.ndarray], np.ndarray | None]:
    """For each image, the rig's centre camera's body mask at that image's size."""
    camera = load_rig(rig_path).camera("center")
    masks: dict[tuple[int, int], np.ndarray | None] = {}

    def mask(image: np.ndarray) -> np.ndarray | None:
        h, w = image.shape[:2]
        if (w, h) not in masks:
            masks[(w, h)] = camera.body_mask_image(w, h)
        return masks[(w, h)]

    return mask


def lanes(args: argparse.Namespace) -> int:
    """Lane boundaries (or, on a taped track, the target on the track) per frame to CSV (steer in radians,
    positive left), with optional overlays; on a Donkey Car tub, the agreement of the steer with the human
    driver's, at the tub's own rate. Frames that do not follow from the one before (a folder of photos of
    different places; ``--independent``: every frame) start afresh: the follower's state is not carried."""
    stack = load_stack_config(args.config, args.preset)
    policy = stack.lane_policy
    body_mask = _centre_body_mask(args.rig) if args.rig else None
    left_out: list[str] = []
    kind, frames = open_frames(args.input, left_out=left_out)
    tub = DonkeyTub(args.input) if kind == "donkeycar-tub" else None
    rate_hz = tub.rate_hz if tub is not None else 30.0
    state = LaneFollowState()
    overlay = _Overlay(args.overlay) if args.overlay else None
    steers: list[float] = []
    rows: list[list[object]] = []
    cuts = 0
    try:
        for frame_set, new_scene in with_scene_starts(frames, args.independent):
            image = frame_set.images["center"]
            if new_scene:
                state = LaneFollowState()
                cuts += 1
            row: list[object] = [frame_set.index, frame_set.name]
            if policy.boundaries == "tape":
                tape = detect_tape_track(image, policy.tape)
                decision, state = heading_follow_step(policy.follow, state, tape.seen_bearing_rad, 1 / rate_hz)
                row += [f"{tape.bearing_rad:.5f}", f"{tape.target_m[0]:.4f}", f"{tape.target_m[1]:.4f}"
                        ] if tape.any_detected else ["", "", ""]
                row += [f"{decision.steer_rad:.5f}", f"{tape.confidence:.3f}", int(new_scene)]
                drawn = draw_tape_track(image, tape, decision.steer_rad) if overlay is not None else None
            else:
                stages = LaneStages() if args.stages else None
                mask = body_mask(image) if body_mask is not None else None
                observation = detect_lanes(image, policy.lanes, stages, mask)
                decision, state = lane_follow_step(policy.follow, state, observation, dt_s=1 / rate_hz)
                for line, source in ((observation.left, observation.left_source),
                                     (observation.right, observation.right_source)):
                    row += [f"{v:.1f}" for v in line.as_tuple()] if source == "detected" else ["", "", "", ""]
                row += [observation.left_source, observation.right_source, f"{decision.steer_rad:.5f}",
                        f"{observation.confidence:.3f}", *_curve_cells(observation), int(new_scene)]
                drawn = draw_lanes(image, observation, decision.steer_rad, stages) if overlay is not None else None
            steers.append(decision.steer_rad)
            rows.append(row)
            if overlay is not None and drawn is not None:
                overlay.write(frame_set.index, drawn)
    finally:
        if overlay is not None:
            overlay.close()
    write_csv_atomic(args.out, TAPE_COLUMNS if policy.boundaries == "tape" else LANE_COLUMNS, rows)
    scenes = f", {cuts} scenes" if cuts > 1 else ""
    print(f"{len(steers)} frames ({kind}{scenes}) -> {args.out}")
    if tub is not None:
        angles = np.array([r.angle for r in tub.records])
        # Donkey Car's angle is positive to the right, kartpilot's steer to the left
        report = steer_agreement(-np.asarray(steers), angles, rate_hz)
        print(f"steer vs the human's user/angle smoothed over 0.5 s: correlation {report.correlation:.3f}, sign "
              f"agreement {100 * report.sign_agreement:.1f} % over the {report.turning_frames} frames where the "
              "human clearly turns (smoothed beyond 0.3)")
    return report_left_out(left_out, args.out)


class _Overlay:
    def __init__(self, target: str | Path) -> None:
        self.path = Path(target)
        self.video: VideoFile | None = None
        if self.path.suffix.lower() not in VIDEO_SUFFIXES:
            self.path.mkdir(parents=True, exist_ok=True)

    def write(self, index: int, image: np.ndarray) -> None:
        if self.path.suffix.lower() in VIDEO_SUFFIXES:
            if self.video is None:
                h, w = image.shape[:2]
                self.video = VideoFile(self.path, 30.0, (w, h))
            if image.shape[:2] != (self.video.size_wh[1], self.video.size_wh[0]):
                image = cv2.resize(image, self.video.size_wh)
            self.video.write(image)
        else:
            cv2.imwrite(str(self.path / f"{index:06d}.png"), image)

    def close(self) -> None:
        if self.video is not None:
            self.video.close()

"""Subcommands of the waypoint-following pipeline: ``reference``, ``drive`` and ``experiment``."""

from __future__ import annotations

import argparse
import contextlib
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from kartpilot.calibration.rig import load_rig
from kartpilot.control.path_follow import steer_bias_of_drive
from kartpilot.core.config import merge_config
from kartpilot.core.errors import ConfigError, KartpilotError, RecordingError
from kartpilot.core.geometry import ground_poses
from kartpilot.core.vehicle import VehicleParams, get_vehicle
from kartpilot.odometry.places import load_places
from kartpilot.odometry.run import run_teach
from kartpilot.odometry.visual_map import VisualMap, load_visual_map, map_path_for
from kartpilot.planning.reference_path import (
    ReferencePath,
    build_reference_path,
    load_reference_path,
    save_reference_path,
)
from kartpilot.record.recording import RecordingReader, RecordingStereoSource
from kartpilot.runtime.config import StackConfig, load_stack_config, sim_lane_preset
from kartpilot.runtime.experiment import TeachRepeatConfig, run_teach_repeat, summary_line
from kartpilot.runtime.faults import parse_injection
from kartpilot.runtime.lane_policy import lane_speed_mode_mps
from kartpilot.runtime.live_drive import LiveDriveSetup, run_live_drive
from kartpilot.runtime.pipelines import Route
from kartpilot.runtime.replay import replay_recording
from kartpilot.runtime.session import SessionOutputs, SessionResult
from kartpilot.runtime.simulate import run_supervised_drive
from kartpilot.sim.simulator import SimConfig, perfect_camera

__all__ = ["drive", "experiment", "reference", "replay"]


def _stereo_vehicle(name: str) -> tuple[VehicleParams, tuple[str, str]]:
    vehicle = get_vehicle(name)
    if vehicle.stereo_pair is None:
        raise ConfigError(f"the {vehicle.name} has no stereo pair: the stereo-VO pipeline needs one (rc-kart)")
    return vehicle, vehicle.stereo_pair


def reference(args: argparse.Namespace) -> int:
    """A reference path (and, from VO, its visual map) from a recorded drive."""
    stack = load_stack_config(args.config)
    vehicle, _ = _stereo_vehicle(args.vehicle)
    source = RecordingStereoSource(args.recording)
    body_cam = source.pose_body_left  # the recording's own rig: where its left camera sat on the kart
    path_config = stack.drive.path if args.speed is None else replace(stack.drive.path, cruise_speed_mps=args.speed)
    out = Path(args.out)
    if args.source == "vo":
        run, visual_map = run_teach(source, body_cam, stack.stereo_vo, stack.drive.map)
        print(f"stereo VO: {run.summary()}")
        poses = run.trajectory.poses
        stamps_ns = np.array([e.stamp_ns for e in run.estimates], np.int64)
    else:
        truth = source.reader.groundtruth()
        if truth is None:
            raise RecordingError(f"{args.recording} has no ground truth (only simulator recordings do)")
        poses, visual_map = truth.poses, None
        stamps_ns = np.round(np.asarray(truth.stamps_s) * 1e9).astype(np.int64)
    ground = ground_poses(poses, body_cam)
    path = build_reference_path(ground[:, :2], path_config)
    save_reference_path(path, out)
    commands = source.reader.commands()
    if commands:
        bias = steer_bias_of_drive(path, ground, stamps_ns, np.array([c.stamp_ns for c in commands]),
                                   np.array([c.steer_rad for c in commands]), vehicle.wheelbase_m)
        print(f"the drive shows a steering pull of {bias:+.3f} rad (positive left); to start from it, set "
              f"drive: {{follow: {{bias: {{initial_rad: {bias:.3f}}}}}}}")
    print(f"reference: {len(path)} waypoints over {path.length_m:.1f} m, speed {path.speed_mps.min():.2f} to "
          f"{path.speed_mps.max():.2f} m/s, written to {out}")
    if visual_map is not None:
        target = visual_map.save(map_path_for(out))
        print(f"visual map: {len(visual_map)} keyframes, written to {target}")
    return 0


def _visual_map(args: argparse.Namespace) -> VisualMap | None:
    if args.no_map:
        return None
    if args.map:
        return load_visual_map(args.map)
    default = map_path_for(args.reference)
    if default.is_file():
        return load_visual_map(default)
    print(f"no visual map at {default}: localising with VO alone (it drifts; build the reference from VO "
          "to get a map)")
    return None


def with_default_speed_mode(config: SimConfig, pipeline: str) -> SimConfig:
    """The lanes pipeline on the sdc-kart, with no speed mode asked for: its default mode, said."""
    mode = lane_speed_mode_mps(pipeline, config.vehicle, config.speed_mode_mps)
    if mode != config.speed_mode_mps:
        print(f"speed mode {mode * 3.6:g} km/h: the lane pipeline's default, the fastest it finished simulated "
              "laps at (docs/lanes.md; --speed-mode to choose)")
    return replace(config, speed_mode_mps=mode)


def _drive_vehicle(args: argparse.Namespace) -> VehicleParams:
    if args.pipeline == "stereo-vo":
        return _stereo_vehicle(args.vehicle or "rc-kart")[0]
    return get_vehicle(args.vehicle or "sdc-kart")


def drive(args: argparse.Namespace) -> int:
    """A supervised drive of any pipeline: in the simulator (through the CAN layer), on a replayed recording
    (open loop, told what the kart measured), or on the real kart."""
    # the real kart's preset on a real drive or its recording; in the simulator, the track's own
    preset = sim_lane_preset(args.preset, args.sim) if args.sim else args.preset or "kart"
    stack = load_stack_config(args.config, preset)
    vehicle = _drive_vehicle(args)
    path: ReferencePath | None = None
    visual_map = None
    places = None
    if args.pipeline == "mono-vo":  # without --places, the pipeline's factory says what is missing
        places = load_places(args.places) if args.places else None
        path = load_reference_path(args.reference) if args.reference else None
    if args.pipeline == "stereo-vo":
        if not args.reference:
            raise ConfigError("the stereo-vo pipeline follows a reference: give --reference (kartpilot reference "
                              "writes one from a recorded drive)")
        path = load_reference_path(args.reference)
        visual_map = _visual_map(args)
    route = Route(path, visual_map, places)
    follow = stack.drive.follow if args.speed is None else replace(stack.drive.follow, max_speed_mps=args.speed)
    drive_config = replace(stack.drive, follow=follow)
    if args.inject and not args.sim:
        raise ConfigError("--inject works with --sim only: a replay or a live drive has no fault to inject")
    if args.sim:
        cameras = {"stereo-vo": vehicle.stereo_pair or (), "mono-vo": (stack.drive.mono.camera,)}.get(
            args.pipeline, stack.sim.cameras)
        overrides = {"track": args.sim, "vehicle": vehicle.name, "seed": args.seed, "camera_rate_hz": args.rate,
                     "speed_mode_mps": args.speed_mode / 3.6 if args.speed_mode else None}
        sim: SimConfig = replace(stack.sim, cameras=cameras,
                                 **{k: v for k, v in overrides.items() if v is not None})
        sim = with_default_speed_mode(sim, args.pipeline)
        if args.perfect_camera:
            sim = replace(sim, effects=perfect_camera())
        if args.steer_bias is not None:
            sim = replace(sim, disturbances=replace(sim.disturbances, steer_bias_rad=args.steer_bias))
        if args.bus == "socketcan":
            raise ConfigError("the simulator sits behind the virtual bus (or none), not socketcan")
        run = run_supervised_drive(
            sim, args.pipeline, replace(stack, drive=drive_config), args.bus or "virtual", args.duration,
            [parse_injection(text) for text in args.inject or []], route,
            SessionOutputs(args.record, args.result, args.video, args.log, progress=not args.no_progress,
                           view=args.view))
        print(drive_summary(run.payload))
        if run.error is not None:
            where = f"; its traceback is in {Path(args.record) / 'error.txt'}" if args.record else ""
            raise KartpilotError(f"the pipeline failed ({run.payload['error']}); the kart was stopped{where}")
        return 0
    if args.replay:
        replayed = replay_recording(args.replay, args.pipeline, replace(stack, drive=drive_config), route,
                                    args.vehicle, SessionOutputs(args.record, args.result, drive_log=args.log,
                                                                 view=args.view))
        print(json.dumps(replayed.to_json()))
        return 0
    if args.live:
        can = stack.can
        if args.bus in ("virtual", "socketcan"):
            can = replace(can, interface=args.bus)
        if args.channel:
            can = replace(can, channel=args.channel)
        rig = load_rig(args.live)
        if args.cameras_json:
            rig = replace(rig, camera_maps=tuple(args.cameras_json))
        setup = LiveDriveSetup(rig, args.pipeline, vehicle, route, args.gamepad, args.web,
                               SessionOutputs(args.record, args.result, view=args.view), args.duration,
                               web_host=args.web_host)
        summary = run_live_drive(setup, replace(stack, can=can))
        print(json.dumps({k: summary[k] for k in ("ended", "seconds", "final_state", "error")}))
        for transition in summary["transitions"]:
            print(f"  {transition['t_s']:7.2f} s  {transition['state']:<10} {transition['reason']}")
        if summary["error"]:
            raise KartpilotError(f"the pipeline failed ({summary['error']}); the kart was stopped")
        return 0
    raise ConfigError("drive needs --sim TRACK, --replay RECORDING or --live RIG")


def drive_summary(payload: dict[str, Any]) -> str:
    """What a supervised drive did, in a few lines: verdict, supervisor, the fault's stop, timing."""
    verdict = f"DISQUALIFIED: {payload['reason']}" if payload["disqualified"] else payload["reason"]
    lines = [f"{verdict} | {payload['distance_m']:.1f} m driven, centre offset max "
             f"{payload['max_center_offset_m']:.3f} m | {payload['steps']} steps, ended: {payload['ended']}"]
    if payload.get("stop_reason"):
        lines.append(f"pipeline stopped: {payload['stop_reason']}")
    for transition in payload["transitions"]:
        lines.append(f"  {transition['t_s']:7.2f} s  {transition['state']:<10} {transition['reason']}")
    if payload["injections"]:
        stop = payload["fault_to_stop_s"]
        if not payload.get("fault_injected", True):
            lines.append("fault to stop: the drive ended before the fault was injected")
        else:
            lines.append(f"fault to stop: {stop:.3f} s (by {payload['stop_by']})" if stop is not None
                         else "fault to stop: no stop after the fault")
    lines.append(stage_lines(SessionResult.from_json(payload)))
    return "\n".join(lines)


def stage_lines(session: SessionResult) -> str:
    """The loop's stages (median, 90th and 99th percentile) and the pipeline's own (mean), in milliseconds."""
    line = "per step (ms, p50 / p90 / p99): " + ", ".join(
        f"{stage} {v['p50']:.1f} / {v['p90']:.1f} / {v['p99']:.1f}" for stage, v in session.stage_ms.items())
    if session.pipeline_stage_ms:
        line += "\npipeline stages (ms, mean): " + ", ".join(
            f"{stage} {ms:.1f}" for stage, ms in session.pipeline_stage_ms.items())
    return line


def _recorded_stack(args: argparse.Namespace) -> StackConfig:
    """The settings a recording is replayed with: ``--config`` and ``--preset`` where given; else the lane
    preset of a simulated run's track (the real kart's, ``kart``, otherwise) and, for the lane pipeline, the lane
    settings the recording names (a scenario's drive, a replay's own recording), so a replay makes the same
    decisions without a config file."""
    try:
        reader: RecordingReader | None = RecordingReader(args.recording)
    except KartpilotError:
        reader = None  # the replay itself says what is wrong with the recording
    preset = args.preset or "kart"
    if args.preset is None and reader is not None and reader.sim_track is not None:
        with contextlib.suppress(ConfigError):  # a track file no longer where it was: the real kart's
            preset = sim_lane_preset(None, reader.sim_track)
    stack = load_stack_config(args.config, preset)
    settings = ((reader.manifest.get("metadata") or {}).get("config") or {}) if reader is not None else {}
    if args.config or args.preset or args.pipeline != "lanes" or not isinstance(settings.get("lane_policy"), dict):
        return stack
    print("settings: the recording's own (its manifest's lane_policy; --config to replay with others)")
    return merge_config(stack, {"lane_policy": settings["lane_policy"]})


def replay(args: argparse.Namespace) -> int:
    """A recording through a pipeline; its commands and outputs written as a new recording."""
    stack = _recorded_stack(args)
    path = load_reference_path(args.reference) if args.reference else None
    visual_map = _visual_map(args) if path is not None and args.pipeline == "stereo-vo" else None
    places = load_places(args.places) if args.places and args.pipeline == "mono-vo" else None
    if args.pipeline == "stereo-vo" and args.vehicle:
        _stereo_vehicle(args.vehicle)
    result = replay_recording(args.recording, args.pipeline, stack, Route(path, visual_map, places), args.vehicle,
                              SessionOutputs(record_dir=args.out, drive_log=args.log, view=args.view),
                              realtime=args.realtime,
                              with_frames=args.with_frames)
    steer = np.array([c.steer_rad for c in result.commands])
    braking = np.mean([c.brake > 0 for c in result.commands]) if result.commands else 0.0
    details = result.session.details
    stop = f", stopped: {details['stop_reason']}" if details.get("stop_reason") else ""
    print(f"{args.pipeline}: {result.steps} sets at {details['rate_hz']:.1f} Hz, {details['unreadable_frames']} "
          f"unreadable frames, steer {steer.min(initial=0.0):+.3f} to {steer.max(initial=0.0):+.3f} rad, braking "
          f"{100 * braking:.0f} % of the time{stop}")
    print(stage_lines(result.session))
    if result.out is not None:
        print(f"wrote {result.out} (commands, outputs/, replay.json)")
    return 0


def experiment(args: argparse.Namespace) -> int:
    """``teach-repeat``: teach, build the reference with VO, repeat, score."""
    stack = load_stack_config(args.config)
    config = TeachRepeatConfig(track=args.track, speed_mps=args.speed, seed=args.seed, camera_rate_hz=args.rate,
                            steer_bias_rad=args.steer_bias, use_map=not args.no_map, controller=args.controller,
                            drive=stack.drive,
                            vo=stack.stereo_vo, effects=stack.sim.effects)
    result = run_teach_repeat(config, args.out, progress=not args.no_progress, video=not args.no_video)
    print(summary_line(result))
    print(f"wrote {Path(args.out) / 'result.json'}, path.png, steering.png")
    return 0

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
from kartpilot.cli.values import VIEW_HELP, new_folder, number, output_file, view_target
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
from kartpilot.runtime.lane_policy import LANE_PRESETS, lane_speed_mode_mps
from kartpilot.runtime.live_drive import LiveDriveSetup, run_live_drive
from kartpilot.runtime.pipelines import PIPELINES, Route
from kartpilot.runtime.replay import replay_recording
from kartpilot.runtime.session import SessionOutputs, SessionResult
from kartpilot.runtime.simulate import run_supervised_drive
from kartpilot.sim.simulator import SimConfig

__all__ = ["add_parsers", "drive", "experiment", "reference", "replay"]


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
                               SessionOutputs(args.record, args.result, view=args.view), args.duration)
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
                            vo=stack.stereo_vo)
    result = run_teach_repeat(config, args.out, progress=not args.no_progress, video=not args.no_video)
    print(summary_line(result))
    print(f"wrote {Path(args.out) / 'result.json'}, path.png, steering.png")
    return 0


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """This module's subcommands, each with its arguments and handler."""
    ref = sub.add_parser("reference", help="a reference path (and visual map) from a recorded drive")
    ref.add_argument("recording", help="a kartpilot recording with a stereo pair")
    ref.add_argument("--out", required=True, type=output_file,
                     help="the path file (.csv or .yaml); the map goes beside it")
    ref.add_argument("--from", dest="source", choices=("vo", "groundtruth"), default="vo",
                     help="vo: stereo VO over the recording, with a visual map (default); groundtruth: the "
                          "simulator's poses")
    ref.add_argument("--vehicle", default="rc-kart", help="the kart (its wheelbase); camera mounts come from the "
                     "recording's rig")
    ref.add_argument("--speed", type=number(above=0), help="cruise speed of the path's speed profile, m/s")
    ref.add_argument("--config", help="YAML file merged over the defaults (sections stereo_vo, drive)")
    ref.set_defaults(handler=reference)

    drive_parser = sub.add_parser("drive", help="a supervised drive of any pipeline: simulated, replayed or live")
    drive_parser.add_argument("--vehicle", help="rc-kart or sdc-kart (default: sdc-kart for lanes, rc-kart for "
                                                "stereo-vo)")
    drive_parser.add_argument("--pipeline", choices=tuple(PIPELINES), default="stereo-vo",
                              help="lanes; stereo-vo (--reference); mono-vo: one camera, monocular VO fused with "
                                   "place fixes (--places)")
    drive_parser.add_argument("--places", help="mono-vo: the place database of the reference drive (kartpilot places "
                                               "build); its drive is the reference unless --reference is given")
    drive_parser.add_argument("--reference", help="stereo-vo: a path written by 'kartpilot reference'")
    where = drive_parser.add_mutually_exclusive_group()
    where.add_argument("--sim", metavar="TRACK", help="drive in the simulator on this track")
    where.add_argument("--replay", metavar="RECORDING", help="run the pipeline on a recording (open loop)")
    where.add_argument("--live", metavar="RIG", help="drive the real kart: the rig file's cameras, the CAN bus of "
                                                     "the config's can section (or --bus, --channel)")
    drive_parser.add_argument("--preset", choices=tuple(LANE_PRESETS),
                              help="lanes: the lane pipeline's preset (default: kart; --sim: the track's own)")
    drive_parser.add_argument("--bus", choices=("virtual", "socketcan", "none"),
                              help="--sim: virtual (default: the simulated ECUs behind python-can's virtual bus) or "
                                   "none; --live: socketcan or virtual (default: the config's can.interface)")
    drive_parser.add_argument("--channel", help="--live: the CAN channel (can0; vcan0 for a bench test)")
    drive_parser.add_argument("--cameras-json", nargs="+", metavar="JSON",
                              help="--live: the organiser's camera-mapping files (front, left, right to device "
                                   "paths); the first whose paths all exist wins (default: the rig file's camera_maps)")
    drive_parser.add_argument("--gamepad", metavar="DEVICE", help="--live: the gamepad's joystick device "
                                                                  "(/dev/input/js0)")
    drive_parser.add_argument("--web", metavar="PORT", type=number(int, minimum=1, maximum=65535),
                              help="--live: serve the kart's web page on this port")
    drive_parser.add_argument("--duration", type=number(above=0), help="--sim, --live: seconds to drive at most")
    drive_parser.add_argument("--inject", action="append", metavar="KIND@SECONDS",
                              help="--sim: inject a fault (camera-freeze, black-frame, vo-failure, can-bus-off, "
                                   "heartbeat-loss, ecu-error, steering-sensor-loss, steering-sensor-range, "
                                   "loop-stall, gamepad-unplug, stage-exception); repeatable")
    drive_parser.add_argument("--map", help="the visual map (default: the reference's .map.npz, if there)")
    drive_parser.add_argument("--no-map", action="store_true", help="localise with VO alone")
    drive_parser.add_argument("--speed", type=number(above=0), help="stereo-vo: cap the path's speed profile, m/s")
    drive_parser.add_argument("--speed-mode", type=number(above=0),
                              help="--sim: cap the top speed, km/h (the SDC kart's modes)")
    drive_parser.add_argument("--seed", type=number(int, minimum=0))
    drive_parser.add_argument("--rate", type=number(above=0, maximum=1000),
                              help="camera and control rate, Hz (--sim; a replay keeps its own)")
    drive_parser.add_argument("--steer-bias", type=number(), help="the simulated kart's drag to one side, rad (+ left)")
    drive_parser.add_argument("--record", type=new_folder,
                              help="record the drive here (frames, commands, outputs, CAN)")
    drive_parser.add_argument("--video", type=output_file,
                              help="write the camera view with the referee's state here (MP4)")
    drive_parser.add_argument("--result", type=output_file,
                              help="write the result JSON here (transitions, fault_to_stop_s, timing)")
    drive_parser.add_argument("--view", type=view_target, help=VIEW_HELP)
    drive_parser.add_argument("--log", type=output_file,
                              help="stereo-vo, mono-vo: write the pipeline's per-step log here (CSV)")
    drive_parser.add_argument("--config", help="YAML file merged over the defaults (sections sim, lane_policy, "
                                               "stereo_vo, drive, can, watchdogs, supervisor)")
    drive_parser.add_argument("--no-progress", action="store_true")
    drive_parser.set_defaults(handler=drive)

    rep = sub.add_parser("replay", help="push a recording through a pipeline; write its outputs as a recording")
    rep.add_argument("recording")
    rep.add_argument("--pipeline", choices=tuple(PIPELINES), required=True)
    rep.add_argument("--out", type=new_folder, help="the new recording: commands, the pipeline's outputs, replay.json")
    rep.add_argument("--realtime", action="store_true", help="at the recorded pace (default: as fast as possible)")
    rep.add_argument("--with-frames", action="store_true", help="copy the frames into the new recording too")
    rep.add_argument("--reference", help="stereo-vo, mono-vo: the path to follow (written by 'kartpilot reference'; "
                                         "mono-vo: default the place database's drive)")
    rep.add_argument("--places", help="mono-vo: the place database of the reference drive (kartpilot places build)")
    rep.add_argument("--log", type=output_file, help="stereo-vo, mono-vo: write the pipeline's per-step log here (CSV)")
    rep.add_argument("--view", type=view_target, help=VIEW_HELP)
    rep.add_argument("--map", help="stereo-vo: the visual map (default: the reference's .map.npz, if there)")
    rep.add_argument("--no-map", action="store_true", help="stereo-vo: localise with VO alone")
    rep.add_argument("--vehicle", help="the kart (wheelbase, steering range; default: the one the recording was made "
                                       "on)")
    rep.add_argument("--preset", choices=tuple(LANE_PRESETS),
                     help="lanes: the kind of track and camera (kart: the real kart's road lines, the default; "
                          "a simulated run's default is its track's; dashcam: a car's; tape: a small car's "
                          "wide-angle camera on a taped track)")
    rep.add_argument("--config", help="YAML file merged over the defaults")
    rep.set_defaults(handler=replay)

    experiment_parser = sub.add_parser("experiment", help="reproduce an experiment of the thesis in the simulator")
    experiment_parser.add_argument("name", choices=("teach-repeat",),
                                   help="teach-repeat: teach, build the reference with stereo VO, repeat, score")
    experiment_parser.add_argument("--track", default="straight20")
    experiment_parser.add_argument("--speed", type=number(above=0), default=0.62, help="m/s")
    experiment_parser.add_argument("--seed", type=number(int, minimum=0), default=1)
    experiment_parser.add_argument("--rate", type=number(above=0, maximum=1000), default=15.0,
                                   help="camera and control rate, Hz")
    experiment_parser.add_argument("--steer-bias", type=number(), default=0.03, help="the kart's drag to one side, rad")
    experiment_parser.add_argument("--no-map", action="store_true", help="localise with VO alone, as the thesis did")
    experiment_parser.add_argument("--controller", choices=("tuned", "plain_stanley"), default="tuned",
                                   help="plain_stanley: the pipeline as the thesis ran it, for comparison")
    experiment_parser.add_argument("--no-video", action="store_true")
    experiment_parser.add_argument("--out", required=True)
    experiment_parser.add_argument("--config", help="YAML file merged over the defaults (sections stereo_vo, drive)")
    experiment_parser.add_argument("--no-progress", action="store_true")
    experiment_parser.set_defaults(handler=experiment)

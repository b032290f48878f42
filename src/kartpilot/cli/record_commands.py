"""``kartpilot record`` (the live cameras to a recording) and ``kartpilot recordings`` (what a recording holds)."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict

from kartpilot.actuation.can_bus import protocol_database
from kartpilot.calibration.rig import apply_camera_maps, load_rig
from kartpilot.core.config import load_yaml_mapping, merge_config
from kartpilot.core.geometry import mount_pose
from kartpilot.core.vehicle import get_vehicle
from kartpilot.record.convert import export_recording, import_donkey_tub, import_stereo_source
from kartpilot.record.info import recording_info
from kartpilot.record.live import record_live
from kartpilot.record.mcap_export import export_mcap
from kartpilot.record.recording import RecordingReader, RecordingWriter
from kartpilot.record.rosbag import BagImportConfig, export_ros2_bag, import_bag
from kartpilot.runtime.config import load_stack_config
from kartpilot.sensors.capture import LiveFrameSource
from kartpilot.sensors.kitti import KittiOdometrySource

__all__ = ["record", "recordings_export", "recordings_import_bag", "recordings_import_kitti",
           "recordings_import_tub", "recordings_info", "view"]

RECORD_QUEUE_FRAMES = 16  # per camera: half a second at 30 fps before frames are dropped (and counted)


def record(args: argparse.Namespace) -> int:
    """Record the rig's live cameras until the duration is up or Ctrl-C."""
    stack = load_stack_config(args.config)
    rig = apply_camera_maps(load_rig(args.rig), args.cameras_json or ())
    cameras = args.cameras.split(",") if args.cameras else None
    source = LiveFrameSource(rig, stack.live, cameras).start()
    names = list(source.threads)
    try:
        writer = RecordingWriter(args.out, {n: rig.cameras[n] for n in names},
                                 stereo_pair=rig.stereo_pair if rig.stereo_pair and set(rig.stereo_pair) <= set(names)
                                 else None,
                                 metadata={"source": "kartpilot record", "rig_file": str(args.rig),
                                           "capture": {n: asdict(rig.capture[n]) for n in names}},
                                 queue_frames=RECORD_QUEUE_FRAMES, drop_when_full=True,
                                 image_format=args.image_format)
    except BaseException:
        source.close()
        raise
    print(f"recording {', '.join(names)} to {args.out}" + (f" for {args.duration:g} s" if args.duration else
                                                            " (Ctrl-C to stop)"))
    stats = record_live(source, writer, args.duration)
    skew = stats["skew_ms"]
    print(f"{stats['stopped']} after {stats['seconds']:.1f} s: {stats['sets']} sets, {stats['incomplete_sets']} "
          "incomplete" + (f", skew {skew['median']:.1f} ms median / {skew['max']:.1f} ms max" if skew else ""))
    for name in names:
        camera = stats["cameras"][name]
        print(f"  {name}: {stats['written'][name]} frames written, {stats['dropped'][name]} dropped by the recorder, "
              f"{stats['missing'][name]} sets without it, "
              f"{camera['failures']} read failures, {camera['reopens']} reopened"
              + (f"; {stats['problems'][name]}" if name in stats["problems"] else ""))
    return 0


def recordings_info(args: argparse.Namespace) -> int:
    info = recording_info(RecordingReader(args.recording))
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    state = "closed properly" if info["closed"] else "NOT closed properly (cut off; everything flushed is kept)"
    if info.get("write_error"):
        state = f"NOT closed properly: its writing failed ({info['write_error']}); everything written is kept"
    print(f"{info['folder']}: {info['duration_s']:.2f} s, {state}")
    for name, camera in info["cameras"].items():
        skew = next((f", skew to {k[8:-3]} {v['median']:.2f} ms median / {v['max']:.2f} ms max"
                     for k, v in camera.items() if k.startswith("skew_to_")), "")
        print(f"  camera {name}: {camera['frames']} frames at {camera['rate_hz']} Hz, "
              f"{camera['dropped']} dropped by the recorder, {camera['missing']} sets without it{skew}")
    commands = info["commands"]
    if commands["count"]:
        steer = commands["steer_rad"]
        print(f"  commands: {commands['count']} at {commands['rate_hz']} Hz, steer {steer['min']:+.3f} to "
              f"{steer['max']:+.3f} rad (mean {steer['mean']:+.3f}), throttle mean {commands['throttle_mean']:.2f}, "
              f"braking {100 * commands['braking_fraction']:.0f} % of the time")
    else:
        print("  commands: none")
    if info["outputs"]:
        print("  pipeline outputs: " + ", ".join(f"{topic} ({rows} rows)" for topic, rows in info["outputs"].items()))
    if info["can_frames"]:
        print(f"  CAN frames: {info['can_frames']}")
    if info["dropped_lines"]:
        print(f"  lines dropped from the recording (queue full): {info['dropped_lines']}")
    print(f"  ground truth: {'yes' if info['has_groundtruth'] else 'no'}; stereo pair: {info['stereo_pair']}")
    return 0


def recordings_import_tub(args: argparse.Namespace) -> int:
    """A Donkey Car tub as a kartpilot recording."""
    camera = None
    if args.rig:
        rig = load_rig(args.rig)
        camera = rig.camera(args.camera) if args.camera else next(iter(rig.cameras.values()))
    frames = import_donkey_tub(args.tub, args.out, camera, args.fov_deg, math.radians(args.max_steer_deg))
    how = f"camera from {args.rig}" if args.rig else f"intrinsics guessed from a {args.fov_deg:g} deg field of view"
    print(f"imported {frames} frames and commands from {args.tub} into {args.out} ({how})")
    return 0


def recordings_import_kitti(args: argparse.Namespace) -> int:
    """A KITTI odometry sequence as a kartpilot recording, the left camera at the given mount."""
    source = KittiOdometrySource(args.root, args.sequence)
    mount = mount_pose(z_m=args.camera_height, pitch_down_deg=args.camera_pitch_down)
    frames = import_stereo_source(source, args.out, mount)
    skipped = f", {len(source) - frames} unreadable frames left out" if frames < len(source) else ""
    print(f"imported {frames} stereo frames of {source.name} into {args.out} (left camera "
          f"{args.camera_height:g} m above the road, pitched {args.camera_pitch_down:g} deg down{skipped})")
    return 0


def recordings_export(args: argparse.Namespace) -> int:
    """A recording as a folder of images plus one CSV, or as one MCAP file for Foxglove."""
    cameras, out = args.cameras.split(",") if args.cameras else None, args.out
    if args.format == "mcap":
        counts = export_mcap(args.recording, out, cameras)
        print(f"exported {sum(counts.values())} messages on {len(counts)} topics to {out} (MCAP; Foxglove opens it)")
        return 0
    if args.format == "ros2":
        counts = export_ros2_bag(args.recording, out, get_vehicle(args.vehicle) if args.vehicle else None)
        print(f"exported {sum(counts.values())} messages on {len(counts)} topics to {out} (a ROS 2 bag)")
        return 0
    rows = export_recording(args.recording, out, cameras)
    print(f"exported {rows} sets to {out} (frames.csv, images/)")
    return 0


def view(args: argparse.Namespace) -> int:
    """A recording and its outputs as a Rerun view: a .rrd file, or a viewer."""
    reader = RecordingReader(args.recording)
    database = None
    if reader.can_frames():
        name = args.vehicle or reader.vehicle
        stack = load_stack_config(args.config)
        database = protocol_database(stack.can, get_vehicle(name)) if name else None
    from kartpilot.record.rerun_view import view_recording  # rerun takes half a second to import

    out = None if args.out in (None, "live") else args.out
    sets = view_recording(args.recording, out or "live", database=database)
    if database is None and reader.can_frames():
        print("  the CAN frames are shown raw: the recording does not say which kart it was made on (--vehicle)")
    print(f"{sets} sets of {args.recording} " + (f"written to {out} (open it with: rerun {out})"
                                                 if out else "sent to the Rerun viewer"))
    return 0


def recordings_import_bag(args: argparse.Namespace) -> int:
    """A ROS 1 or ROS 2 bag as a kartpilot recording: cameras, commands and ground truth; the rest is listed."""
    config = merge_config(BagImportConfig(), load_yaml_mapping(args.topics) if args.topics else None, "topics")
    result = import_bag(args.bag, args.out, config, get_vehicle(args.vehicle))
    frames = ", ".join(f"{name} {count}" for name, count in result.frames.items())
    print(f"imported {args.bag} into {args.out}: frames {frames}; {result.commands} commands; "
          f"{result.groundtruth_poses} ground-truth poses")
    for note in result.notes:
        print(f"  note: {note}")
    for name, count in result.unsynchronised.items():
        print(f"  {name}: {count} frames within no set of the reference camera (sync_tolerance_ms)")
    for topic, msgtype, reason in result.unmapped:
        print(f"  not imported: {topic} ({msgtype}): {reason}")
    return 0

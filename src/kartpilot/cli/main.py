"""``kartpilot``: one command, thin subcommands.

A known error (:class:`KartpilotError`) prints one line and exits 1; a usage
error exits 2 (argparse); anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence

from kartpilot import __version__
from kartpilot.cli import (
    calibrate_commands,
    can_commands,
    commands,
    drive_commands,
    places_commands,
    record_commands,
)
from kartpilot.core.errors import KartpilotError
from kartpilot.runtime.pipelines import PIPELINES

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="kartpilot", description="Camera-only self-driving stack for karts.")
    parser.add_argument("--version", action="version", version=f"kartpilot {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log each stage's decisions")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    odometry = sub.add_parser("odometry", help="run stereo visual odometry over a dataset or recording")
    odo_sub = odometry.add_subparsers(dest="source", required=True, metavar="SOURCE")
    kitti = odo_sub.add_parser("kitti", help="KITTI odometry layout (sequences/NN, poses/NN.txt)")
    kitti.add_argument("root")
    kitti.add_argument("--sequence", default="00")
    euroc = odo_sub.add_parser("euroc", help="EuRoC ASL layout (mav0/cam0, cam1)")
    euroc.add_argument("root")
    recording = odo_sub.add_parser("recording", help="a kartpilot recording folder")
    recording.add_argument("root")
    synthetic = odo_sub.add_parser("synthetic", help="the built-in synthetic stereo sequence")
    synthetic.add_argument("--frames", type=int, default=40)
    synthetic.add_argument("--seed", type=int, default=0)
    for sub_parser in (kitti, euroc, recording):
        sub_parser.add_argument("--mono", action="store_true",
                                help="monocular VO on the left camera, metric scale from the ground plane")
        sub_parser.add_argument("--camera-height", type=float,
                                help="--mono: the camera's height above the road, m (1.65 on KITTI, 0.6 on the "
                                     "SDC kart)")
    for sub_parser in (kitti, euroc, recording, synthetic):
        sub_parser.add_argument("--out", required=True, help="trajectory file (.txt = KITTI, .tum = TUM)")
        sub_parser.add_argument("--format", choices=("kitti", "tum"), help="override the format guessed from --out")
        sub_parser.add_argument("--config", help="YAML file merged over the defaults")
        sub_parser.add_argument("--plot", help="write the top-view plot here (PNG)")
        sub_parser.add_argument("--json", help="write the summary and metrics here")
        sub_parser.add_argument("--no-progress", action="store_true")
        sub_parser.set_defaults(handler=commands.odometry)

    evaluate = sub.add_parser("eval", help="ATE, RPE and end-point drift of a trajectory against ground truth")
    evaluate.add_argument("--gt", required=True)
    evaluate.add_argument("--est", required=True)
    evaluate.add_argument("--format", choices=("kitti", "tum"), help="format of both files (default: guessed)")
    evaluate.add_argument("--plot", help="write the paths and the error over distance here (PNG)")
    evaluate.add_argument("--json", help="write the metrics here")
    evaluate.set_defaults(handler=commands.evaluate)

    disparity = sub.add_parser("disparity", help="dense block matching scored against Middlebury ground truth")
    disparity.add_argument("pair", help="folder with a Middlebury pair and its ground truth")
    disparity.add_argument("--method", choices=("bm", "sgbm"), default="sgbm")
    disparity.add_argument("--wls", action="store_true", help="apply the WLS post-filter")
    disparity.add_argument("--threshold", type=float, default=2.0)
    disparity.set_defaults(handler=commands.disparity)

    sim = sub.add_parser("sim", help="drive a simulated kart on a track, judged by the referee")
    sim.add_argument("--track", help="bundled track name (utrack, sdc-assen, straight20) or a track YAML file")
    sim.add_argument("--vehicle", choices=("rc-kart", "sdc-kart"))
    sim.add_argument("--driver", choices=("centerline", "commands", "lanes"), default="centerline",
                     help="lanes: the lane-following pipeline on the rendered cameras (sdc-kart)")
    sim.add_argument("--speed-mode", type=float, help="cap the top speed, km/h (the SDC kart's 5/15/30/60 modes)")
    sim.add_argument("--commands", help="recording (or its commands.csv) whose commands the commands driver replays")
    sim.add_argument("--laps", type=int)
    sim.add_argument("--speed", type=float, help="target speed of the centerline driver, m/s")
    sim.add_argument("--weave", type=float, help="zig-zag amplitude of the centerline driver, m")
    sim.add_argument("--edge-offset", type=float, help="drive this far left (+) or right (-) of the centre, m")
    sim.add_argument("--seed", type=int)
    sim.add_argument("--rate", type=float, help="camera and control rate, Hz")
    sim.add_argument("--cameras", help="comma-separated cameras to render (default: all of the vehicle's)")
    sim.add_argument("--no-cones", action="store_true", help="remove the cones (scene and referee)")
    sim.add_argument("--no-render", action="store_true", help="physics and referee only (no images)")
    sim.add_argument("--record", help="write a recording (frames, commands, ground truth, result.json) here")
    sim.add_argument("--video", help="write the camera view with the referee's state here (MP4)")
    sim.add_argument("--result", help="write the referee's result JSON here")
    sim.add_argument("--config", help="YAML file merged over the defaults (sections sim, centerline_driver)")
    sim.add_argument("--no-progress", action="store_true")
    sim.set_defaults(handler=commands.simulate)

    lanes = sub.add_parser("lanes", help="lane boundaries and steer for an image, folder, video, recording or tub")
    lanes.add_argument("input")
    lanes.add_argument("--out", required=True, help="CSV, one row per frame")
    lanes.add_argument("--overlay", help="write the frames with the lanes drawn: a .mp4 file or a folder")
    lanes.add_argument("--stages", action="store_true", help="draw the raw and clustered lines too")
    lanes.add_argument("--config", help="YAML file merged over the defaults (sections lane_detection, lane_policy)")
    lanes.set_defaults(handler=commands.lanes)

    calibrate = sub.add_parser("calibrate", help="camera intrinsics (mono) or a stereo pair from board images, or "
                                                 "the kart's steering")
    cal_sub = calibrate.add_subparsers(dest="mode", required=True, metavar="MODE")
    mono = cal_sub.add_parser("mono", help="one camera")
    mono.add_argument("images", nargs="+")
    mono.add_argument("--name", default="center", help="the camera's name in the rig file")
    stereo = cal_sub.add_parser("stereo", help="a stereo pair (images paired by name: left03.jpg, right03.jpg)")
    stereo.add_argument("--left", nargs="+", required=True)
    stereo.add_argument("--right", nargs="+", required=True)
    for cal in (mono, stereo):
        cal.add_argument("--board", default="9x6", help="inner corners COLUMNSxROWS (ChArUco: squares)")
        cal.add_argument("--square", type=float, default=0.025, help="square side, m")
        cal.add_argument("--charuco", action="store_true", help="a ChArUco board instead of a chessboard")
        cal.add_argument("--marker", type=float, help="ChArUco marker side, m (default 0.75 of a square)")
        cal.add_argument("--dictionary", default="DICT_4X4_50", help="ChArUco dictionary")
        cal.add_argument("--mount", help="the (left) camera's pose on the kart: X,Y,Z[,YAW_DEG,PITCH_DOWN_DEG]")
        cal.add_argument("--out", required=True, help="the rig file to write (YAML)")
        cal.add_argument("--json", action="store_true", help="print a machine-readable summary")
        cal.set_defaults(handler=calibrate_commands.calibrate)

    steering = cal_sub.add_parser("steering", help="the RDW kart's steering: sweep it, fit value to sensor to "
                                                   "road-wheel angle, write it into the rig file")
    steering.add_argument("--rig", required=True, help="the kart's rig file (its steering section is rewritten)")
    steering.add_argument("--vehicle", default="sdc-kart", help="the kart (its wheelbase, for --turning-circle)")
    steering.add_argument("--bus", choices=("socketcan", "virtual"), help="default: the config's can.interface")
    steering.add_argument("--channel", help="the CAN channel (can0)")
    scale = steering.add_mutually_exclusive_group()
    scale.add_argument("--turning-circle", type=float, metavar="DIAMETER_M",
                       help="the rear axle's turning circle at full lock (--at-value), measured driving slowly")
    scale.add_argument("--rad-per-value", type=float, help="road-wheel radians per unit of the ECU's value, by hand")
    steering.add_argument("--at-value", type=float, default=1.25, help="the value the turning circle was driven at")
    steering.add_argument("--positive-steers", choices=("right", "left"), default="right",
                          help="which way a positive value turns the wheels (right on the RDW kart)")
    steering.add_argument("--max-value", type=float, default=1.0, help="sweep from -this to this (at most 1.25)")
    steering.add_argument("--steps", type=int, default=9)
    steering.add_argument("--settle", type=float, default=1.0, help="seconds for the wheels to settle at each step")
    steering.add_argument("--config", help="YAML file merged over the defaults (section can)")
    steering.set_defaults(handler=calibrate_commands.calibrate_steering_command)

    rec = sub.add_parser("record", help="record the live cameras of a rig file")
    rec.add_argument("--rig", required=True, help="rig file: each camera's calibration and capture settings")
    rec.add_argument("--out", required=True, help="the recording folder to create")
    rec.add_argument("--duration", type=float, help="seconds to record (default: until Ctrl-C)")
    rec.add_argument("--cameras", help="comma-separated cameras (default: every camera with capture settings)")
    rec.add_argument("--cameras-json", nargs="+", metavar="JSON",
                     help="the organiser's camera-mapping files; the first whose paths all exist wins (default: the "
                          "rig file's camera_maps)")
    rec.add_argument("--image-format", choices=("jpg", "png"), default="jpg",
                     help="jpg (quality 95) keeps up with three 960x540 cameras at 30 fps on two cores; png is "
                          "lossless and about 25x slower to encode")
    rec.add_argument("--config", help="YAML file merged over the defaults (section live)")
    rec.set_defaults(handler=record_commands.record)

    recordings = sub.add_parser("recordings", help="inspect recordings")
    rec_sub = recordings.add_subparsers(dest="action", required=True, metavar="ACTION")
    info = rec_sub.add_parser("info", help="duration, frames per camera, drops, sync skew, command statistics")
    info.add_argument("recording")
    info.add_argument("--json", action="store_true")
    info.set_defaults(handler=record_commands.recordings_info)
    tub = rec_sub.add_parser("import-tub", help="a Donkey Car tub as a recording")
    tub.add_argument("tub")
    tub.add_argument("--out", required=True)
    tub.add_argument("--rig", help="a rig file with the tub camera's calibration (default: guessed from --fov-deg)")
    tub.add_argument("--camera", help="which camera of the rig file (default: its first)")
    tub.add_argument("--fov-deg", type=float, default=120.0, help="horizontal field of view to guess intrinsics from")
    tub.add_argument("--max-steer-deg", type=float, default=25.0, help="the steer that user/angle 1 stands for")
    tub.set_defaults(handler=record_commands.recordings_import_tub)
    export = rec_sub.add_parser("export", help="a recording as a folder of images plus one CSV")
    export.add_argument("recording")
    export.add_argument("--out", required=True)
    export.add_argument("--cameras", help="comma-separated cameras (default: all)")
    export.set_defaults(handler=record_commands.recordings_export)

    ref = sub.add_parser("reference", help="a reference path (and visual map) from a recorded drive")
    ref.add_argument("recording", help="a kartpilot recording with a stereo pair")
    ref.add_argument("--out", required=True, help="the path file (.csv or .yaml); the map goes beside it")
    ref.add_argument("--from", dest="source", choices=("vo", "groundtruth"), default="vo",
                     help="vo: stereo VO over the recording, with a visual map (default); groundtruth: the "
                          "simulator's poses")
    ref.add_argument("--vehicle", default="rc-kart", help="the kart (its wheelbase); camera mounts come from the "
                     "recording's rig")
    ref.add_argument("--speed", type=float, help="cruise speed of the path's speed profile, m/s")
    ref.add_argument("--config", help="YAML file merged over the defaults (sections stereo_vo, drive)")
    ref.set_defaults(handler=drive_commands.reference)

    drive = sub.add_parser("drive", help="a supervised drive of any pipeline: simulated, replayed or live")
    drive.add_argument("--vehicle", help="rc-kart or sdc-kart (default: sdc-kart for lanes, rc-kart for stereo-vo)")
    drive.add_argument("--pipeline", choices=tuple(PIPELINES), default="stereo-vo",
                       help="lanes; stereo-vo (--reference); mono-vo: one camera, monocular VO fused with place fixes "
                            "(--places)")
    drive.add_argument("--places", help="mono-vo: the place database of the reference drive (kartpilot places "
                                        "build); its drive is the reference unless --reference is given")
    drive.add_argument("--reference", help="stereo-vo: a path written by 'kartpilot reference'")
    where = drive.add_mutually_exclusive_group()
    where.add_argument("--sim", metavar="TRACK", help="drive in the simulator on this track")
    where.add_argument("--replay", metavar="RECORDING", help="run the pipeline on a recording (open loop)")
    where.add_argument("--live", metavar="RIG", help="drive the real kart: the rig file's cameras, the CAN bus of "
                                                     "the config's can section (or --bus, --channel)")
    drive.add_argument("--bus", choices=("virtual", "socketcan", "none"),
                       help="--sim: virtual (default: the simulated ECUs behind python-can's virtual bus) or none; "
                            "--live: socketcan or virtual (default: the config's can.interface)")
    drive.add_argument("--channel", help="--live: the CAN channel (can0; vcan0 for a bench test)")
    drive.add_argument("--cameras-json", nargs="+", metavar="JSON",
                       help="--live: the organiser's camera-mapping files (front, left, right to device paths); the "
                            "first whose paths all exist wins (default: the rig file's camera_maps)")
    drive.add_argument("--gamepad", metavar="DEVICE", help="--live: the gamepad's joystick device (/dev/input/js0)")
    drive.add_argument("--web", metavar="PORT", type=int, help="--live: serve the kart's web page on this port")
    drive.add_argument("--duration", type=float, help="--sim, --live: seconds to drive at most")
    drive.add_argument("--inject", action="append", metavar="KIND@SECONDS",
                       help="--sim: inject a fault (camera-freeze, black-frame, vo-failure, can-bus-off, "
                            "heartbeat-loss, ecu-error, steering-sensor-loss, steering-sensor-range, loop-stall, "
                            "gamepad-unplug, stage-exception); repeatable")
    drive.add_argument("--map", help="the visual map (default: the reference's .map.npz, if there)")
    drive.add_argument("--no-map", action="store_true", help="localise with VO alone")
    drive.add_argument("--speed", type=float, help="stereo-vo: cap the path's speed profile, m/s")
    drive.add_argument("--speed-mode", type=float, help="--sim: cap the top speed, km/h (the SDC kart's modes)")
    drive.add_argument("--seed", type=int)
    drive.add_argument("--rate", type=float, help="camera and control rate, Hz (--sim; a replay keeps its own)")
    drive.add_argument("--steer-bias", type=float, help="the simulated kart's drag to one side, rad (+ left)")
    drive.add_argument("--record", help="record the drive here (frames, commands, outputs, CAN)")
    drive.add_argument("--video", help="write the camera view with the referee's state here (MP4)")
    drive.add_argument("--result", help="write the result JSON here (transitions, fault_to_stop_s, timing)")
    drive.add_argument("--log", help="stereo-vo, mono-vo: write the pipeline's per-step log here (CSV)")
    drive.add_argument("--config", help="YAML file merged over the defaults (sections sim, lane_policy, stereo_vo, "
                                        "drive, can, watchdogs, supervisor)")
    drive.add_argument("--no-progress", action="store_true")
    drive.set_defaults(handler=drive_commands.drive)

    rep = sub.add_parser("replay", help="push a recording through a pipeline; write its outputs as a recording")
    rep.add_argument("recording")
    rep.add_argument("--pipeline", choices=tuple(PIPELINES), required=True)
    rep.add_argument("--out", help="the new recording: commands, the pipeline's outputs, replay.json")
    rep.add_argument("--realtime", action="store_true", help="at the recorded pace (default: as fast as possible)")
    rep.add_argument("--with-frames", action="store_true", help="copy the frames into the new recording too")
    rep.add_argument("--reference", help="stereo-vo, mono-vo: the path to follow (written by 'kartpilot reference'; "
                                         "mono-vo: default the place database's drive)")
    rep.add_argument("--places", help="mono-vo: the place database of the reference drive (kartpilot places build)")
    rep.add_argument("--log", help="stereo-vo, mono-vo: write the pipeline's per-step log here (CSV)")
    rep.add_argument("--map", help="stereo-vo: the visual map (default: the reference's .map.npz, if there)")
    rep.add_argument("--no-map", action="store_true", help="stereo-vo: localise with VO alone")
    rep.add_argument("--vehicle", help="the kart (wheelbase, steering range; default: the one the recording was made "
                                       "on)")
    rep.add_argument("--config", help="YAML file merged over the defaults")
    rep.set_defaults(handler=drive_commands.replay)

    experiment = sub.add_parser("experiment", help="reproduce an experiment of the thesis in the simulator")
    experiment.add_argument("name", choices=("teach-repeat",),
                            help="teach-repeat: teach, build the reference with stereo VO, repeat, score")
    experiment.add_argument("--track", default="straight20")
    experiment.add_argument("--speed", type=float, default=0.62, help="m/s")
    experiment.add_argument("--seed", type=int, default=1)
    experiment.add_argument("--rate", type=float, default=15.0, help="camera and control rate, Hz")
    experiment.add_argument("--steer-bias", type=float, default=0.03, help="the kart's drag to one side, rad")
    experiment.add_argument("--no-map", action="store_true", help="localise with VO alone, as the thesis did")
    experiment.add_argument("--controller", choices=("tuned", "plain_stanley"), default="tuned",
                            help="plain_stanley: the pipeline as the thesis ran it, for comparison")
    experiment.add_argument("--no-video", action="store_true")
    experiment.add_argument("--out", required=True)
    experiment.add_argument("--config", help="YAML file merged over the defaults (sections stereo_vo, drive)")
    experiment.add_argument("--no-progress", action="store_true")
    experiment.set_defaults(handler=drive_commands.experiment)

    places = sub.add_parser("places", help="place recognition: a database of a reference drive, and queries")
    places_sub = places.add_subparsers(dest="action", required=True, metavar="ACTION")
    build = places_sub.add_parser("build", help="a place database from a recording with positions")
    build.add_argument("recording")
    build.add_argument("--out", required=True, help="the database file (places.db)")
    build.add_argument("--camera", help="the camera (default: center, else the stereo pair's left, else the first)")
    build.add_argument("--positions", help="the camera's trajectory (KITTI or TUM; default: the recording's "
                                           "ground truth)")
    build.add_argument("--config", help="YAML file merged over the defaults (section places)")
    build.set_defaults(handler=places_commands.places_build)
    query = places_sub.add_parser("query", help="where an image, or each frame of a recording, was taken")
    query.add_argument("database")
    query.add_argument("query", help="an image file or a recording folder")
    query.add_argument("--camera", help="the recording's camera (default: the database's)")
    query.add_argument("--radius", type=float, default=2.0, help="Recall@K counts places within this, m")
    query.add_argument("--out", help="write each frame's fix here (CSV)")
    query.add_argument("--json", help="write the recall figures here")
    query.set_defaults(handler=places_commands.places_query)

    can_parser = sub.add_parser("can", help="the kart's CAN bus: decoded traffic, live or from a recording")
    can_sub = can_parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    monitor = can_sub.add_parser("monitor", help="one line per message id: rate, longest gap, last values, faults")
    where_from = monitor.add_mutually_exclusive_group()
    where_from.add_argument("--recording", help="a recording's can.csv instead of a live bus")
    where_from.add_argument("--bus", choices=("socketcan", "virtual"), help="live: default the config's can.interface")
    monitor.add_argument("--channel", help="live: the CAN channel (can0)")
    monitor.add_argument("--protocol", choices=("rdw", "kartpilot"),
                         help="how to decode (default: the recording's kart's, live rdw)")
    monitor.add_argument("--duration", type=float, help="live: seconds to listen (default: until Ctrl-C)")
    monitor.add_argument("--every", type=float, default=1.0, help="live: print the table this often, s")
    monitor.add_argument("--json", help="write the last table here (JSON)")
    monitor.add_argument("--config", help="YAML file merged over the defaults (section can)")
    monitor.set_defaults(handler=can_commands.can_monitor)

    demo = sub.add_parser("demo", help="the main job on an embedded default (see README)")
    demo.add_argument("--out", default="demo_out")
    demo.add_argument("--vo-speed", type=float, default=2.0, help="speed of the utrack lap, m/s")
    demo.set_defaults(handler=commands.demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.handler(args))
    except KartpilotError as exc:
        print(f"kartpilot: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("kartpilot: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

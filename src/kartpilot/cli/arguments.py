"""Every subcommand's arguments, built without importing what the commands run.

``kartpilot --help``, a usage error and the start of every command pay only for argparse and
:mod:`kartpilot.cli.values`: each subcommand names its handler by module and function (:func:`_handler`), and the
module is imported when the command runs, so ``kartpilot lanes`` never loads scikit-learn, matplotlib, the CAN stack
or the simulator (``tests/cli/test_startup.py`` keeps it so). The choices that name things the library defines
(lane presets, pipelines, scenarios, vehicles, studies) are spelt out here, and the same test checks each against
the library's own registry.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable

from kartpilot.cli.values import (
    VIEW_HELP,
    config_path,
    device,
    file_or_new_folder,
    input_path,
    new_folder,
    number,
    output_file,
    output_folder,
    results_folder,
    view_target,
    written_path,
)

__all__ = ["LANE_PRESETS", "PIPELINES", "SCENARIOS", "STUDIES", "VEHICLES", "add_parsers", "handler_target"]

LANE_PRESETS = ("kart", "dashcam", "kart-sim", "tape")
"""The lane pipeline's presets: ``kartpilot.runtime.lane_policy.LANE_PRESETS``."""
PIPELINES = ("lanes", "stereo-vo", "mono-vo")
"""The drive pipelines: ``kartpilot.runtime.pipelines.PIPELINES``."""
SCENARIOS = ("start-on-green", "speed-limit", "red-light", "pedestrian", "overtake", "parking", "event")
"""The event's scenarios: ``kartpilot.sim.scenarios.SCENARIOS``."""
VEHICLES = ("rc-kart", "sdc-kart", "sdc-kart-2026", "sdc-kart-steep")
"""The vehicles, in sorted order: ``kartpilot.core.vehicle.VEHICLES``."""
PERFECT_CAMERA_HELP = ("a perfect pinhole rather than the vehicle's real cameras (the default: rolling shutter, "
                       "motion blur, auto-exposure, shot noise, MJPG, the stereo pair's rectification residual); "
                       "replaces sim.effects (docs/simulator.md)")

STUDIES = ("features", "filters", "detectors", "robustness", "lanes", "controllers")
"""The built-in studies: ``kartpilot.study.spec.BUILT_IN``."""


def _handler(module: str, name: str) -> Callable[[argparse.Namespace], int]:
    """The command's handler, ``module.name``, imported when the command runs rather than when the parser is
    built."""
    def run(args: argparse.Namespace) -> int:
        function: Callable[[argparse.Namespace], int] = getattr(importlib.import_module(module), name)
        return function(args)

    run.target = (module, name)  # type: ignore[attr-defined]
    return run


def handler_target(handler: Callable[[argparse.Namespace], int]) -> tuple[str, str]:
    """The module and function a subcommand's handler runs (for the tests, which import each one)."""
    target: tuple[str, str] = handler.target  # type: ignore[attr-defined]
    return target


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Every subcommand, with its arguments and handler."""
    for add in (_general, _detect, _calibrate, _recordings, _drive, _places, _can, _lidar, _study):
        add(sub)


def _general(sub: argparse._SubParsersAction) -> None:
    """The subcommands whose handlers are in :mod:`kartpilot.cli.commands`."""
    odometry_parser = sub.add_parser("odometry", help="run stereo visual odometry over a dataset or recording")
    odo_sub = odometry_parser.add_subparsers(dest="source", required=True, metavar="SOURCE")
    kitti = odo_sub.add_parser("kitti", help="KITTI odometry layout (sequences/NN, poses/NN.txt)")
    kitti.add_argument("root", type=input_path)
    kitti.add_argument("--sequence", default="00")
    euroc = odo_sub.add_parser("euroc", help="EuRoC ASL layout (mav0/cam0, cam1)")
    euroc.add_argument("root", type=input_path)
    recording = odo_sub.add_parser("recording", help="a kartpilot recording folder")
    recording.add_argument("root", type=input_path)
    synthetic = odo_sub.add_parser("synthetic", help="the built-in synthetic stereo sequence")
    synthetic.add_argument("--frames", type=number(int, minimum=2, maximum=100_000), default=40)
    synthetic.add_argument("--seed", type=number(int, minimum=0), default=0)
    for sub_parser in (kitti, euroc, recording):
        sub_parser.add_argument("--mono", action="store_true",
                                help="monocular VO on the left camera, metric scale from the ground plane")
        sub_parser.add_argument("--camera-height", type=number(above=0),
                                help="--mono: the camera's height above the road, m (1.65 on KITTI, 0.6 on the "
                                     "SDC kart)")
        sub_parser.add_argument("--camera-pitch-down", type=number(minimum=-90, maximum=90), default=0.0,
                                help="--places: the camera's pitch below level, deg")
        sub_parser.add_argument("--places", type=input_path,
                                help="--mono: fuse place fixes from this place database (kartpilot places build) "
                                     "into the metres and the position")
    for sub_parser in (kitti, euroc, recording, synthetic):
        sub_parser.add_argument("--out", required=True, type=output_file,
                                help="trajectory file (.txt = KITTI, .tum = TUM)")
        sub_parser.add_argument("--format", choices=("kitti", "tum"), help="override the format guessed from --out")
        sub_parser.add_argument("--config", type=config_path, help="YAML file merged over the defaults")
        sub_parser.add_argument("--plot", type=output_file, help="write the top-view plot here (PNG)")
        sub_parser.add_argument("--view", type=view_target, help=VIEW_HELP)
        sub_parser.add_argument("--json", type=output_file, help="write the summary and metrics here")
        sub_parser.add_argument("--no-progress", action="store_true")
        sub_parser.set_defaults(handler=_handler("kartpilot.cli.commands", "odometry"))

    evaluate = sub.add_parser("eval", help="score kartpilot against ground truth: a trajectory, or its detectors and "
                                           "lane finder on a team's own labelled frames")
    what = evaluate.add_subparsers(dest="what", required=True, metavar="WHAT")
    trajectory = what.add_parser("trajectory", help="ATE, RPE and end-point drift of a trajectory against ground "
                                                    "truth")
    trajectory.add_argument("--gt", type=input_path, required=True)
    trajectory.add_argument("--est", type=input_path, required=True)
    trajectory.add_argument("--format", choices=("kitti", "tum"), help="format of both files (default: guessed)")
    trajectory.add_argument("--plot", type=output_file, help="write the paths and the error over distance here (PNG)")
    trajectory.add_argument("--json", type=output_file, help="write the metrics here")
    trajectory.set_defaults(handler=_handler("kartpilot.cli.commands", "evaluate"))
    detect = what.add_parser("detect", help="the detectors on labelled frames: found, concerning the kart, state "
                                            "read, false alarms, per class (docs/evaluation.md)")
    detect.add_argument("frames", type=input_path, help="the folder the labels' image names are relative to")
    detect.add_argument("labels", type=input_path,
                        help="a kartpilot or COCO JSON file, or a YOLO folder (with classes.txt)")
    detect.add_argument("--class-map", help="THEIRS=OURS[,...]: the labels' class names as kartpilot's (THEIRS= "
                                            "leaves a class out)")
    detect.add_argument("--rig", type=input_path, action="append", metavar="[PREFIX=]RIG",
                        help="the rig whose centre camera took the frames (its mount places things on the ground; "
                             "default: the real SDC kart's); PREFIX=RIG for the frames whose name starts with PREFIX "
                             "(repeat)")
    detect.add_argument("--detector", help="classical (default), onnx:MODEL.onnx or classical+onnx:MODEL.onnx")
    detect.add_argument("--classes", type=input_path,
                        help="onnx: YAML mapping the model's class ids to kartpilot's classes")
    detect.add_argument("--config", type=config_path,
                        help="YAML file merged over the defaults (lane_policy.detector, and "
                             "lane_policy.behaviour for the act windows)")
    detect.add_argument("--slack", type=number(minimum=0, maximum=100), default=5.0,
                        help="how far a hand-drawn box's edge may be off, px (default 5)")
    lanes = what.add_parser("lanes", help="the lane finder on labelled frames: the share of boundary points within "
                                          "N px, per row (docs/evaluation.md)")
    lanes.add_argument("frames", type=input_path, help="the folder the labels' image names are relative to")
    lanes.add_argument("labels", type=input_path, help="a CSV (image,side,row,x) or kartpilot JSON of boundary points")
    lanes.add_argument("--within", type=number(above=0, maximum=1000), default=25.0,
                       help="a point is met within this many pixels along its row (default 25)")
    lanes.add_argument("--preset", choices=LANE_PRESETS, default="kart", help="the lane finder's preset")
    lanes.add_argument("--config", type=config_path,
                       help="YAML file merged over the preset (section lane_policy: lanes)")
    for parser in (detect, lanes):
        parser.add_argument("--out", type=output_file, help="write the table here (Markdown)")
        parser.add_argument("--json", type=output_file, help="write every score, miss and false alarm here")
    detect.set_defaults(handler=_handler("kartpilot.cli.eval_commands", "eval_detect"))
    lanes.set_defaults(handler=_handler("kartpilot.cli.eval_commands", "eval_lanes"))

    disparity_parser = sub.add_parser("disparity", help="dense block matching scored against Middlebury ground truth")
    disparity_parser.add_argument("pair", type=input_path, help="folder with a Middlebury pair and its ground truth")
    disparity_parser.add_argument("--method", choices=("bm", "sgbm"), default="sgbm")
    disparity_parser.add_argument("--wls", action="store_true", help="apply the WLS post-filter")
    disparity_parser.add_argument("--threshold", type=number(above=0), default=2.0)
    disparity_parser.set_defaults(handler=_handler("kartpilot.cli.commands", "disparity"))

    sim = sub.add_parser("sim", help="drive a simulated kart on a track, judged by the referee")
    sim.add_argument("--track", type=input_path,
                     help="bundled track name (utrack, sdc-assen, lelystad, straight20) or a track YAML "
                          "file")
    sim.add_argument("--vehicle", choices=VEHICLES,
                     help="the kart (--scenario: sdc-kart, or sdc-kart-2026 whose rules use its LiDAR)")
    sim.add_argument("--driver", choices=("centerline", "commands", "lanes"), default="centerline",
                     help="lanes: the lane-following pipeline on the rendered cameras (sdc-kart)")
    sim.add_argument("--scenario", type=input_path, metavar="NAME|FILE",
                     help="one of the event's scenarios (" + ", ".join(SCENARIOS) + ") or a scenario file "
                          "(docs/scenarios.md), on the venue track, closed loop with the event's rules, scored as "
                          "the event does (--seed varies a named one; exit 1 on a fault)")
    sim.add_argument("--inject", action="append", metavar="KIND@SECONDS",
                     help="--scenario: a camera's or the LiDAR's fault from its time on (camera-freeze, black-frame, "
                          "lidar-loss, lidar-freeze); repeatable")
    sim.add_argument("--save-scenario", type=output_file, metavar="FILE",
                     help="--scenario: write the scenario as run (props placed, seed) to this file, which "
                          "reproduces it exactly")
    sim.add_argument("--preset", choices=LANE_PRESETS,
                     help="lanes: the lane pipeline's preset (default: the track's, lane_preset in its file)")
    sim.add_argument("--speed-mode", type=number(above=0),  # lanes on the sdc-kart: a known-good mode by default
                     help="cap the top speed, km/h (the SDC kart's 5/15/30/60 modes)")
    sim.add_argument("--commands", type=input_path,
                     help="recording (or its commands.csv) whose commands the commands driver replays")
    sim.add_argument("--laps", type=number(int, minimum=1))
    sim.add_argument("--speed", type=number(above=0), help="target speed of the centerline driver, m/s")
    sim.add_argument("--weave", type=number(minimum=0), help="zig-zag amplitude of the centerline driver, m")
    sim.add_argument("--edge-offset", type=number(), help="drive this far left (+) or right (-) of the centre, m")
    sim.add_argument("--seed", type=number(int, minimum=0))
    sim.add_argument("--rate", type=number(above=0, maximum=1000), help="camera and control rate, Hz")
    sim.add_argument("--cameras", help="comma-separated cameras to render (default: all of the vehicle's)")
    sim.add_argument("--perfect-camera", action="store_true", help=PERFECT_CAMERA_HELP)
    sim.add_argument("--no-cones", action="store_true", help="remove the cones (scene and referee)")
    sim.add_argument("--no-render", action="store_true", help="physics and referee only (no images)")
    sim.add_argument("--record", type=new_folder,
                     help="write a recording (frames, commands, ground truth, result.json) here")
    sim.add_argument("--video", type=output_file, help="write the camera view with the referee's state here (MP4)")
    sim.add_argument("--result", type=output_file, help="write the referee's result JSON here")
    sim.add_argument("--view", type=view_target, help=VIEW_HELP)
    sim.add_argument("--config", type=config_path,
                     help="YAML file merged over the defaults (sections sim, centerline_driver)")
    sim.add_argument("--no-progress", action="store_true")
    sim.set_defaults(handler=_handler("kartpilot.cli.commands", "simulate"))

    lanes_parser = sub.add_parser("lanes", help="lane boundaries and steer for an image, folder, video, recording or "
                                                "tub")
    lanes_parser.add_argument("input", type=input_path)
    lanes_parser.add_argument("--out", required=True, type=output_file, help="CSV, one row per frame")
    lanes_parser.add_argument("--overlay", type=file_or_new_folder,
                              help="write the frames with the lanes drawn: a .mp4 file or a folder")
    lanes_parser.add_argument("--stages", action="store_true", help="draw the raw and clustered lines too")
    lanes_parser.add_argument("--preset", choices=LANE_PRESETS, default="kart",
                              help="the kind of track and camera: kart (road lines, a camera close to the ground, the "
                                   "lane pipeline's own), dashcam (road lines, a car's dash camera) or tape (a small "
                                   "car's wide-angle camera on a taped track)")
    lanes_parser.add_argument("--config", type=config_path,
                              help="YAML file merged over the preset (section lane_policy: lanes, "
                                   "follow)")
    lanes_parser.add_argument("--independent", action="store_true",
                              help="every image on its own (unrelated photos): nothing carries from one to the next; "
                                   "without it a frame that does not follow from the one before starts afresh")
    lanes_parser.add_argument("--rig", type=input_path,
                              help="rig file whose centre camera's body mask (the kart's own body in view) "
                                   "is left out of the search")
    lanes_parser.set_defaults(handler=_handler("kartpilot.cli.commands", "lanes"))

    demo_parser = sub.add_parser("demo", help="the event's six scenarios at the venue, then the small kart's "
                                              "teach-and-repeat on stereo VO, in the simulator (see README)")
    demo_parser.add_argument("--out", default="demo_out", type=output_folder)
    demo_parser.add_argument("--full", action="store_true",
                             help="add a lap of the venue at 30 km/h, and make the teach-and-repeat a lap of utrack "
                                  "(about ten minutes)")
    demo_parser.add_argument("--vo-speed", type=number(above=0), default=2.0,
                             help="with --full: speed of the utrack lap, m/s")
    demo_parser.set_defaults(handler=_handler("kartpilot.cli.demo_command", "demo"))


def _detect(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("detect", help="traffic lights, speed signs, stop lines, zebras, people, a car, "
                                           "barriers and a parking bay, per frame, to CSV")
    parser.add_argument("input", type=input_path, help="an image, a folder of images, a video or a recording")
    parser.add_argument("--out", required=True, type=output_file, help="CSV, one row per object")
    parser.add_argument("--detector",
                        help="classical (default), onnx:MODEL.onnx (a team's YOLO model exported to ONNX, in place "
                             "of the classical detectors) or classical+onnx:MODEL.onnx (beside them)")
    parser.add_argument("--config", type=config_path,
                        help="YAML file merged over the defaults (section lane_policy.detector, as a "
                             "drive takes it: e.g. signals: {values_kmh: [10, 15, 20, 30, 50]})")
    parser.add_argument("--classes", type=input_path,
                        help="onnx: YAML mapping the model's class ids to kartpilot's classes")
    parser.add_argument("--rig", type=input_path,
                        help="rig file whose centre camera's mount places the objects on the ground "
                             "(default: the real SDC kart's centre camera, 0.56 m up, 6.8 deg down)")
    parser.add_argument("--overlay", type=file_or_new_folder, help="draw the detections: a folder of PNGs or a video")
    parser.add_argument("--no-people", action="store_true", help="skip the HOG people detector (the slowest part)")
    parser.add_argument("--independent", action="store_true",
                        help="every image on its own: no track ids carried from one to the next")
    parser.set_defaults(handler=_handler("kartpilot.cli.detect_commands", "detect"))


def _calibrate(sub: argparse._SubParsersAction) -> None:
    """The subcommands whose handlers are in :mod:`kartpilot.cli.calibrate_commands`."""
    calibrate_parser = sub.add_parser("calibrate", help="camera intrinsics (mono) or a stereo pair from board "
                                                        "images, or the kart's steering")
    cal_sub = calibrate_parser.add_subparsers(dest="mode", required=True, metavar="MODE")
    mono = cal_sub.add_parser("mono", help="one camera, from photos of a board or a video of it moved before it")
    mono.add_argument("images", type=input_path, nargs="*", help="photos of the board (or give --video)")
    mono.add_argument("--video", type=input_path,
                      help="a video of the board moved before the camera: its frames where the board "
                           "has moved since the last one kept")
    mono.add_argument("--max-views", type=number(int, minimum=3, maximum=200), default=40,
                      help="--video: at most this many frames, spread over the video")
    mono.add_argument("--name", default="center", help="the camera's name in the rig file")
    stereo = cal_sub.add_parser("stereo", help="a stereo pair (images paired by name: left03.jpg, right03.jpg)")
    stereo.add_argument("--left", type=input_path, nargs="+", required=True)
    stereo.add_argument("--right", type=input_path, nargs="+", required=True)
    for cal in (mono, stereo):
        cal.add_argument("--board", default="9x6", help="inner corners COLUMNSxROWS (ChArUco: squares)")
        cal.add_argument("--square", type=number(above=0), default=0.025, help="square side, m")
        cal.add_argument("--charuco", action="store_true", help="a ChArUco board instead of a chessboard")
        cal.add_argument("--marker", type=number(above=0), help="ChArUco marker side, m (default 0.75 of a square)")
        cal.add_argument("--dictionary", default="DICT_4X4_50", help="ChArUco dictionary")
        cal.add_argument("--mount", help="the (left) camera's pose on the kart: X,Y,Z[,YAW_DEG,PITCH_DOWN_DEG]")
        cal.add_argument("--out", required=True, type=output_file, help="the rig file to write (YAML)")
        cal.add_argument("--json", action="store_true", help="print a machine-readable summary")
        cal.set_defaults(handler=_handler("kartpilot.cli.calibrate_commands", "calibrate"))

    ground = cal_sub.add_parser("ground", help="each camera's pose over the ground (height, pitch, roll, yaw) from "
                                               "one image per camera of one ChArUco board lying on the floor")
    ground.add_argument("--image", type=input_path, action="append", required=True, metavar="NAME=FILE",
                        help="a camera's image of the board (repeat: --image center=c.jpg --image left=l.jpg ...)")
    ground.add_argument("--board", help="the board's squares COLUMNSxROWS (default: found in the images)")
    ground.add_argument("--square", type=number(above=0), default=0.115,
                        help="square side, m (the images cannot tell it; default: the organiser's board's 0.115)")
    ground.add_argument("--marker", type=number(above=0),
                        help="marker side, m (default: measured in the images against the squares)")
    ground.add_argument("--dictionary", help="ArUco dictionary (default: found in the images)")
    ground.add_argument("--resamples", type=number(int, minimum=0, maximum=1000), default=50,
                        help="refits on resampled points for each figure's standard deviation (0: none)")
    ground.add_argument("--rig", type=input_path,
                        help="a rig file with the cameras' intrinsics (else each focal length is estimated "
                             "from its one view); its other contents are kept")
    ground.add_argument("--reference", default="center", help="the camera that sets the kart's forward direction")
    ground.add_argument("--reference-x", type=number(), default=0.0,
                        help="how far ahead of the body's origin (the rear axle) the reference camera stands, m")
    ground.add_argument("--out", required=True, type=output_file, help="the rig file to write (YAML)")
    ground.add_argument("--birdseye", type=output_file, help="write the stitched bird's-eye view here (PNG or JPEG)")
    ground.add_argument("--ahead", type=number(above=0), default=8.0, help="the bird's-eye view's reach ahead, m")
    ground.add_argument("--side", type=number(above=0), default=5.0, help="its reach to each side, m")
    ground.add_argument("--pixels-per-m", type=number(above=1, maximum=1000), default=100.0)
    ground.add_argument("--json", action="store_true", help="print a machine-readable summary")
    ground.set_defaults(handler=_handler("kartpilot.cli.calibrate_commands", "calibrate_ground_command"), charuco=True)
    lidar = cal_sub.add_parser("lidar", help="the LiDAR's mount (x, y, turn) from a recording of the board held "
                                             "upright at a few places, seen by the centre camera and the LiDAR")
    lidar.add_argument("recording", type=input_path,
                       help="a recording with the centre camera's frames and the LiDAR's sweeps")
    lidar.add_argument("--rig", type=input_path, required=True,
                       help="the rig file: the centre camera's calibration and mount, and "
                            "the LiDAR's mount as measured by hand (the fit starts there)")
    lidar.add_argument("--camera", default="center", help="the camera that sees the board")
    lidar.add_argument("--board", required=True, help="the board's squares COLUMNSxROWS (ChArUco) or inner "
                                                      "corners (a chessboard, with --chessboard)")
    lidar.add_argument("--square", type=number(above=0), default=0.115, help="square side, m")
    lidar.add_argument("--marker", type=number(above=0), help="ChArUco marker side, m (default 0.75 of a square)")
    lidar.add_argument("--dictionary", default="DICT_4X4_50", help="ChArUco dictionary")
    lidar.add_argument("--chessboard", dest="charuco", action="store_false", help="a chessboard, not a ChArUco board")
    lidar.add_argument("--max-gap", type=number(above=0, maximum=1.0), default=0.1,
                       help="a frame pairs with the sweep nearest its time within this, s")
    lidar.add_argument("--out", required=True, type=output_file, help="the rig file to write, with the LiDAR's mount")
    lidar.add_argument("--json", action="store_true", help="print a machine-readable summary")
    lidar.set_defaults(handler=_handler("kartpilot.cli.calibrate_commands", "calibrate_lidar_command"), charuco=True)

    steering = cal_sub.add_parser("steering", help="the RDW kart's steering: sweep it, fit value to sensor to "
                                                   "road-wheel angle, write it into the rig file")
    steering.add_argument("--rig", type=input_path, required=True,
                          help="the kart's rig file (its steering section is rewritten)")
    steering.add_argument("--vehicle", default="sdc-kart", help="the kart (its wheelbase, for --turning-circle)")
    steering.add_argument("--bus", choices=("socketcan", "virtual"), help="default: the config's can.interface")
    steering.add_argument("--channel", help="the CAN channel (can0)")
    scale = steering.add_mutually_exclusive_group()
    scale.add_argument("--turning-circle", type=number(above=0), metavar="DIAMETER_M",
                       help="the rear axle's turning circle at full lock (--at-value), measured driving slowly")
    scale.add_argument("--rad-per-value", type=number(), help="road-wheel radians per unit of the ECU's value, by hand")
    steering.add_argument("--at-value", type=number(), default=1.25, help="the value the turning circle was driven at")
    steering.add_argument("--positive-steers", choices=("right", "left"), default="right",
                          help="which way a positive value turns the wheels (right on the RDW kart)")
    steering.add_argument("--max-value", type=number(above=0, maximum=1.25), default=1.0,
                          help="sweep from -this to this (at most 1.25)")
    steering.add_argument("--steps", type=number(int, minimum=2), default=9)
    steering.add_argument("--settle", type=number(minimum=0), default=1.0,
                          help="seconds for the wheels to settle at each step")
    steering.add_argument("--config", type=config_path, help="YAML file merged over the defaults (section can)")
    steering.set_defaults(handler=_handler("kartpilot.cli.calibrate_commands", "calibrate_steering_command"))


def _recordings(sub: argparse._SubParsersAction) -> None:
    """The subcommands whose handlers are in :mod:`kartpilot.cli.record_commands`."""
    rec = sub.add_parser("record", help="record the live cameras of a rig file")
    rec.add_argument("--rig", type=input_path, required=True,
                     help="rig file: each camera's calibration and capture settings")
    rec.add_argument("--out", required=True, type=new_folder, help="the recording folder to create")
    rec.add_argument("--duration", type=number(above=0), help="seconds to record (default: until Ctrl-C)")
    rec.add_argument("--cameras", help="comma-separated cameras (default: every camera with capture settings)")
    rec.add_argument("--cameras-json", type=input_path, nargs="+", metavar="JSON",
                     help="the organiser's camera-mapping files; the first whose paths all exist wins (default: the "
                          "rig file's camera_maps)")
    rec.add_argument("--image-format", choices=("jpg", "png"), default="jpg",
                     help="jpg (quality 95) keeps up with three 960x540 cameras at 30 fps on two cores; png is "
                          "lossless and about 25x slower to encode")
    rec.add_argument("--config", type=config_path, help="YAML file merged over the defaults (section live)")
    rec.set_defaults(handler=_handler("kartpilot.cli.record_commands", "record"))

    recordings = sub.add_parser("recordings", help="inspect recordings")
    rec_sub = recordings.add_subparsers(dest="action", required=True, metavar="ACTION")
    info = rec_sub.add_parser("info", help="duration, frames per camera, drops, sync skew, command statistics")
    info.add_argument("recording", type=input_path)
    info.add_argument("--json", action="store_true")
    info.set_defaults(handler=_handler("kartpilot.cli.record_commands", "recordings_info"))
    tub = rec_sub.add_parser("import-tub", help="a Donkey Car tub as a recording")
    tub.add_argument("tub", type=input_path)
    tub.add_argument("--out", required=True, type=new_folder)
    tub.add_argument("--rig", type=input_path,
                     help="a rig file with the tub camera's calibration (default: guessed from --fov-deg)")
    tub.add_argument("--camera", help="which camera of the rig file (default: its first)")
    tub.add_argument("--fov-deg", type=number(above=0, maximum=179), default=120.0,
                     help="horizontal field of view to guess intrinsics from")
    tub.add_argument("--max-steer-deg", type=number(above=0, maximum=90), default=25.0,
                     help="the steer that user/angle 1 stands for")
    tub.set_defaults(handler=_handler("kartpilot.cli.record_commands", "recordings_import_tub"))
    kitti = rec_sub.add_parser("import-kitti", help="a KITTI odometry sequence (stereo, ground truth) as a recording")
    kitti.add_argument("root", type=input_path, help="the KITTI odometry folder (sequences/, poses/)")
    kitti.add_argument("--sequence", required=True)
    kitti.add_argument("--out", required=True, type=new_folder)
    kitti.add_argument("--camera-height", type=number(above=0), required=True,
                       help="the left camera's height above the road, m (1.65 on KITTI's car)")
    kitti.add_argument("--camera-pitch-down", type=number(minimum=-90, maximum=90), default=0.0,
                       help="its pitch below level, deg")
    kitti.set_defaults(handler=_handler("kartpilot.cli.record_commands", "recordings_import_kitti"))

    viewer = sub.add_parser("view", help="a recording and its outputs in the Rerun viewer, or as a .rrd file")
    viewer.add_argument("recording", type=input_path)
    viewer.add_argument("--out", type=view_target, help="write a .rrd file here (default: send to a viewer, started "
                                                        "if none is running)")
    viewer.add_argument("--vehicle", choices=VEHICLES,
                        help="the kart whose CAN messages to decode (default: the one the recording names)")
    viewer.add_argument("--config", type=config_path,
                        help="YAML file merged over the defaults (section can: the DBC file)")
    viewer.set_defaults(handler=_handler("kartpilot.cli.record_commands", "view"))

    bag = rec_sub.add_parser("import-bag", help="a ROS 1 or ROS 2 bag as a recording (cameras, commands, ground "
                                                "truth; the topics it cannot map are listed)")
    bag.add_argument("bag", type=input_path, help="a ROS 1 .bag file or a ROS 2 bag folder")
    bag.add_argument("--out", required=True, type=new_folder)
    bag.add_argument("--topics", help="YAML topic map: cameras (name, image, info), stereo_pair, commands, "
                                      "groundtruth, base_frame, sync_tolerance_ms (default: found by type)")
    bag.add_argument("--vehicle", choices=VEHICLES, default="sdc-kart",
                     help="its top speed and wheelbase turn commanded speeds and yaw rates into throttle and steer")
    bag.set_defaults(handler=_handler("kartpilot.cli.record_commands", "recordings_import_bag"))

    export = rec_sub.add_parser("export", help="a recording as a folder of images plus one CSV, one MCAP file or a "
                                               "ROS 2 bag")
    export.add_argument("recording", type=input_path)
    export.add_argument("--out", required=True, type=written_path,
                        help="folder and ros2: a new folder; mcap: the file to write")
    export.add_argument("--format", choices=("folder", "mcap", "ros2"), default="folder",
                        help="folder: images and frames.csv; mcap: images, calibration, transforms, ground truth, "
                             "commands, CAN and outputs in Foxglove's schemas; ros2: images, camera info, mounts, "
                             "ground truth and Ackermann commands as a ROS 2 bag")
    export.add_argument("--cameras", help="comma-separated cameras (default: all)")
    export.add_argument("--vehicle", choices=VEHICLES,
                        help="ros2: the top speed a full throttle stands for in the commands (default: the speed is "
                             "the throttle)")
    export.set_defaults(handler=_handler("kartpilot.cli.record_commands", "recordings_export"),
                        check=_export_out(export))


def _export_out(parser: argparse.ArgumentParser) -> Callable[[argparse.Namespace], None]:
    """The check of ``recordings export --out``, which depends on ``--format``: a file to write for ``mcap``, a
    new folder otherwise; a usage error as argparse's own types give."""
    def check(args: argparse.Namespace) -> None:
        try:
            args.out = output_file(args.out) if args.format == "mcap" else new_folder(args.out)
            if args.vehicle and args.format != "ros2":
                parser.error("--vehicle is for --format ros2 (the commands' speed)")
            if args.cameras and args.format == "ros2":
                parser.error("--cameras is for the folder and mcap formats; a ROS 2 bag takes every camera")
        except argparse.ArgumentTypeError as exc:
            parser.error(f"argument --out: {exc}")
    return check


def _drive(sub: argparse._SubParsersAction) -> None:
    """The subcommands whose handlers are in :mod:`kartpilot.cli.drive_commands`."""
    ref = sub.add_parser("reference", help="a reference path (and visual map) from a recorded drive")
    ref.add_argument("recording", type=input_path, help="a kartpilot recording with a stereo pair")
    ref.add_argument("--out", required=True, type=output_file,
                     help="the path file (.csv or .yaml); the map goes beside it")
    ref.add_argument("--from", dest="source", choices=("vo", "groundtruth"), default="vo",
                     help="vo: stereo VO over the recording, with a visual map (default); groundtruth: the "
                          "simulator's poses")
    ref.add_argument("--vehicle", default="rc-kart", help="the kart (its wheelbase); camera mounts come from the "
                     "recording's rig")
    ref.add_argument("--speed", type=number(above=0), help="cruise speed of the path's speed profile, m/s")
    ref.add_argument("--config", type=config_path,
                     help="YAML file merged over the defaults (sections stereo_vo, drive)")
    ref.set_defaults(handler=_handler("kartpilot.cli.drive_commands", "reference"))

    drive_parser = sub.add_parser("drive", help="a supervised drive of any pipeline: simulated, replayed or live")
    drive_parser.add_argument("--vehicle", help="rc-kart or sdc-kart (default: sdc-kart for lanes, rc-kart for "
                                                "stereo-vo)")
    drive_parser.add_argument("--pipeline", choices=PIPELINES, default="stereo-vo",
                              help="lanes; stereo-vo (--reference); mono-vo: one camera, monocular VO fused with "
                                   "place fixes (--places)")
    drive_parser.add_argument("--places", type=input_path,
                              help="mono-vo: the place database of the reference drive (kartpilot places "
                                   "build); its drive is the reference unless --reference is given")
    drive_parser.add_argument("--reference", type=input_path, help="stereo-vo: a path written by 'kartpilot reference'")
    where = drive_parser.add_mutually_exclusive_group()
    where.add_argument("--sim", type=input_path, metavar="TRACK", help="drive in the simulator on this track")
    where.add_argument("--replay", type=input_path, metavar="RECORDING",
                       help="run the pipeline on a recording (open loop)")
    where.add_argument("--live", type=input_path, metavar="RIG",
                       help="drive the real kart: the rig file's cameras, the CAN bus of "
                            "the config's can section (or --bus, --channel)")
    drive_parser.add_argument("--preset", choices=LANE_PRESETS,
                              help="lanes: the lane pipeline's preset (default: kart; --sim: the track's own)")
    drive_parser.add_argument("--bus", choices=("virtual", "socketcan", "none"),
                              help="--sim: virtual (default: the simulated ECUs behind python-can's virtual bus) or "
                                   "none; --live: socketcan or virtual (default: the config's can.interface)")
    drive_parser.add_argument("--channel", help="--live: the CAN channel (can0; vcan0 for a bench test)")
    drive_parser.add_argument("--cameras-json", type=input_path, nargs="+", metavar="JSON",
                              help="--live: the organiser's camera-mapping files (front, left, right to device "
                                   "paths); the first whose paths all exist wins (default: the rig file's camera_maps)")
    drive_parser.add_argument("--gamepad", metavar="DEVICE", type=device, help="--live: the gamepad's joystick device "
                                                                  "(/dev/input/js0)")
    drive_parser.add_argument("--web", metavar="PORT", type=number(int, minimum=1, maximum=65535),
                              help="--live: serve the kart's web page on this port")
    drive_parser.add_argument("--web-host", metavar="ADDRESS", default="127.0.0.1",
                              help="--web: the address the page listens on (default 127.0.0.1: this machine only; "
                                   "the hotspot's address to serve the phones on it; 0.0.0.0: every interface)")
    drive_parser.add_argument("--duration", type=number(above=0), help="--sim, --live: seconds to drive at most")
    drive_parser.add_argument("--inject", action="append", metavar="KIND@SECONDS",
                              help="--sim: inject a fault (camera-freeze, black-frame, vo-failure, can-bus-off, "
                                   "heartbeat-loss, ecu-error, steering-sensor-loss, steering-sensor-range, "
                                   "loop-stall, gamepad-unplug, stage-exception, lidar-loss, lidar-freeze); "
                                   "repeatable")
    drive_parser.add_argument("--map", type=input_path,
                              help="the visual map (default: the reference's .map.npz, if there)")
    drive_parser.add_argument("--no-map", action="store_true", help="localise with VO alone")
    drive_parser.add_argument("--speed", type=number(above=0), help="stereo-vo: cap the path's speed profile, m/s")
    drive_parser.add_argument("--speed-mode", type=number(above=0),
                              help="--sim: cap the top speed, km/h (the SDC kart's modes)")
    drive_parser.add_argument("--seed", type=number(int, minimum=0))
    drive_parser.add_argument("--rate", type=number(above=0, maximum=1000),
                              help="camera and control rate, Hz (--sim; a replay keeps its own)")
    drive_parser.add_argument("--steer-bias", type=number(), help="the simulated kart's drag to one side, rad (+ left)")
    drive_parser.add_argument("--perfect-camera", action="store_true", help="--sim: " + PERFECT_CAMERA_HELP)
    drive_parser.add_argument("--record", type=new_folder,
                              help="record the drive here (frames, commands, outputs, CAN)")
    drive_parser.add_argument("--video", type=output_file,
                              help="write the camera view with the referee's state here (MP4)")
    drive_parser.add_argument("--result", type=output_file,
                              help="write the result JSON here (transitions, fault_to_stop_s, timing)")
    drive_parser.add_argument("--view", type=view_target, help=VIEW_HELP)
    drive_parser.add_argument("--log", type=output_file,
                              help="stereo-vo, mono-vo: write the pipeline's per-step log here (CSV)")
    drive_parser.add_argument("--config", type=config_path,
                              help="YAML file merged over the defaults (sections sim, lane_policy, "
                                   "stereo_vo, drive, can, watchdogs, supervisor)")
    drive_parser.add_argument("--no-progress", action="store_true")
    drive_parser.set_defaults(handler=_handler("kartpilot.cli.drive_commands", "drive"))

    rep = sub.add_parser("replay", help="push a recording through a pipeline; write its outputs as a recording")
    rep.add_argument("recording", type=input_path)
    rep.add_argument("--pipeline", choices=PIPELINES, required=True)
    rep.add_argument("--out", type=new_folder, help="the new recording: commands, the pipeline's outputs, replay.json")
    rep.add_argument("--realtime", action="store_true", help="at the recorded pace (default: as fast as possible)")
    rep.add_argument("--with-frames", action="store_true", help="copy the frames into the new recording too")
    rep.add_argument("--reference", type=input_path,
                     help="stereo-vo, mono-vo: the path to follow (written by 'kartpilot reference'; "
                          "mono-vo: default the place database's drive)")
    rep.add_argument("--places", type=input_path,
                     help="mono-vo: the place database of the reference drive (kartpilot places build)")
    rep.add_argument("--log", type=output_file, help="stereo-vo, mono-vo: write the pipeline's per-step log here (CSV)")
    rep.add_argument("--view", type=view_target, help=VIEW_HELP)
    rep.add_argument("--map", type=input_path,
                     help="stereo-vo: the visual map (default: the reference's .map.npz, if there)")
    rep.add_argument("--no-map", action="store_true", help="stereo-vo: localise with VO alone")
    rep.add_argument("--vehicle", help="the kart (wheelbase, steering range; default: the one the recording was made "
                                       "on)")
    rep.add_argument("--preset", choices=LANE_PRESETS,
                     help="lanes: the kind of track and camera (kart: the real kart's road lines, the default; "
                          "a simulated run's default is its track's; dashcam: a car's; tape: a small car's "
                          "wide-angle camera on a taped track)")
    rep.add_argument("--config", type=config_path, help="YAML file merged over the defaults")
    rep.set_defaults(handler=_handler("kartpilot.cli.drive_commands", "replay"))

    experiment_parser = sub.add_parser("experiment", help="reproduce an experiment of the thesis in the simulator")
    experiment_parser.add_argument("name", choices=("teach-repeat",),
                                   help="teach-repeat: teach, build the reference with stereo VO, repeat, score")
    experiment_parser.add_argument("--track", type=input_path, default="straight20")
    experiment_parser.add_argument("--speed", type=number(above=0), default=0.62, help="m/s")
    experiment_parser.add_argument("--seed", type=number(int, minimum=0), default=1)
    experiment_parser.add_argument("--rate", type=number(above=0, maximum=1000), default=15.0,
                                   help="camera and control rate, Hz")
    experiment_parser.add_argument("--steer-bias", type=number(), default=0.03, help="the kart's drag to one side, rad")
    experiment_parser.add_argument("--no-map", action="store_true", help="localise with VO alone, as the thesis did")
    experiment_parser.add_argument("--controller", choices=("tuned", "plain_stanley"), default="tuned",
                                   help="plain_stanley: the pipeline as the thesis ran it, for comparison")
    experiment_parser.add_argument("--no-video", action="store_true")
    experiment_parser.add_argument("--out", required=True, type=output_folder)
    experiment_parser.add_argument("--config", type=config_path,
                                   help="YAML file merged over the defaults (sections stereo_vo, drive)")
    experiment_parser.add_argument("--no-progress", action="store_true")
    experiment_parser.set_defaults(handler=_handler("kartpilot.cli.drive_commands", "experiment"))


def _places(sub: argparse._SubParsersAction) -> None:
    """The subcommands whose handlers are in :mod:`kartpilot.cli.places_commands`."""
    places = sub.add_parser("places", help="place recognition: a database of a reference drive, and queries")
    places_sub = places.add_subparsers(dest="action", required=True, metavar="ACTION")
    build = places_sub.add_parser("build", help="a place database from a recording with positions")
    build.add_argument("recording", type=input_path)
    build.add_argument("--out", required=True, type=output_file, help="the database file (places.db)")
    build.add_argument("--camera", help="the camera (default: center, else the stereo pair's left, else the first)")
    build.add_argument("--positions-from", choices=("truth", "stereo-vo", "mono-vo"),
                       help="tag the places with the recording's ground truth (the default, where it has one), or "
                            "with visual odometry over the recording (a real drive)")
    build.add_argument("--positions", help="the camera's trajectory (KITTI or TUM; default: the recording's "
                                           "ground truth)")
    build.add_argument("--config", type=config_path, help="YAML file merged over the defaults (section places)")
    build.set_defaults(handler=_handler("kartpilot.cli.places_commands", "places_build"))
    query = places_sub.add_parser("query", help="where an image, or each frame of a recording, was taken")
    query.add_argument("database", type=input_path)
    query.add_argument("query", type=input_path, help="an image file or a recording folder")
    query.add_argument("--camera", help="the recording's camera (default: the database's)")
    query.add_argument("--radius", type=number(above=0), default=2.0, help="Recall@K counts places within this, m")
    query.add_argument("--out", type=output_file, help="write each frame's fix here (CSV)")
    query.add_argument("--json", type=output_file, help="write the recall figures here")
    query.set_defaults(handler=_handler("kartpilot.cli.places_commands", "places_query"))


def _can(sub: argparse._SubParsersAction) -> None:
    """The subcommands whose handlers are in :mod:`kartpilot.cli.can_commands`."""
    can_parser = sub.add_parser("can", help="the kart's CAN bus: decoded traffic, live or from a recording")
    can_sub = can_parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    monitor = can_sub.add_parser("monitor", help="one line per message id: rate, longest gap, last values, faults")
    where_from = monitor.add_mutually_exclusive_group()
    where_from.add_argument("--recording", type=input_path, help="a recording's can.csv instead of a live bus")
    where_from.add_argument("--bus", choices=("socketcan", "virtual"), help="live: default the config's can.interface")
    monitor.add_argument("--channel", help="live: the CAN channel (can0)")
    monitor.add_argument("--protocol", choices=("rdw", "kartpilot"),
                         help="how to decode (default: the recording's kart's, live rdw)")
    monitor.add_argument("--duration", type=number(above=0), help="live: seconds to listen (default: until Ctrl-C)")
    monitor.add_argument("--every", type=number(above=0), default=1.0, help="live: print the table this often, s")
    monitor.add_argument("--json", type=output_file, help="write the last table here (JSON)")
    monitor.add_argument("--config", type=config_path, help="YAML file merged over the defaults (section can)")
    monitor.set_defaults(handler=_handler("kartpilot.cli.can_commands", "can_monitor"))


def _lidar(sub: argparse._SubParsersAction) -> None:
    """The subcommands whose handlers are in :mod:`kartpilot.cli.lidar_commands`."""
    lidar = sub.add_parser("lidar", help="the kart's planar LiDAR: its sweeps' rate and health, live or recorded")
    lidar_sub = lidar.add_subparsers(dest="action", required=True, metavar="ACTION")
    monitor = lidar_sub.add_parser("monitor", help="the device's information and health, then its sweeps' rate, gaps "
                                                   "and returns (an RPLIDAR on a serial port, or a recording)")
    where_from = monitor.add_mutually_exclusive_group(required=True)
    where_from.add_argument("--port", type=device, help="live: the serial device (/dev/ttyUSB0) or a pyserial URL")
    where_from.add_argument("--recording", type=input_path, help="a recording's sweeps instead of a live device")
    monitor.add_argument("--baudrate", type=number(int), default=115200, help="live: 115200 (A1, A2), 256000 (A3, S1)")
    monitor.add_argument("--duration", type=number(above=0), help="live: seconds to listen (default: until Ctrl-C)")
    monitor.add_argument("--every", type=number(above=0), default=1.0, help="live: print a line this often, s")
    monitor.add_argument("--json", type=output_file, help="write the last summary here (JSON)")
    monitor.set_defaults(handler=_handler("kartpilot.cli.lidar_commands", "lidar_monitor"))


def _study(sub: argparse._SubParsersAction) -> None:
    """The subcommands whose handlers are in :mod:`kartpilot.cli.study_commands`."""
    study = sub.add_parser("study", help="the thesis's study and sweeps, on Ray: run, report, tune, list")
    actions = study.add_subparsers(dest="action", required=True, metavar="ACTION")
    listing = actions.add_parser("list", help="the built-in studies and their sizes")
    listing.set_defaults(handler=_handler("kartpilot.cli.study_commands", "study_list"))
    run = actions.add_parser("run", help="run a study's cells (cached by their hash), then write its report")
    _common(run)
    run.add_argument("--cache", help="where simulated recordings are kept (default: OUT/cache)")
    run.set_defaults(handler=_handler("kartpilot.cli.study_commands", "study_run"))
    report = actions.add_parser("report", help="a study folder's report: Markdown, CSV and figures")
    report.add_argument("folder", type=input_path)
    report.set_defaults(handler=_handler("kartpilot.cli.study_commands", "study_report"))
    tune = actions.add_parser("tune", help="search a study's tune space with Optuna; report on held-out cells")
    _common(tune)
    tune.add_argument("--trials", type=number(int, minimum=1), help="how many trials (default: the spec's)")
    tune.set_defaults(handler=_handler("kartpilot.cli.study_commands", "study_tune"))


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", type=input_path, help=f"a built-in study ({', '.join(STUDIES)}) or a spec .yaml file")
    parser.add_argument("--out", required=True, type=results_folder,
                        help="the study's folder: rows are cached here, so a rerun computes only new cells")
    parser.add_argument("--quick", action="store_true", help="the study's small size (a few minutes on 2 cores)")
    parser.add_argument("--address", help="an existing Ray cluster (HOST:6379, from `ray start --head`); "
                                          "default: Ray on this machine's cores")
    parser.add_argument("--cpus", type=number(int, minimum=1), help="cores of the local Ray (default: all)")
    parser.add_argument("--data", type=input_path, default="../shared/data", help="the datasets' folder (real sources)")
    parser.add_argument("--no-progress", action="store_true")

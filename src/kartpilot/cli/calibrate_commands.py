"""``kartpilot calibrate mono|stereo``: a rig file from images of a calibration board; ``calibrate ground``: each
camera's pose over the ground from one board lying on the floor; ``calibrate steering``: the kart's steering
calibration into its rig file."""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from kartpilot.actuation.can_bus import open_bus
from kartpilot.actuation.steering_calibration import calibrate_steering, steer_of_turning_circle, sweep_values
from kartpilot.calibration.board import (
    BoardConfig,
    BoardView,
    MonoCalibration,
    board_points,
    calibrate_mono,
    calibrate_stereo,
    detect_board,
    find_board,
    measure_marker,
    pair_names,
    read_views,
    views_from_frames,
)
from kartpilot.calibration.ground import (
    AGREEMENT_WARN_M,
    BirdseyeView,
    MountSpread,
    board_pose,
    calibrate_ground,
    ground_agreement,
    stitch_birdseye,
)
from kartpilot.calibration.lidar import BoardSighting, board_segment_body, fit_lidar_mount
from kartpilot.calibration.rig import Rig, load_rig, save_rig
from kartpilot.core.errors import CalibrationError, ConfigError
from kartpilot.core.files import write_bytes_atomic
from kartpilot.core.geometry import invert_pose, mount_pose
from kartpilot.core.types import Image
from kartpilot.core.vehicle import get_vehicle
from kartpilot.runtime.config import load_stack_config
from kartpilot.sensors.base import read_image

__all__ = ["calibrate", "calibrate_ground_command", "calibrate_steering_command"]


def _board(args: argparse.Namespace) -> BoardConfig:
    try:
        columns, rows = (int(v) for v in args.board.lower().split("x"))
    except ValueError as exc:
        raise ConfigError(f"--board {args.board!r}: expected COLUMNSxROWS, such as 9x6") from exc
    return BoardConfig(kind="charuco" if args.charuco else "chessboard", columns=columns, rows=rows,
                       square_m=args.square, marker_m=args.marker or 0.0, dictionary=args.dictionary)


def _mount(text: str | None) -> np.ndarray:
    if not text:
        return mount_pose()  # at the body's origin, looking forward
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError as exc:
        raise ConfigError(f"--mount {text!r}: expected X,Y,Z[,YAW_DEG,PITCH_DOWN_DEG] in metres") from exc
    if len(values) not in (3, 4, 5):
        raise ConfigError(f"--mount {text!r}: expected 3 to 5 numbers")
    return mount_pose(*values)


def _camera_json(calibration: MonoCalibration) -> dict[str, Any]:
    cam = calibration.camera
    return {"fx": cam.fx_px, "fy": cam.fy_px, "cx": cam.cx_px, "cy": cam.cy_px, "distortion": list(cam.distortion),
            "rms_px": calibration.rms_px, "per_image_rms_px": calibration.per_view_rms_px}


def _print_camera(name: str, calibration: MonoCalibration) -> None:
    cam = calibration.camera
    print(f"{name}: fx {cam.fx_px:.2f} fy {cam.fy_px:.2f} cx {cam.cx_px:.2f} cy {cam.cy_px:.2f} px, distortion "
          f"{', '.join(f'{d:+.4f}' for d in cam.distortion)}, RMS {calibration.rms_px:.3f} px")
    for image, rms in calibration.per_view_rms_px.items():
        print(f"  {image}: {rms:.3f} px")


def _mono_views(args: argparse.Namespace, board: BoardConfig) -> tuple[list[BoardView], list[str], tuple[int, int]]:
    """The board's views from the photos, or from the video's frames where the board has moved."""
    if bool(args.images) == bool(args.video):
        raise ConfigError("give the board's photos or --video, one of the two")
    if not args.video:
        return read_views(args.images, board)
    from kartpilot.record.replay import open_frames

    if Path(args.video).is_dir():
        raise ConfigError(f"--video {args.video} is a folder: give the video file (or the photos as arguments)")
    kind, frame_sets = open_frames(args.video)
    if kind != "video":
        raise ConfigError(f"--video {args.video}: a {kind}, not a video (give photos as arguments)")
    frames = ((f"frame {fs.index}", fs.images["center"]) for fs in frame_sets)
    views, read, size = views_from_frames(frames, board, args.max_views)
    print(f"{args.video}: {read} frames, the board found and moved in {len(views)} kept",
          file=sys.stderr if args.json else sys.stdout)
    return views, [], size


def calibrate(args: argparse.Namespace) -> int:
    board = _board(args)
    if args.mode == "mono":
        views, skipped, size = _mono_views(args, board)
        result = calibrate_mono(views, size)
        rig = Rig({args.name: result.camera.on_body(_mount(args.mount))})
        summary: dict[str, Any] = {"rms_px": result.rms_px, "used": [v.name for v in views], "skipped": skipped,
                                   "cameras": {args.name: _camera_json(result)}}
        if not args.json:
            _print_camera(args.name, result)
    else:
        left_views, left_skipped, size = read_views(args.left, board)
        right_views, right_skipped, right_size = read_views(args.right, board)
        if size != right_size:
            raise ConfigError(f"the left images are {size[0]}x{size[1]}, the right {right_size[0]}x{right_size[1]}")
        pairs = pair_names([Path(p).name for p in args.left], [Path(p).name for p in args.right])
        stereo = calibrate_stereo(left_views, right_views, size, pairs=pairs)
        pose_left = _mount(args.mount)
        pose_right = pose_left @ invert_pose(stereo.pose_right_left)
        rig = Rig({"left": stereo.left.camera.on_body(pose_left),
                   "right": stereo.right.camera.on_body(pose_right)}, ("left", "right"))
        rows = list(stereo.row_error_px.values())
        summary = {"rms_px": stereo.rms_px, "used": list(stereo.pairs), "skipped": left_skipped + right_skipped,
                   "cameras": {"left": _camera_json(stereo.left), "right": _camera_json(stereo.right)},
                   "baseline_m": stereo.baseline_m, "rectified_focal_px": stereo.rectification.rig.camera.fx_px,
                   "rectified_row_error_px": {"median": float(np.median(rows)), "max": float(np.max(rows))}}
        if not args.json:
            _print_camera("left", stereo.left)
            _print_camera("right", stereo.right)
            print(f"stereo: RMS {stereo.rms_px:.3f} px over {len(stereo.pairs)} pairs, baseline "
                  f"{stereo.baseline_m:.4f} m, rectified focal {summary['rectified_focal_px']:.2f} px, "
                  f"rows after rectification differ by {np.median(rows):.3f} px (median; max {np.max(rows):.3f})")
    save_rig(rig, args.out)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        for line in summary["skipped"]:
            print(f"skipped {line}")
        print(f"rig written to {Path(args.out)}")
    return 0


def _write_image(path: str, image: np.ndarray) -> None:
    ok, data = cv2.imencode(Path(path).suffix.lower() or ".png", image)
    if not ok:
        raise ConfigError(f"{path}: cannot write an image of that kind (use .png or .jpg)")
    write_bytes_atomic(path, data.tobytes())


def _named_images(items: list[str]) -> dict[str, Path]:
    named = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise ConfigError(f"--image {item!r}: expected NAME=FILE, such as center=center.jpg")
        if name in named:
            raise ConfigError(f"--image: camera {name!r} given twice")
        named[name] = Path(path)
    return named


def _ground_board(args: argparse.Namespace, images: dict[str, Image]) -> BoardConfig:
    """The board of ``calibrate ground``: as given, or found in the images (layout, dictionary, the markers' side);
    what was found is said (on stderr under ``--json``, whose stdout is the summary alone)."""
    say = partial(print, file=sys.stderr if args.json else sys.stdout)
    if args.board and args.dictionary:
        board = _board(args)
    else:
        search = detect_board(list(images.values()), args.square, args.marker or 0.0)
        board = search.board
        say(f"found {board.describe()}: {search.markers} markers over the images, the layout fitting to "
            f"{search.fit:.3f} of a marker's side" + ("; the markers' side measured against the squares"
                                                      if search.marker_measured else ""))
        if args.board or args.dictionary:
            given = _board(argparse.Namespace(**{**vars(args), "marker": args.marker or board.marker_m,
                                                 "dictionary": args.dictionary or board.dictionary,
                                                 "board": args.board or f"{board.columns}x{board.rows}"}))
            board = replace(given, legacy=board.legacy)
            say(f"using {board.describe()} as given")
        return board
    if args.marker is None:
        measured = measure_marker(list(images.values()), board)
        if measured is not None:
            board = replace(board, marker_m=measured)
            say(f"the markers measure {measured * 1000:.1f} mm against the squares (--marker to give them)")
    return board


def _spread(value: float, sd: float | None, unit: str, digits: int) -> str:
    return f"{value:.{digits}f}" + (f" +- {sd:.{digits}f}" if sd is not None and math.isfinite(sd) else "") + unit


def calibrate_ground_command(args: argparse.Namespace) -> int:
    """Each camera's pose over the ground from one image per camera of one board lying on the floor; the rig
    file with those poses, and the bird's-eye view of all the cameras stitched, each camera's part outlined."""
    images = {name: read_image(path) for name, path in _named_images(args.image).items()}
    board = _ground_board(args, images)
    views, sizes = {}, {}
    for name, image in images.items():
        view = board_points(image, board, name)
        if len(view.ids) < board.min_points:
            raise CalibrationError(f"camera {name!r}: {view.counted()} of {board.describe()} found in its image; "
                                   f"{board.min_points} are needed (is the board in view, and the one given?)")
        views[name], sizes[name] = view, (image.shape[1], image.shape[0])
    base = load_rig(args.rig) if args.rig else None
    known = {n: c for n, c in base.cameras.items() if n in views} if base is not None else {}
    mounts = calibrate_ground(views, sizes, known, args.reference, args.reference_x, resamples=args.resamples)
    agreement = ground_agreement(views, {n: m.camera for n, m in mounts.items()})
    cameras = dict(base.cameras) if base is not None else {}
    for name, mount in mounts.items():
        kept = cameras.get(name)
        cameras[name] = replace(mount.camera, body_mask=kept.body_mask) if kept is not None else mount.camera
    rig = replace(base, cameras=cameras) if base is not None else Rig(cameras)
    summary: dict[str, Any] = {
        "board": {"columns": board.columns, "rows": board.rows, "square_m": board.square_m,
                  "marker_m": board.marker_m, "dictionary": board.dictionary, "legacy": board.legacy},
        "cameras": {name: {"height_m": m.height_m, "pitch_down_deg": m.pitch_down_deg, "roll_deg": m.roll_deg,
                           "yaw_deg": m.yaw_deg, "tilt_from_down_deg": m.tilt_deg,
                           "axis_heading_deg": None if math.isnan(m.heading_deg) else m.heading_deg,
                           "sd": None if m.spread is None else {k: (None if math.isnan(v) else v)
                                                                for k, v in asdict(m.spread).items()},
                           "reprojection_px": m.reprojection_px, "points": m.corners,
                           "chessboard_corners": views[name].corners, "markers": views[name].markers,
                           "fx_px": m.camera.fx_px, "fx_sd_px": m.focal_sd_px,
                           "intrinsics_estimated": m.intrinsics_estimated}
                    for name, m in mounts.items()},
        "agreement": [{"cameras": [a.first, a.second], "points": a.points, "median_m": a.median_m,
                       "max_m": a.max_m} for a in agreement]}
    birdseye = BirdseyeView((0.0, args.ahead), (-args.side, args.side), args.pixels_per_m)
    stitched = stitch_birdseye(images, {n: m.camera for n, m in mounts.items()}, birdseye, outline=True)
    save_rig(rig, args.out)
    if args.birdseye:
        _write_image(args.birdseye, stitched)
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        for name, m in mounts.items():
            sd = m.spread or MountSpread(*[math.nan] * 6)
            source = "estimated from this view" if m.intrinsics_estimated else "the rig's"
            heading = "no heading: straight down" if math.isnan(m.heading_deg) else \
                f"heading {_spread(m.heading_deg, sd.heading_deg, ' deg', 1)}"
            print(f"{name}: height {_spread(m.height_m * 100, sd.height_m * 100, ' cm', 1)}, pitch down "
                  f"{_spread(m.pitch_down_deg, sd.pitch_down_deg, ' deg', 2)}, roll "
                  f"{_spread(m.roll_deg, sd.roll_deg, ' deg', 2)}, yaw "
                  f"{_spread(m.yaw_deg, sd.yaw_deg, ' deg', 2)}")
            print(f"  optical axis {_spread(m.tilt_deg, sd.tilt_deg, ' deg', 2)} from straight down, {heading}; "
                  f"{views[name].counted()}, reprojection {m.reprojection_px:.2f} px; fx "
                  f"{_spread(m.camera.fx_px, m.focal_sd_px if m.intrinsics_estimated else None, ' px', 0)} ({source})")
        for a in agreement:
            warn = "  WARNING: more than " + f"{AGREEMENT_WARN_M * 100:.0f} cm" if a.max_m > AGREEMENT_WARN_M else ""
            print(f"{a.first} and {a.second} agree on {a.points} board points: {a.median_m * 100:.1f} cm apart on the "
                  f"ground (median), {a.max_m * 100:.1f} cm at most{warn}")
    print(f"rig written to {args.out}" + (f", bird's-eye view to {args.birdseye}" if args.birdseye else ""),
          file=sys.stderr if args.json else sys.stdout)
    return 0


def calibrate_steering_command(args: argparse.Namespace) -> int:
    """Sweep the RDW kart's steering, fit the calibration, write it into the rig file."""
    stack = load_stack_config(args.config)
    rig = load_rig(args.rig)  # checked before anything moves
    vehicle = get_vehicle(args.vehicle)
    for name, value, ok, what in (("--max-value", args.max_value, 0 < args.max_value <= 1.25, "in (0, 1.25]"),
                                  ("--settle", args.settle, 0 < args.settle <= 60, "in (0, 60] seconds"),
                                  ("--at-value", args.at_value, 0 < abs(args.at_value) <= 1.25,
                                   "in [-1.25, 1.25], not 0"),
                                  ("--rad-per-value", args.rad_per_value, args.rad_per_value is None or
                                   0 < args.rad_per_value < 2, "in (0, 2)")):
        if not ok or (value is not None and not math.isfinite(value)):
            raise ConfigError(f"{name} {value}: must be {what}")
    if args.rad_per_value is not None:
        rad_per_value = args.rad_per_value
    elif args.turning_circle is not None:
        rad_per_value = steer_of_turning_circle(args.turning_circle, vehicle.wheelbase_m) / abs(args.at_value)
    else:
        raise ConfigError("give the road-wheel angle's scale: --turning-circle DIAMETER_M (measured at full lock, "
                          "--at-value) or --rad-per-value")
    can = replace(stack.can, protocol="rdw", interface=args.bus or stack.can.interface,
                  channel=args.channel or stack.can.channel)
    values = sweep_values(args.max_value, args.steps)
    print(f"sweeping the steering over {len(values)} values from -{args.max_value} to {args.max_value} on "
          f"{can.interface} {can.channel}, {args.settle:g} s each: the kart must be on stands or rolling slowly")
    calibration, r_squared, points = calibrate_steering(open_bus(can), can, rad_per_value, values, args.settle,
                                                        -1 if args.positive_steers == "right" else 1)
    for value, counts in points:
        print(f"  value {value:+.3f}: sensor {counts:+.0f} counts")
    save_rig(replace(rig, steering=calibration), args.rig)
    print(f"steering: {calibration.counts_per_value:+.1f} counts per unit of value, straight at "
          f"{calibration.count_offset:+.1f} counts (R² {r_squared:.4f}); {calibration.rad_per_value:.4f} rad per unit "
          f"of value, {calibration.max_steer_rad:.3f} rad at the ECU's limit; written to {args.rig}")
    return 0


def calibrate_lidar_command(args: argparse.Namespace) -> int:
    """The LiDAR's mount from a recording of the board held upright at a few places: each frame of ``--camera``
    where the board is found, with the sweep nearest its time; the rig file with the mount written to ``--out``."""
    from kartpilot.record.recording import RecordingReader

    rig = load_rig(args.rig)
    if rig.lidar is None:
        raise CalibrationError(f"{args.rig}: no lidar section; give the LiDAR's mount as measured by hand (lidar: "
                               "mount: {x_m, y_m, z_m, yaw_deg}): the fit starts there")
    camera = rig.camera(args.camera)
    reader = RecordingReader(args.recording)
    if not reader.lidars:
        raise CalibrationError(f"{args.recording} holds no LiDAR sweeps")
    name = next(iter(reader.lidars))
    sweeps = reader.scans(name)
    stamps = np.array([s.stamp_ns for s in sweeps], np.int64)
    if not len(stamps):
        raise CalibrationError(f"{args.recording}: the LiDAR {name!r} has no sweeps")
    board = _board(args)
    sightings = []
    for stamp, path in reader.frames(args.camera):
        view = find_board(read_image(path), board, path.name)
        nearest = int(np.argmin(np.abs(stamps - stamp)))
        if view is None or abs(int(stamps[nearest]) - stamp) > args.max_gap * 1e9:
            continue
        board_in_cam, _ = board_pose(view, camera)
        segment = board_segment_body(camera.pose_body_cam_array @ board_in_cam, board, rig.lidar.z_m)
        if segment is not None:
            sightings.append(BoardSighting(path.name, segment, sweeps[nearest].points_m()))
    fit = fit_lidar_mount(sightings, rig.lidar)
    save_rig(replace(rig, lidar=fit.mount), args.out)
    if args.json:
        print(json.dumps({"mount": asdict(fit.mount), "rms_m": fit.rms_m,
                          "places": [{"frame": n, "returns": c, "rms_m": r} for n, c, r in fit.per_place]}))
    else:
        print(f"{len(sightings)} frames with the board, each with its sweep")
        print("\n".join(fit.lines()))
        print(f"rig written to {args.out}")
    return 0

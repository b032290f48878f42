"""``kartpilot calibrate mono|stereo``: a rig file from images of a calibration board; ``calibrate ground``: each
camera's pose over the ground from one board lying on the floor; ``calibrate steering``: the kart's steering
calibration into its rig file."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from kartpilot.actuation.can_bus import open_bus
from kartpilot.actuation.steering_calibration import calibrate_steering, steer_of_turning_circle, sweep_values
from kartpilot.calibration.board import (
    BoardConfig,
    MonoCalibration,
    calibrate_mono,
    calibrate_stereo,
    find_board,
    pair_names,
    read_views,
)
from kartpilot.calibration.ground import BirdseyeView, calibrate_ground, stitch_birdseye
from kartpilot.calibration.rig import Rig, load_rig, save_rig
from kartpilot.core.errors import CalibrationError, ConfigError
from kartpilot.core.files import write_bytes_atomic
from kartpilot.core.geometry import invert_pose, mount_pose
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


def calibrate(args: argparse.Namespace) -> int:
    board = _board(args)
    if args.mode == "mono":
        views, skipped, size = read_views(args.images, board)
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


def calibrate_ground_command(args: argparse.Namespace) -> int:
    """Each camera's pose over the ground from one image per camera of one board lying on the floor; the rig
    file with those poses, and the bird's-eye view of all the cameras stitched."""
    board = _board(args)
    images = {name: read_image(path) for name, path in _named_images(args.image).items()}
    views, sizes = {}, {}
    for name, image in images.items():
        view = find_board(image, board, name)
        if view is None:
            raise CalibrationError(f"camera {name!r}: fewer than {board.min_charuco_corners} of the board's corners "
                                   "found in its image (is it the board given by --board, --square, --dictionary?)")
        views[name], sizes[name] = view, (image.shape[1], image.shape[0])
    base = load_rig(args.rig) if args.rig else None
    known = {n: c for n, c in base.cameras.items() if n in views} if base is not None else {}
    mounts = calibrate_ground(views, sizes, known, args.reference, args.reference_x)
    cameras = dict(base.cameras) if base is not None else {}
    for name, mount in mounts.items():
        kept = cameras.get(name)
        cameras[name] = replace(mount.camera, body_mask=kept.body_mask) if kept is not None else mount.camera
    rig = replace(base, cameras=cameras) if base is not None else Rig(cameras)
    summary = {name: {"height_m": m.height_m, "pitch_down_deg": m.pitch_down_deg, "roll_deg": m.roll_deg,
                      "yaw_deg": m.yaw_deg, "reprojection_px": m.reprojection_px, "corners": m.corners,
                      "fx_px": m.camera.fx_px, "intrinsics_estimated": m.intrinsics_estimated}
               for name, m in mounts.items()}
    birdseye = BirdseyeView((0.0, args.ahead), (-args.side, args.side), args.pixels_per_m)
    stitched = stitch_birdseye(images, {n: m.camera for n, m in mounts.items()}, birdseye)
    save_rig(rig, args.out)
    if args.birdseye:
        _write_image(args.birdseye, stitched)
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        for name, m in mounts.items():
            source = "estimated from this view" if m.intrinsics_estimated else "the rig's"
            print(f"{name}: height {m.height_m:.3f} m, pitch down {m.pitch_down_deg:.2f} deg, roll "
                  f"{m.roll_deg:.2f} deg, yaw {m.yaw_deg:+.2f} deg; {m.corners} corners, reprojection "
                  f"{m.reprojection_px:.2f} px; fx {m.camera.fx_px:.1f} px ({source})")
    print(f"rig written to {args.out}" + (f", bird's-eye view to {args.birdseye}" if args.birdseye else ""))
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

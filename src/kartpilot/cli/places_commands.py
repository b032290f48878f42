"""``kartpilot places build|query``: a place database from a reference drive, and where images were taken."""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

from kartpilot.calibration.lens import undistortion
from kartpilot.core.errors import ConfigError, DataError
from kartpilot.core.files import write_csv_atomic, write_json_atomic
from kartpilot.core.geometry import invert_pose
from kartpilot.core.trajectory import Trajectory, read_trajectory
from kartpilot.core.types import FrameSet, Image
from kartpilot.core.vehicle import VEHICLES, get_vehicle
from kartpilot.eval.places import evaluate_places
from kartpilot.odometry.mono_vo import MonoVO
from kartpilot.odometry.places import PlaceFix, build_places, load_places
from kartpilot.odometry.run import run_vo
from kartpilot.odometry.stereo_vo import StereoVO
from kartpilot.record.recording import POSE_GAP_S, RecordingReader, RecordingStereoSource
from kartpilot.runtime.config import StackConfig, load_stack_config
from kartpilot.sensors.base import read_gray

__all__ = ["places_build", "places_query"]


def _camera(reader: RecordingReader, name: str | None) -> str:
    if name is not None:
        return name
    if "center" in reader.cameras:
        return "center"
    if reader.stereo_pair:
        return reader.stereo_pair[0]
    return next(iter(reader.cameras))


def places_build(args: argparse.Namespace) -> int:
    stack = load_stack_config(args.config)
    config = stack.places
    reader = RecordingReader(args.recording)
    camera = _camera(reader, args.camera)
    if camera not in reader.cameras:
        raise ConfigError(f"the recording has no camera {camera!r} (it has {', '.join(reader.cameras)})")
    poses, source = _positions(reader, camera, args, stack)
    _check_coverage(reader, camera, poses, source)
    start = time.perf_counter()
    database = build_places(reader.posed_frames(camera, poses), reader.cameras[camera], camera, config,
                            {"recording": str(args.recording), "positions": source})
    path = database.save(args.out)
    travelled = Trajectory.from_poses(database.poses_world_cam).path_length_m
    print(f"{len(database)} places over {travelled:.0f} m of the {camera} camera, positions from {source}; "
          f"{config.vlad.words} words, {database.vectors.shape[1]}-dimensional vectors; "
          f"{path.stat().st_size / 1e6:.1f} MB in {time.perf_counter() - start:.0f} s -> {path}")
    return 0


def _check_coverage(reader: RecordingReader, camera: str, poses: Trajectory, source: str) -> None:
    """Every frame needs a pose (as the database is built): a trajectory that covers only part of the drive
    would build a database of part of the track without a word."""
    indices = reader.pose_indices(camera, poses)
    covered = sum(index is not None for index in indices)
    if covered < len(indices) or not indices:
        raise DataError(f"{source} gives a pose for {covered} of the {len(indices)} frames of the {camera} camera "
                        f"(within {POSE_GAP_S * 1e3:g} ms of each frame's time): give one pose per frame, as TUM "
                        "with the frames' times")


def _positions(reader: RecordingReader, camera: str, args: argparse.Namespace, stack: StackConfig
               ) -> tuple[Trajectory, str]:
    """The camera's poses to tag the places with, and where they came from: a given trajectory, the
    recording's ground truth, or visual odometry over the recording itself (a real drive has no ground truth;
    places from VO are in VO's frame, which the mono-vo pipeline follows as it is)."""
    if args.positions:
        return read_trajectory(args.positions), f"--positions {args.positions}"
    wanted = args.positions_from
    truth = reader.camera_poses(camera) if wanted in (None, "truth") else None
    if truth is not None:
        return truth, "the recording's ground truth"
    if wanted is None or wanted == "truth":
        raise DataError(f"{args.recording} has no ground truth to tag its images with: pass --positions with the "
                        f"{camera} camera's trajectory, or --positions-from stereo-vo or mono-vo")
    if wanted == "stereo-vo":
        stereo = RecordingStereoSource(reader.folder)
        run = run_vo(stereo.frame_sets(), StereoVO(stereo.rig, stack.stereo_vo), str(reader.folder))
        # the rectified left camera's poses, moved onto the database's camera by the two mounts
        to_camera = invert_pose(stereo.pose_body_left) @ reader.cameras[camera].pose_body_cam_array
        print(run.summary())
        return Trajectory(run.trajectory.stamps_s, run.trajectory.poses @ to_camera), "stereo VO over the recording"
    calibration = reader.cameras[camera]
    lens = undistortion(calibration)
    pinhole = lens.pinhole if lens is not None else calibration
    height = float(pinhole.pose_body_cam_array[2, 3])
    if height <= 0:
        raise ConfigError(f"monocular VO's scale comes from the {camera!r} camera's height above the road, and "
                          "its mount in the recording does not give one")
    config = replace(stack.mono_vo, ground=replace(stack.mono_vo.ground, camera_height_m=height))

    def frames() -> Iterator[FrameSet | int]:
        for k, (stamp, path) in enumerate(reader.frames(camera)):
            try:
                image = read_gray(path)
            except DataError:
                yield k
                continue
            yield FrameSet(k, stamp, {camera: lens(image) if lens is not None else image})

    vehicle = get_vehicle(reader.vehicle) if reader.vehicle in VEHICLES else None  # its tyres' slip in bends
    mono = run_vo(frames(), MonoVO(pinhole, config, camera, vehicle), str(reader.folder))
    print(mono.summary())
    return mono.trajectory, f"monocular VO over the recording (scale from the {mono.scale_source})"


def places_query(args: argparse.Namespace) -> int:
    database = load_places(args.database)
    target = Path(args.query)
    if target.is_file():
        fix = database.locate(read_gray(target))
        print(_describe(fix))
        return 0
    if not (target / "manifest.json").is_file():
        raise DataError(f"{target} is neither an image nor a recording")
    reader = RecordingReader(target)
    camera = args.camera or database.camera_name
    if camera not in reader.cameras:
        raise ConfigError(f"the recording has no camera {camera!r} (the database is of {database.camera_name!r}; "
                          f"the recording has {', '.join(reader.cameras)})")
    lens = database.lens_for(reader.cameras[camera], camera)  # queried as the database's images were built

    def straight(image: Image) -> Image:
        return lens(image) if lens is not None else image

    truth = reader.camera_poses(camera)
    fixes: list[PlaceFix] = []
    if truth is not None:
        queries = ((stamp, straight(image), pose) for stamp, image, pose in reader.posed_frames(camera, truth))
        recall = evaluate_places(database, queries, args.radius, fixes)
        print(f"{target} against {args.database}, the truth from the recording's ground truth\n{recall.table()}")
        if args.json:
            write_json_atomic(args.json, recall.to_json())
    else:
        for stamp_ns, path in reader.frames(camera):
            fixes.append(database.locate(straight(read_gray(path)), stamp_ns))
        accepted = sum(f.accepted for f in fixes)
        print(f"{len(fixes)} images, {accepted} placed (no ground truth in the recording to score them)")
    if args.out:
        _write_fixes(fixes, Path(args.out))
    return 0


def _describe(fix: PlaceFix) -> str:
    if not fix.accepted:
        return f"no place: {fix.reason}"
    x, y, z = fix.position_m
    road = f", registered on the road (across the track {fix.cross_track_sigma_m:.2f} m)" if fix.registered else ""
    return (f"x {x:.2f} m, y {y:.2f} m, z {z:.2f} m, sigma {fix.sigma_m:.2f} m; best place {fix.place} "
            f"({fix.inliers} inliers){road}")


def _write_fixes(fixes: list[PlaceFix], path: Path) -> None:
    header = ["stamp_ns", "accepted", "x_m", "y_m", "z_m", "sigma_m", "place", "inliers", "registered",
              "cross_track_sigma_m", "heading_sigma_rad", "reason"]
    write_csv_atomic(path, header, ([fix.stamp_ns, int(fix.accepted), *(f"{v:.4f}" for v in fix.position_m),
                                     f"{fix.sigma_m:.4f}", fix.place, fix.inliers, int(fix.registered),
                                     f"{fix.cross_track_sigma_m:.4f}", f"{fix.heading_sigma_rad:.4f}", fix.reason]
                                    for fix in fixes))

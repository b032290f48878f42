"""Visual odometry accuracy on every sequence at hand, real and simulated, each marked tuned-on or held-out.

The defaults were tuned on KITTI 06 (stereo and monocular), the stereo keyframes on utrack seed 1 as well (the
attitude prior, once tuned there, is off since its ablation on the real clips: ``benchmarks/vo_ablation.py``),
and the monocular arc settings on sdc-assen seeds 1 and 2; every other row is held out (utrack seed 2's result
was seen with the attitude prior on and off before its default was set). Simulated drives are recorded once into
``--cache`` (several seeds each):

* utrack, rc-kart stereo: 160 m from the start at 2 m/s, an 74 m straight and 130 degrees of the first bend;
* sdc-assen, sdc-kart centre camera (monocular, the mount's arc with the tyres' slip): 70 s at 4 m/s, about
  280 m with bends (seeds 1 to 3), and 70 s at 6 m/s (seed 4).

kitti-raw-city has no poses: its row compares the distance stereo VO (scale from the baseline) and
monocular VO (scale from the 1.65 m camera height) drive, each scale independent of the other.

    python benchmarks/vo_accuracy.py --data ../shared/data --out docs/results/vo_accuracy.json
    python benchmarks/vo_table.py docs/results/vo_accuracy.json --out docs/results/vo_accuracy.md
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import os
import platform
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common import write_json
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.config import config_to_dict
from kartpilot.core.files import write_text_atomic
from kartpilot.core.trajectory import Trajectory
from kartpilot.core.types import FrameSet
from kartpilot.core.vehicle import VehicleParams, get_vehicle
from kartpilot.eval.trajectory_metrics import evaluate_trajectory
from kartpilot.odometry.mono_vo import GroundConfig, MonoVO, MonoVOConfig
from kartpilot.odometry.run import VORun, run_vo
from kartpilot.odometry.stereo_vo import StereoVO
from kartpilot.odometry.vo import VisualOdometry
from kartpilot.record.recording import RecordingReader, RecordingStereoSource
from kartpilot.record.replay import RecordingFrameSource
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sensors.base import StereoSource
from kartpilot.sensors.euroc import EurocSource
from kartpilot.sensors.kitti import KittiOdometrySource
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.simulator import CameraEffectsConfig, SimConfig, perfect_camera


@dataclass(frozen=True)
class Sequence:
    """One row: a name, where it comes from, which VO, and whether the defaults were tuned on it."""

    name: str
    kind: str  # "real" or "simulated"
    mode: str  # "stereo" or "mono"
    tuned_on: bool
    note: str


def _length_m(trajectory: Trajectory) -> float:
    return float(np.linalg.norm(np.diff(trajectory.positions, axis=0), axis=1).sum())


def _row(sequence: Sequence, run: VORun, truth: Trajectory | None) -> dict[str, Any]:
    row: dict[str, Any] = {**sequence.__dict__, "frames": len(run.trajectory), "bridged_frames": run.bridged_frames,
                           "frames_per_second": run.frames_per_second, "distance_m": _length_m(run.trajectory)}
    if truth is not None:
        metrics = evaluate_trajectory(truth, run.trajectory)
        row.update(true_distance_m=metrics.path_length_m, end_drift_percent=metrics.end_drift_percent,
                   ate_rmse_m=metrics.ate_rmse_m, end_rotation_deg=metrics.end_rotation_deg,
                   end_rotation_deg_per_m=metrics.end_rotation_deg_per_m,
                   rpe_percent={f"{r.delta_m:g}m": r.translation_percent for r in metrics.rpe},
                   rpe_rotation_deg_per_m={f"{r.delta_m:g}m": r.rotation_deg_per_m for r in metrics.rpe})
    print(f"{sequence.name:34s} {sequence.mode:6s} {'tuned on' if sequence.tuned_on else 'held out':9s} "
          + (f"drift {row['end_drift_percent']:6.2f} %  rotation {row['end_rotation_deg']:5.2f} deg  "
             f"ATE {row['ate_rmse_m']:.3f} m  " if truth is not None else "")
          + f"{row['distance_m']:.1f} m, {run.bridged_frames} bridged, {run.frames_per_second:.1f} frames/s")
    return row


def _stereo(source: StereoSource) -> VORun:
    return run_vo(source.frame_sets(), StereoVO(source.rig), source.name)


def _mono(frames: Iterator[FrameSet | int], camera: PinholeCamera, camera_name: str, height_m: float,
          name: str, vehicle: VehicleParams | None = None) -> VORun:
    vo: VisualOdometry = MonoVO(camera, MonoVOConfig(ground=GroundConfig(camera_height_m=height_m)), camera_name,
                                vehicle)
    return run_vo(frames, vo, name)


ROOT = Path(__file__).resolve().parents[1]
SIMULATOR_SOURCES = ("src/kartpilot/sim", "src/kartpilot/core/vehicle.py", "src/kartpilot/core/camera.py")
"""What draws a simulated recording: a cached one is reused only while none of it has changed."""


def simulator_hash() -> str:
    """A hash of every file under :data:`SIMULATOR_SOURCES` (its path and contents; not bytecode)."""
    digest = hashlib.sha256()
    for source in SIMULATOR_SOURCES:
        path = ROOT / source
        for file in sorted(path.rglob("*") if path.is_dir() else [path]):
            if file.is_file() and "__pycache__" not in file.parts:
                digest.update(str(file.relative_to(ROOT)).encode() + b"\0" + file.read_bytes())
    return digest.hexdigest()[:16]


def record_once(folder: Path, config: SimConfig, speed_mps: float) -> Path:
    """Record a centre-line drive once (kept in the cache for later runs; ``benchmarks/honest_camera.py`` and
    ``benchmarks/camera_ablation.py`` share the cache). A cached recording drawn by another simulator (a changed
    renderer, texture, track or camera: :func:`simulator_hash`, kept beside it) is refused, not reused: a table
    once took two of its rows from recordings an earlier renderer drew."""
    drawn_by = folder.with_name(folder.name + ".simulator")
    if not (folder / "manifest.json").is_file():
        print(f"recording {folder.name} ...")
        run_simulation(config, "centerline", driver_config=CenterlineDriverConfig(speed_mps=speed_mps),
                       outputs=SessionOutputs(record_dir=folder))
        write_text_atomic(drawn_by, simulator_hash() + "\n")
        return folder
    if not drawn_by.is_file() or drawn_by.read_text().strip() != simulator_hash():
        raise SystemExit(f"{folder} was drawn by another simulator than this checkout's (or one that did not say): "
                         "delete it to record it again")
    held = RecordingReader(folder).manifest.get("metadata", {}).get("sim", {})
    wanted = json.loads(json.dumps(config_to_dict(config)))
    effects = held.get("effects", {})  # a recording older than a field holds that field's default then
    if any(wanted["effects"][k] != v for k, v in effects.items() if k in wanted["effects"]) or \
            held.get("seed") != wanted["seed"]:
        raise SystemExit(f"{folder} was recorded through another camera or seed than asked: delete it to record "
                         "it again")
    return folder


def real_rows(data: Path) -> list[dict[str, Any]]:
    rows = []
    kitti = data / "kitti-odometry"
    if kitti.is_dir():
        source = KittiOdometrySource(kitti, "06")
        truth = source.ground_truth()
        tuning = Sequence("KITTI 06 (51 frames, straight)", "real", "stereo", True, "the defaults' tuning clip")
        rows.append(_row(tuning, _stereo(source), truth))
        rows.append(_row(Sequence("KITTI 06 (51 frames, straight)", "real", "mono", True, "camera 1.65 m"),
                         _mono(source.frame_sets(), source.rig.camera, "left", 1.65, source.name), truth))
    city = data / "kitti-raw-city"
    if city.is_dir():
        source = KittiOdometrySource(city, "91")
        stereo = _row(Sequence("kitti-raw-city (100 frames, no poses)", "real", "stereo", False, "scale: baseline"),
                      _stereo(source), None)
        mono = _row(Sequence("kitti-raw-city (100 frames, no poses)", "real", "mono", False, "scale: camera 1.65 m"),
                    _mono(source.frame_sets(), source.rig.camera, "left", 1.65, source.name), None)
        stereo["stereo_over_mono_distance"] = mono["stereo_over_mono_distance"] = (
            stereo["distance_m"] / mono["distance_m"])
        rows += [stereo, mono]
    moving = data / "euroc-mh01-moving"
    if moving.is_dir():
        hand_held = EurocSource(moving)
        rows.append(_row(Sequence("EuRoC MH_01 (110 frames, hand-held)", "real", "stereo", False,
                                  "a rig carried over a pallet, 0.5 to 1 m away; no mount, no attitude prior"),
                         _stereo(hand_held), hand_held.ground_truth()))
    euroc = data / "euroc-v101-static"
    if euroc.is_dir():
        run = _stereo(EurocSource(euroc))
        row = _row(Sequence("EuRoC V1_01 (95 frames, standing)", "real", "stereo", False,
                            "largest distance from the start"), run, None)
        row["excursion_m"] = float(np.linalg.norm(run.trajectory.positions, axis=1).max())
        rows.append(row)
    return rows


def simulated_camera(kind: str) -> tuple[CameraEffectsConfig, str]:
    """The ``real`` camera (the kart presets' default) or the ``perfect`` one, and the suffix of its recordings'
    names in the cache (the perfect camera's were the cache's first, and have none)."""
    return (CameraEffectsConfig(), "-real") if kind == "real" else (perfect_camera(), "")


def simulated_rows(cache: Path, seeds: list[int], quick: bool, kind: str = "real") -> list[dict[str, Any]]:
    """The simulated drives through the kart presets' ``real`` camera (the default) or the ``perfect`` one."""
    rows = []
    utrack_s = 40.0 if quick else 80.0
    effects, suffix = simulated_camera(kind)
    for seed in seeds:
        folder = record_once(cache / f"utrack-rc-stereo-{utrack_s:g}s-{seed}{suffix}",
                           SimConfig(track="utrack", vehicle="rc-kart", cameras=("left", "right"), camera_rate_hz=10.0,
                                     max_time_s=utrack_s, seed=seed, effects=effects), 2.0)
        source = RecordingStereoSource(folder)
        note = "rc-kart, 14 cm baseline" + ("; seen while setting the attitude prior (now off)" if seed == 2 else "")
        rows.append(_row(Sequence(f"utrack, seed {seed} ({2 * utrack_s:.0f} m, straight and bend)", "simulated",
                                  "stereo", seed == 1, note), _stereo(source), source.ground_truth()))
    assen_s = 35.0 if quick else 70.0
    # seeds 1 and 2 at 4 m/s: the arc's settings were tuned there; seed 3 at 4 m/s and seed 4 at 6 m/s are held out
    for seed, speed in ((1, 4.0), (2, 4.0), (3, 4.0), (4, 6.0)):
        if seed not in seeds:
            continue
        name = f"assen-sdc-centre-{assen_s:g}s-{seed}" + ("" if speed == 4.0 else f"-{speed:g}mps") + suffix
        folder = record_once(cache / name, SimConfig(track="sdc-assen", vehicle="sdc-kart", cameras=("center",),
                                                    camera_rate_hz=10.0, max_time_s=assen_s, seed=seed,
                                                    effects=effects), speed)
        reader = RecordingReader(folder)
        camera = reader.cameras["center"]
        truth = reader.camera_poses("center")
        height = float(camera.pose_body_cam_array[2, 3])
        rows.append(_row(Sequence(f"sdc-assen, seed {seed} ({speed * assen_s:.0f} m at {speed:g} m/s, bends)",
                                  "simulated", "mono", seed <= 2, f"sdc-kart centre camera, {height:g} m"),
                         _mono(iter(RecordingFrameSource(folder, ["center"]).read, None), camera, "center", height,
                               folder.name, get_vehicle("sdc-kart")), truth))
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--cache", default="benchmarks/results/recordings", help="simulated recordings, kept")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--quick", action="store_true", help="half-length simulated drives")
    parser.add_argument("--camera", choices=("real", "perfect"), default="real",
                        help="the simulated drives' camera (the kart presets' real one is the default)")
    parser.add_argument("--out", default="docs/results/vo_accuracy.json")
    args = parser.parse_args()
    rows = real_rows(Path(args.data)) + simulated_rows(Path(args.cache), args.seeds, args.quick, args.camera)
    write_json(args.out, {
        "date": datetime.date.today().isoformat(),
        "configuration": "defaults",
        "simulated_camera": args.camera,
        "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                    "python": platform.python_version(), "opencv": cv2.__version__},
        "rows": rows,
    })
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The jobs a study's cells run: each takes one cell and returns one row of metrics.

A job is pure in its cell (the job, its parameters, the source, the seed and the stack configuration):
the same cell gives the same row, which is what lets a study cache rows by the cell's hash.

**Isolation of the simulator.** Panda3D keeps state between renderers in one process and a rendering run
holds a few hundred MB. A job that renders runs the simulator in a short-lived child process of its own
(``spawn``, one per recording or drive), not in the Ray worker: the worker stays small and reusable for
the cheap cells (VO over a recording, dynamics-only drives), every renderer starts from a clean process,
its memory goes back to the system when the child exits, and a renderer that crashes becomes that cell's
recorded error instead of taking the worker down. Recordings are cached on each machine by the hash of
the simulator's configuration and shared by every cell that replays them (a file lock stops two workers
recording the same drive at once).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import io
import itertools
import json
import math
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any, TypeVar

import cv2
import numpy as np

from kartpilot.control.path_follow import PathFollowState, path_follow_step
from kartpilot.core.config import config_to_dict, merge_config
from kartpilot.core.errors import ConfigError, DataError
from kartpilot.core.trajectory import Trajectory
from kartpilot.core.types import ActuatorCommand, FrameSet, VehiclePose
from kartpilot.core.vehicle import get_vehicle
from kartpilot.eval.trajectory_metrics import evaluate_trajectory
from kartpilot.odometry.run import VORun, run_vo
from kartpilot.odometry.stereo_vo import StereoVO, VODiagnostics
from kartpilot.odometry.two_view import rotation_angle_deg, two_view_motion
from kartpilot.planning.reference_path import advance_progress, build_reference_path, lateral_offset
from kartpilot.record.recording import RecordingStereoSource
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.experiment import TeachRepeatConfig, run_teach_repeat
from kartpilot.runtime.lane_policy import LanePolicy
from kartpilot.runtime.loop import run_loop
from kartpilot.runtime.scenarios import run_scenario
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sensors.base import StereoSource
from kartpilot.sensors.kitti import KittiOdometrySource
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.scenarios import Scenario, scenario, scenario_text
from kartpilot.sim.simulator import SimConfig, Simulator
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource
from kartpilot.sim.variation import DayRanges, vary
from kartpilot.study.spec import REAL_SOURCES, Cell, JobParams, code_version, params_of, stack_of

__all__ = ["DEPTH_EDGES_M", "GRID_COLS", "GRID_ROWS", "JOBS", "Job", "JobContext", "lane_drive", "run_cell",
           "scenario_event", "wobbled"]

GRID_ROWS, GRID_COLS = 4, 6
"""The image grid the final points are counted over (the thesis's bar graphs, its Fig. 11 and 12)."""

DEPTH_EDGES_M = tuple(float(d) for d in (1, 2, 3, 4, 5, 7.5, 10, 15, 20, 30, 45))
"""The depth histogram's bins over the thesis's 1 to 45 m range, finer where the near points are."""

T = TypeVar("T")


@dataclass(frozen=True)
class JobContext:
    """Where a job finds its inputs on the machine it runs on: the shared datasets, and a folder for
    recordings it may make (kept between studies; the same path on every machine of a cluster)."""

    data_dir: Path
    cache_dir: Path


@dataclass(frozen=True)
class Job:
    run: Callable[[Cell, JobContext], dict[str, Any]]
    description: str


def _in_child(function: Callable[..., T], *args: Any) -> T:
    """Run ``function(*args)`` in a fresh process (see the module's note on isolation)."""
    with ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn")) as pool:
        return pool.submit(function, *args).result()


def _record(config: SimConfig, speed_mps: float, folder: Path) -> None:
    cv2.setNumThreads(1)
    run_simulation(config, "centerline", driver_config=CenterlineDriverConfig(speed_mps=speed_mps),
                   outputs=SessionOutputs(record_dir=folder))


def recorded_drive(config: SimConfig, speed_mps: float, cache_dir: Path) -> Path:
    """A centre-line drive recorded with ``config``: from the cache, or recorded once in a child process (the
    code's version is part of the key: a changed simulator records again)."""
    blob = json.dumps({"sim": config_to_dict(config), "speed_mps": speed_mps, "code": code_version()},
                      sort_keys=True, default=str)
    folder = cache_dir / "recordings" / hashlib.sha256(blob.encode()).hexdigest()[:16]
    folder.parent.mkdir(parents=True, exist_ok=True)
    with open(folder.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # a second worker waits for the first's recording
        if not (folder / "manifest.json").is_file():
            partial = folder.with_name(folder.name + ".partial")
            shutil.rmtree(partial, ignore_errors=True)
            _in_child(_record, config, speed_mps, partial)
            shutil.rmtree(folder, ignore_errors=True)
            partial.rename(folder)
    return folder


def _sim_config(stack: StackConfig, cell: Cell, params: JobParams, cameras: tuple[str, ...]) -> SimConfig:
    return replace(stack.sim, track=cell.source, seed=cell.seed, vehicle=params.vehicle, cameras=cameras,
                   camera_rate_hz=params.camera_rate_hz, max_time_s=params.seconds)


def _stereo_source(cell: Cell, stack: StackConfig, params: JobParams, context: JobContext) -> StereoSource:
    if cell.source == "kitti-06":
        return KittiOdometrySource(context.data_dir / "kitti-odometry", "06")
    if cell.source == "kitti-raw-city":
        return KittiOdometrySource(context.data_dir / "kitti-raw-city", "91")
    if cell.source == "synthetic":  # the textured road of ``sim.synthetic_stereo``: no renderer, exact truth
        return SyntheticStereoSource(SyntheticStereoConfig(frames=params.frames or 40, speed_mps=params.speed_mps,
                                                           rate_hz=params.camera_rate_hz, seed=cell.seed))
    pair = get_vehicle(params.vehicle).stereo_pair
    if pair is None:
        raise DataError(f"vehicle {params.vehicle} has no stereo pair")
    return RecordingStereoSource(recorded_drive(_sim_config(stack, cell, params, pair), params.speed_mps,
                                                context.cache_dir))


def _frames(source: StereoSource, limit: int) -> Iterator[FrameSet | int]:
    frames: Iterator[FrameSet | int] = iter(source.frame_sets())
    return itertools.islice(frames, limit) if limit > 0 else frames


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values)) if values else math.nan


def point_distribution(diagnostics: list[VODiagnostics], size_wh: tuple[int, int], near_m: float
                       ) -> dict[str, Any]:
    """Where the final points (PnP inliers) fall: counts over the image grid, a depth histogram over
    ``DEPTH_EDGES_M`` and the share nearer than ``near_m``, summed over the run."""
    width, height = size_wh
    pixels = np.concatenate([d.inlier_pixels.reshape(-1, 2) for d in diagnostics]) if diagnostics else \
        np.zeros((0, 2))
    depths = np.concatenate([d.inlier_depths_m.ravel() for d in diagnostics]) if diagnostics else np.zeros(0)
    grid, _, _ = np.histogram2d(pixels[:, 1], pixels[:, 0], bins=(GRID_ROWS, GRID_COLS),
                                range=((0, height), (0, width)))
    histogram, _ = np.histogram(depths, bins=DEPTH_EDGES_M)
    return {"final_points": len(depths), "grid_counts": grid.astype(int).tolist(),
            "depth_counts": histogram.astype(int).tolist(),
            "near_share": float(np.mean(depths < near_m)) if len(depths) else math.nan,
            "median_depth_m": float(np.median(depths)) if len(depths) else math.nan}


def trajectory_row(run: VORun, truth: Trajectory | None) -> dict[str, Any]:
    row: dict[str, Any] = {"frames": len(run.trajectory), "bridged_frames": run.bridged_frames,
                           "lost": any(e.status == "lost" for e in run.estimates),
                           "distance_m": run.trajectory.path_length_m,
                           "ms_per_frame": 1000.0 / run.frames_per_second if run.frames_per_second > 0 else math.nan}
    if truth is not None:
        metrics = evaluate_trajectory(truth, run.trajectory, rpe_deltas_m=(1.0,))
        rpe = metrics.rpe[0]
        row.update(true_distance_m=metrics.path_length_m, drift_percent=metrics.end_drift_percent,
                   ate_m=metrics.ate_rmse_m, rpe_translation_percent=rpe.translation_percent,
                   rpe_rotation_deg_per_m=rpe.rotation_deg_per_m, end_rotation_deg=metrics.end_rotation_deg,
                   end_rotation_deg_per_m=metrics.end_rotation_deg_per_m)
    return row


def stereo_vo_job(cell: Cell, context: JobContext) -> dict[str, Any]:
    """Stereo VO over a simulated recording or a real dataset: accuracy, what each filter kept, and where
    the final points are."""
    stack, params = stack_of(cell), params_of(cell)
    source = _stereo_source(cell, stack, params, context)
    run = run_vo(_frames(source, params.frames), StereoVO(source.rig, stack.stereo_vo), source.name)
    diagnostics = [d for e in run.estimates if isinstance(d := getattr(e, "diagnostics", None), VODiagnostics)]
    row = trajectory_row(run, source.ground_truth())
    for stage in ("left_features", "stereo_matches", "epipolar_ok", "depth_ok", "temporal_matches", "inliers"):
        row[f"mean_{stage}"] = _mean([getattr(d, stage) for d in diagnostics])
    camera = source.rig.camera
    return row | point_distribution(diagnostics, (camera.width_px, camera.height_px), params.near_m)


def two_view_job(cell: Cell, context: JobContext) -> dict[str, Any]:
    """The monocular front end on consecutive left images with known motion: matches, inliers, the rotation's
    and the translation direction's error, and the drift when each step is given its true length (so the
    scale, which the thesis could not recover, does not hide the front end's errors)."""
    stack, params = stack_of(cell), params_of(cell)
    source = _stereo_source(cell, stack, params, context)
    truth = source.ground_truth()
    if truth is None:
        raise DataError(f"{cell.source} has no ground truth for the two-view job")
    vo = stack.stereo_vo
    count = min(len(source), params.frames) if params.frames > 0 else len(source)
    images = [source.frame(i).left for i in range(count)]
    poses = truth.poses[: len(images)]
    estimate = [poses[0]]
    matches, inliers, rotation_errors, direction_errors, seconds = [], [], [], [], []
    for i in range(1, len(images)):
        start = time.perf_counter()
        motion = two_view_motion(images[i - 1], images[i], source.rig.camera.matrix, vo.features, vo.matching,
                                 vo.temporal, vo.klt, stack.mono_vo.ransac_px)
        seconds.append(time.perf_counter() - start)
        true_step = np.linalg.inv(poses[i - 1]) @ poses[i]  # camera i in camera i-1
        step = true_step.copy()
        matches.append(motion.matches)
        inliers.append(motion.inliers)
        if motion.rotation is not None and motion.direction is not None:
            # recoverPose gives x_b = R x_a + t: camera b in camera a is (R^T, -R^T t)
            rotation = motion.rotation.T
            direction = -motion.rotation.T @ motion.direction
            true_direction = true_step[:3, 3] / max(np.linalg.norm(true_step[:3, 3]), 1e-9)
            rotation_errors.append(rotation_angle_deg(rotation.T @ true_step[:3, :3]))
            direction_errors.append(math.degrees(math.acos(float(np.clip(direction @ true_direction, -1, 1)))))
            step[:3, :3] = rotation
            step[:3, 3] = direction * np.linalg.norm(true_step[:3, 3])
        estimate.append(estimate[-1] @ step)
    run_truth = Trajectory(truth.stamps_s[: len(images)], np.array(poses))
    metrics = evaluate_trajectory(run_truth, Trajectory(run_truth.stamps_s, np.array(estimate)), (1.0,))
    return {"frames": len(images), "mean_matches": _mean(matches), "mean_inliers": _mean(inliers),
            "failed_pairs": len(images) - 1 - len(rotation_errors),
            "rotation_error_deg": _mean(rotation_errors), "direction_error_deg": _mean(direction_errors),
            "drift_percent": metrics.end_drift_percent, "end_rotation_deg": metrics.end_rotation_deg,
            "ms_per_frame": 1000.0 * _mean(seconds)}


def lane_drive(stack: StackConfig, config: SimConfig) -> dict[str, Any]:
    """The lane follower closed loop in the simulator: touches, distance, centre offset and steer rate."""
    cv2.setNumThreads(1)
    steers: list[float] = []
    with Simulator(config) as sim:
        policy = LanePolicy(sim.cameras, stack.lane_policy, config.camera_rate_hz)

        def step(frames: FrameSet) -> ActuatorCommand:
            command = policy(frames)
            steers.append(command.steer_rad)
            return command

        run_loop(sim, step, sim)
        result = sim.result(1.0)
    rate = np.diff(steers) * config.camera_rate_hz
    return {"touched": result.disqualified, "reason": result.reason, "distance_m": result.distance_m,
            "sim_time_s": result.sim_time_s, "finished": result.finished, "lap_time_s": result.lap_time_s,
            "mean_center_offset_m": result.mean_center_offset_m,
            "max_center_offset_m": result.max_center_offset_m,
            "steer_rate_rms_radps": float(np.sqrt(np.mean(rate**2))) if len(rate) else 0.0}


def lanes_job(cell: Cell, context: JobContext) -> dict[str, Any]:
    """The lane follower closed loop in the simulator (the sdc-kart's three cameras; ``sim.speed_mode_mps``
    is the speed mode): touches, centre offset, steer rate."""
    stack, params = stack_of(cell), params_of(cell)
    return _in_child(lane_drive, stack, _sim_config(stack, cell, params, ()))


def wobbled(xy: np.ndarray, normals: np.ndarray, sigma_m: float, spacing_m: float, rng: np.random.Generator
            ) -> np.ndarray:
    """``xy`` moved along its unit ``normals`` by a smooth random offset (a value of standard deviation
    ``sigma_m`` every ``spacing_m``, linear in between): the error of a reference taught with visual odometry."""
    if sigma_m <= 0:
        return xy
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    knots = np.arange(0.0, s[-1] + spacing_m, spacing_m)
    return xy + np.interp(s, knots, rng.normal(0.0, sigma_m, len(knots)))[:, None] * normals


def path_follow_job(cell: Cell, context: JobContext) -> dict[str, Any]:
    """The path follower on the track's centre line (no cameras, dynamics only), with the errors of
    ``params``: a reference off the centre line by a smooth random offset, and the true pose with noise and
    latency, as visual odometry gives them. How the controller alone tracks the true centre line as its
    gains, look-ahead and speed (``drive.path.cruise_speed_mps``) change."""
    stack, params = stack_of(cell), params_of(cell)
    config = replace(_sim_config(stack, cell, params, ()), render_images=False)
    follow = stack.drive.follow
    rng = np.random.default_rng(cell.seed)
    with Simulator(config) as sim:
        route, start = sim.track.route, sim.track.start_index
        xy = np.roll(route.xy_m, -start, axis=0)
        truth = build_reference_path(xy, stack.drive.path)
        path = build_reference_path(wobbled(xy, np.roll(route.normal(), -start, axis=0), params.path_noise_m, 1.0,
                                            rng), stack.drive.path)
        state = PathFollowState.start(follow)
        cross, steers, done, late, index = [], [], False, [], 0
        while not sim.done and not done:
            s = sim.state
            noise = rng.normal(0.0, 1.0, 3) * (params.pose_noise_m, params.pose_noise_m,
                                               math.radians(params.heading_noise_deg))
            late.append(VehiclePose(sim.time_ns, s.x_m + noise[0], s.y_m + noise[1], s.yaw_rad + noise[2],
                                    s.vx_mps, s.yaw_rate_radps, "ok"))
            pose = late[max(0, len(late) - 1 - params.pose_latency_frames)]
            out, state = path_follow_step(follow, state, path, pose, sim.dt_s, sim.vehicle.wheelbase_m,
                                          sim.vehicle.max_steer_rad)
            done = out.done
            index = advance_progress(truth, s.x_m, s.y_m, index, 2.0)
            cross.append(lateral_offset(truth, index, s.x_m, s.y_m)[1])
            steers.append(out.steer_rad)
            sim.send(ActuatorCommand(sim.time_ns, out.steer_rad, out.throttle, out.brake))
        result = sim.result(1.0)
    cross_arr, rate = np.array(cross), np.diff(steers) / sim.dt_s
    signs = np.sign(cross_arr[np.abs(cross_arr) > 0.02])
    distance = max(result.distance_m, 1e-9)
    return {"success": not result.disqualified and (done or result.finished), "reason": result.reason,
            "distance_m": result.distance_m, "time_s": result.sim_time_s,
            "max_offset_m": float(np.max(np.abs(cross_arr))) if len(cross_arr) else math.nan,
            "rms_offset_m": float(np.sqrt(np.mean(cross_arr**2))) if len(cross_arr) else math.nan,
            "steer_rate_rms_radps": float(np.sqrt(np.mean(rate**2))) if len(rate) else 0.0,
            "oscillations_per_100m": 100.0 * float(np.count_nonzero(np.diff(signs) != 0)) / 2 / distance}


def _teach_repeat(config: TeachRepeatConfig, folder: Path) -> dict[str, Any]:
    cv2.setNumThreads(1)
    with contextlib.redirect_stdout(io.StringIO()):
        return run_teach_repeat(config, folder, video=False, keep_teach=False)  # a cell keeps its result only


def teach_repeat_job(cell: Cell, context: JobContext) -> dict[str, Any]:
    """The thesis's autonomous run, closed loop: teach by driving the track, build the reference with stereo VO,
    repeat with the stereo-VO pipeline (``runtime.experiment``). Success: no disqualification, and the end
    point within the thesis's 1.5 m of the taught one."""
    stack, params = stack_of(cell), params_of(cell)
    config = TeachRepeatConfig(track=cell.source, speed_mps=params.speed_mps, seed=cell.seed,
                               camera_rate_hz=params.camera_rate_hz, drive=stack.drive, vo=stack.stereo_vo)
    with tempfile.TemporaryDirectory() as folder:
        result = _in_child(_teach_repeat, config, Path(folder))
    end = math.hypot(float(result["end_error_along_m"]), float(result["end_error_across_m"]))
    return {"success": not result["disqualified"] and end <= float(result["thesis_end_error_m"]),
            "touched": bool(result["disqualified"]), "reason": result["reason"], "end_error_m": end,
            "distance_m": result["distance_m"],
            "max_distance_from_taught_path_m": result["max_distance_from_taught_path_m"],
            "steer_rate_rms_radps": result["steer_rate_rms_radps"]}


def _scenario_event(plan: Scenario, stack: StackConfig) -> dict[str, Any]:
    cv2.setNumThreads(1)
    return run_scenario(plan, None, stack)


def scenario_event(name: str, seed: int, ranges: DayRanges) -> Scenario:
    """The event a sweep's cell drives: the built-in scenario ``name`` on ``seed``, varied as the day of ``seed``
    sets it."""
    return vary(scenario(name, seed), seed, ranges)


def scenario_job(cell: Cell, context: JobContext) -> dict[str, Any]:
    """One event of a scenario sweep (``params``: ``scenario``, ``variation``): the built-in scenario on the cell's
    seed, varied by :func:`kartpilot.sim.variation.vary`, driven closed loop in a child process; its verdict,
    faults, the rules' states and the event as the file that reproduces it."""
    if "scenario" not in cell.params:
        raise ConfigError("a scenario cell needs params.scenario: kartpilot.study.sweep makes such cells")
    ranges = merge_config(DayRanges(), cell.params.get("variation", {}), "variation")
    plan = scenario_event(str(cell.params["scenario"]), cell.seed, ranges)
    result = _in_child(_scenario_event, plan, stack_of(cell))
    text = scenario_text(plan)
    return {"scenario": plan.name, "passed": bool(result["passed"]), "faults": list(result["faults"]),
            "states": result.get("states", []), "scenario_file": text,
            "pitch_off_deg": result.get("pitch_off_deg", 0.0), "mount_pitch_deg": plan.effects.mount_pitch_deg,
            "kinds": plan.kinds,
            "sunny": plan.render.sky == "clear", "duration_s": plan.duration_s}


JOBS: dict[str, Job] = {
    "stereo_vo": Job(stereo_vo_job, "stereo VO over a simulated recording or a real dataset"),
    "two_view": Job(two_view_job, "the monocular front end (features, matching, essential matrix) per frame pair"),
    "lanes": Job(lanes_job, "the lane follower closed loop in the simulator"),
    "path_follow": Job(path_follow_job, "the path follower on the centre line with the true pose"),
    "teach_repeat": Job(teach_repeat_job, "teach, reference from stereo VO, repeat closed loop (the thesis's run)"),
    "scenario": Job(scenario_job, "one event of a scenario sweep: a built-in scenario varied as the day may"),
}


def run_cell(cell: Cell, context: JobContext) -> dict[str, Any]:
    """One cell's row: its labels, then the job's metrics (or ``status: failed`` and the error)."""
    cv2.setNumThreads(1)  # one core per cell: the study's parallelism is its cells
    start = time.perf_counter()
    row: dict[str, Any] = cell.labels()
    try:
        if cell.source in REAL_SOURCES and not (context.data_dir).is_dir():
            raise DataError(f"the data folder {context.data_dir} is missing")
        row.update(JOBS[cell.job].run(cell, context))
        row["status"] = "ok"
        row["error"] = ""
    except Exception as exc:  # a failing cell is a row with its error, never the end of the study
        row["status"] = "failed"
        row["error"] = f"{type(exc).__name__}: {exc}"[:500]
    row["cell_seconds"] = time.perf_counter() - start
    row["worker_code_version"] = code_version()
    return row

"""The thesis's autonomous-run experiment in one call, in the simulator.

1. **Teach**: the ``centerline`` driver drives the track once (the thesis's manual drive),
   recorded unless asked not to.
2. **Reference**: stereo VO runs over the teach drive's stereo pairs as they are drawn; its
   trajectory becomes the reference path (resampled, smoothed, with a speed profile), saved as CSV.
3. **Repeat**: the kart starts again from the same place and follows the reference
   with the live stereo-VO pipeline and the path follower, until it stops at the end.
4. **Score**: the referee's verdict, the end point against the teach drive's end point
   (along and across the track, the thesis's 1.5 m), the distance between the two
   true paths, and plots of path versus reference and steering over time.

The kart's drag to one side and the track's cross-slope are switched on in both drives.
"""

from __future__ import annotations

import logging
import math
import queue
import shutil
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.spatial import cKDTree

from kartpilot.control.path_follow import BiasConfig, PathFollowConfig, steer_bias_of_drive
from kartpilot.control.stanley import StanleyConfig
from kartpilot.core.camera import StereoRig
from kartpilot.core.errors import ConfigError
from kartpilot.core.files import write_json_atomic
from kartpilot.core.geometry import Array, ground_poses
from kartpilot.core.types import ActuatorCommand, FrameSet
from kartpilot.core.vehicle import VehicleParams, get_vehicle
from kartpilot.eval.plots import plot_path_following, plot_steering
from kartpilot.odometry.run import VORun, teach_over
from kartpilot.odometry.stereo_vo import StereoVOConfig
from kartpilot.odometry.visual_map import MapConfig, VisualMap, map_path_for
from kartpilot.planning.reference_path import PathConfig, ReferencePath, build_reference_path, save_reference_path
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.loop import Outputs
from kartpilot.runtime.path_policy import DriveConfig
from kartpilot.runtime.pipelines import Route
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import SimRun, run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.simulator import CameraEffectsConfig, DisturbanceConfig, SimConfig

__all__ = ["TeachRepeatConfig", "end_errors", "path_distance", "plain_stanley_drive_config", "run_teach_repeat",
           "summary_line"]

log = logging.getLogger(__name__)

THESIS_END_ERROR_M = 1.5


@dataclass(frozen=True)
class TeachRepeatConfig:
    """Attributes:
        track, speed_mps, seed: the experiment (the thesis: a 20 m straight at 0.62 m/s).
        camera_rate_hz: the pipeline's frame rate (the thesis ran at 12 to 13 FPS).
        steer_bias_rad: the kart's drag to one side (positive pulls left).
        use_map: relocalise against the taught drive's visual map (False: VO alone, as the thesis).
        controller: ``tuned`` (``drive``'s settings) or ``plain_stanley``: the pipeline as the thesis ran
            it, for comparison (unsmoothed reference, Stanley with the heading at the nearest waypoint, no
            feed-forward, bias compensation or rate limit, a constant throttle and a hand-set speed,
            VO alone).
        drive: the pipeline's settings; its path's cruise speed is set to ``speed_mps``.
        vo: the stereo VO's settings, for the reference and the repeat drive alike.
        effects: the simulated cameras (the small kart's real ones by default; ``perfect_camera()`` the pinhole).
    """

    track: str = "straight20"
    speed_mps: float = 0.62
    seed: int = 1
    camera_rate_hz: float = 15.0
    steer_bias_rad: float = 0.03
    use_map: bool = True
    controller: Literal["tuned", "plain_stanley"] = "tuned"
    drive: DriveConfig = field(default_factory=DriveConfig)
    vo: StereoVOConfig = field(default_factory=StereoVOConfig)
    effects: CameraEffectsConfig = field(default_factory=CameraEffectsConfig)

    def __post_init__(self) -> None:
        if self.speed_mps <= 0 or self.camera_rate_hz <= 0:
            raise ConfigError("the experiment's speed and camera rate must be positive")
        if self.controller not in ("tuned", "plain_stanley"):
            raise ConfigError(f"unknown controller {self.controller!r} (tuned or plain_stanley)")


def plain_stanley_drive_config(speed_mps: float, vehicle: VehicleParams) -> DriveConfig:
    """The thesis's autonomous mode (plain Stanley): every later fix switched off, throttle set by hand for
    ``speed_mps``."""
    drag = vehicle.rolling_decel_mps2 / (vehicle.max_accel_mps2 * (1.0 - speed_mps / vehicle.top_speed_mps))
    follow = PathFollowConfig(
        stanley=StanleyConfig(k_heading=0.5, k_cross_track=1.2, heading_lookahead_m=0.0, heading_lookahead_time_s=0.0,
                              curvature_feedforward=False),
        bias=BiasConfig(gain_rad_per_m_s=0.0), max_steer_rate_radps=100.0, speed_control="constant_throttle",
        constant_throttle=min(max(drag, 0.0), 1.0), speed_input="assumed", assumed_speed_mps=speed_mps)
    return DriveConfig(path=PathConfig(spacing_m=0.05, smoothing_m=0.0, cruise_speed_mps=speed_mps), follow=follow)


def end_errors(reference_xy_yaw: Array, run_xy: Array) -> tuple[float, float]:
    """The run's last position against the reference's last pose: (along, across) its heading, in metres.

    Along is positive past the reference's end; across is positive to its left.
    """
    x, y, yaw = reference_xy_yaw[-1]
    dx, dy = run_xy[-1, 0] - x, run_xy[-1, 1] - y
    return float(dx * math.cos(yaw) + dy * math.sin(yaw)), float(-dx * math.sin(yaw) + dy * math.cos(yaw))


def path_distance(reference_xy: Array, run_xy: Array, spacing_m: float = 0.02) -> Array:
    """For every run point, the distance to the reference polyline (densely resampled)."""
    steps = np.linalg.norm(np.diff(reference_xy, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    dense_s = np.arange(0.0, s[-1] + spacing_m, spacing_m)
    dense = np.column_stack([np.interp(dense_s, s, reference_xy[:, 0]), np.interp(dense_s, s, reference_xy[:, 1])])
    distance, _ = cKDTree(dense).query(run_xy)
    return np.asarray(distance)


def run_teach_repeat(config: TeachRepeatConfig, out: str | Path, progress: bool = False, video: bool = True,
                     keep_teach: bool = True) -> dict[str, object]:
    """Teach, build the reference, repeat, score; write ``out/result.json`` and the plots. Returns the result.
    ``keep_teach=False`` does not record the teach drive (its lossless frames would be most of the output's size,
    and most of the teach drive's time): the reference and the visual map are built from its frames as they come
    either way."""
    out = Path(out)
    vehicle = get_vehicle("rc-kart")
    pair = vehicle.stereo_pair
    assert pair is not None
    sim = SimConfig(track=config.track, vehicle=vehicle.name, seed=config.seed, camera_rate_hz=config.camera_rate_hz,
                    cameras=pair, effects=config.effects,
                    disturbances=DisturbanceConfig(steer_bias_rad=config.steer_bias_rad, cross_slope=True))
    body_cam = vehicle.camera(pair[0]).pose_body_cam_array

    teach_dir = out / "teach"
    if teach_dir.exists():
        shutil.rmtree(teach_dir)
    print(f"1/3 teach: the centerline driver drives {config.track} at {config.speed_mps} m/s"
          + (", recording" if keep_teach else ""))
    print("2/3 reference: stereo VO over the teach drive's frames as they come"
          + (", keeping a visual map" if config.use_map and config.controller == "tuned" else ""))
    tap = _TeachTap(pair, vehicle.stereo_rig(), body_cam, config.vo, config.drive.map)
    try:
        teach = run_simulation(replace(sim, referee=replace(sim.referee, run_on_m=0.5)), "centerline",
                               CenterlineDriverConfig(speed_mps=config.speed_mps),
                               outputs=SessionOutputs(record_dir=teach_dir if keep_teach else None, progress=progress),
                               taps=(tap,))
    except BaseException:
        tap.abandon()
        raise
    vo_run, visual_map = tap.finish()
    if teach.ground_truth is None or teach.result.disqualified:
        raise ConfigError(f"the teach drive failed: {teach.result.reason}")

    drive = config.drive if config.controller == "tuned" else plain_stanley_drive_config(config.speed_mps, vehicle)
    use_map = config.use_map and config.controller == "tuned"
    vo_ground = ground_poses(vo_run.trajectory.poses, body_cam)
    path_config = replace(drive.path, cruise_speed_mps=config.speed_mps)
    reference = build_reference_path(vo_ground[:, :2], path_config)
    save_reference_path(reference, out / "reference.csv")
    visual_map.save(map_path_for(out / "reference.csv"))

    drive = replace(drive, path=path_config)
    commands = tap.commands
    if config.controller == "tuned":
        bias = steer_bias_of_drive(reference, vo_ground, np.array([e.stamp_ns for e in vo_run.estimates]),
                                   np.array([c.stamp_ns for c in commands]), np.array([c.steer_rad for c in commands]),
                                   vehicle.wheelbase_m)
        print(f"   the teach drive shows a steering bias of {bias:+.3f} rad: the follower starts from it")
        drive = replace(drive, follow=replace(drive.follow, bias=replace(drive.follow.bias, initial_rad=bias)))
    print("3/3 repeat: the stereo-VO pipeline follows the reference")
    repeat = run_simulation(sim, "path", stack=StackConfig(drive=drive, stereo_vo=config.vo),
                            route=Route(reference, visual_map if use_map else None),
                            outputs=SessionOutputs(video_path=(out / "repeat.mp4") if video else None,
                                                   drive_log=out / "drive_log.csv",
                                                   result_path=out / "repeat_result.json", progress=progress))
    return score(config, out, teach, repeat, reference, body_cam, vo_run.summary())


class _TeachTap:
    """A sink of the teach drive: its stereo pairs go to VO (:func:`~kartpilot.odometry.run.teach_over`) in a thread
    as they are drawn, and its commands are kept. Nothing is written and read back: the teach drive's frames as
    PNG files were 29 of the 50 s of CPU a straight20 teach drive took, and reading them back 10 s more. VO sees
    the frames the repeat drive's pipeline sees (grey from the simulator's colour image, as live)."""

    def __init__(self, pair: tuple[str, str], rig: StereoRig, body_cam: Array, vo: StereoVOConfig,
                 map_config: MapConfig) -> None:
        self._pair = pair
        self.commands: list[ActuatorCommand] = []
        self._queue: queue.Queue[FrameSet | int | None] = queue.Queue(maxsize=4)
        self._result: tuple[VORun, VisualMap] | None = None
        self._error: BaseException | None = None
        self._ended = False  # the drive's end has reached VO
        self._thread = threading.Thread(target=self._teach, args=(rig, body_cam, vo, map_config),
                                        name="teach-vo", daemon=True)
        self._thread.start()

    def _frames(self) -> Iterator[FrameSet | int]:
        while (frames := self._queue.get()) is not None:
            yield frames
        self._ended = True

    def _teach(self, rig: StereoRig, body_cam: Array, vo: StereoVOConfig, map_config: MapConfig) -> None:
        try:
            self._result = teach_over(self._frames(), rig, "teach drive", body_cam, vo, map_config)
        except BaseException as exc:
            self._error = exc
            # let the drive end (it is told at its next frame), unless it has ended already: a drive that could not
            # start (a track that is not there) leaves VO no frames, and waiting for its end again would never end
            while not self._ended and self._queue.get() is not None:
                pass

    def write_frames(self, frames: FrameSet) -> None:
        if self._error is not None:
            raise self._error
        left, right = self._pair
        if left not in frames.images or right not in frames.images:  # a camera dropped its frame: VO bridges it
            self._queue.put(frames.index)
            return
        self._queue.put(FrameSet(frames.index, frames.stamp_ns, {"left": frames.images[left],
                                                                 "right": frames.images[right]}))

    def send(self, command: ActuatorCommand) -> None:
        self.commands.append(command)

    def write_outputs(self, stamp_ns: int, outputs: Outputs) -> None:
        pass

    def finish(self) -> tuple[VORun, VisualMap]:
        """The VO run and the visual map, once the drive is over."""
        self.abandon()
        if self._error is not None:
            raise self._error
        assert self._result is not None
        return self._result

    def abandon(self) -> None:
        """Tell VO that the drive is over and wait for it (a drive that failed: its result is not asked for)."""
        self._queue.put(None)
        self._thread.join()


def summary_line(result: dict[str, object]) -> str:
    """One line for a person: the verdict, the end point against the thesis's, the tracking error."""
    verdict = f"DISQUALIFIED: {result['reason']}" if result["disqualified"] else str(result["reason"])
    return (f"{verdict} | end point {result['end_error_along_m']:+.3f} m along, {result['end_error_across_m']:+.3f} m "
            f"across (the thesis: {result['thesis_end_error_m']} m) | max "
            f"{result['max_distance_from_taught_path_m']:.3f} m from the taught path, centre offset max "
            f"{result['max_center_offset_m']:.3f} m")


def score(config: TeachRepeatConfig, out: Path, teach: SimRun, repeat: SimRun, reference: ReferencePath,
          body_cam: Array, vo_summary: str) -> dict[str, object]:
    """The result JSON and the plots of one experiment."""
    assert teach.ground_truth is not None and repeat.ground_truth is not None
    teach_truth = ground_poses(teach.ground_truth.poses, body_cam)
    repeat_truth = ground_poses(repeat.ground_truth.poses, body_cam)
    along, across = end_errors(teach_truth, repeat_truth[:, :2])
    relocalised = bool(repeat.extra.get("relocalised_frames"))
    distance = path_distance(teach_truth[:, :2], repeat_truth[:, :2])
    samples = repeat.drive
    steer = np.array([s.steer_rad for s in samples])
    t = np.array([s.stamp_ns for s in samples]) * 1e-9
    steer_rate = np.diff(steer) * config.camera_rate_hz if len(steer) > 1 else np.zeros(1)
    result: dict[str, object] = {
        **repeat.result.to_json(),
        "end_error_along_m": round(along, 4),
        "end_error_across_m": round(across, 4),
        "thesis_end_error_m": THESIS_END_ERROR_M,
        "max_distance_from_taught_path_m": round(float(distance.max()), 4),
        "mean_distance_from_taught_path_m": round(float(distance.mean()), 4),
        "steer_rate_rms_radps": round(float(np.sqrt(np.mean(steer_rate**2))), 4),
        "reference_length_m": round(reference.length_m, 3),
        "reference_vo": vo_summary,
        "teach": teach.result.to_json(),
        "track": config.track, "speed_mps": config.speed_mps, "seed": config.seed,
        "camera_rate_hz": config.camera_rate_hz, "steer_bias_rad": config.steer_bias_rad,
        "controller": config.controller,
        "localisation": "VO and the taught drive's visual map" if relocalised else "VO alone",
        "stop_reason": repeat.stop_reason, "steps": repeat.steps, "missed_deadlines": repeat.missed_deadlines,
        **{k: v for k, v in repeat.extra.items() if k != "stop_reason"},
        "stage_ms": {k: round(v, 3) for k, v in repeat.stage_ms.items()},
    }
    write_json_atomic(out / "result.json", result)
    plot_path_following(teach_truth[:, :2], reference.xy_m, repeat_truth[:, :2],
                        np.array([[s.x_m, s.y_m] for s in samples]), distance, out / "path.png",
                        title=f"{config.track} at {config.speed_mps} m/s, {config.controller} pipeline")
    label = f"{config.track} at {config.speed_mps} m/s, {config.controller} pipeline ({result['localisation']})"
    plot_steering(t, steer, np.array([s.cross_track_m for s in samples]), out / "steering.png", title=label)
    return result

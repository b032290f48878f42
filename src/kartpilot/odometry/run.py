"""Run stereo or monocular VO over a whole frame source and summarise the run."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import DataError, KartpilotError
from kartpilot.core.geometry import Array, vo_ground_pose
from kartpilot.core.trajectory import Trajectory
from kartpilot.core.types import Image
from kartpilot.odometry.mono_vo import MonoEstimate, MonoVO, MonoVOConfig
from kartpilot.odometry.stereo_vo import StereoVO, StereoVOConfig, VOEstimate
from kartpilot.odometry.visual_map import MapBuilder, MapConfig, VisualMap
from kartpilot.sensors.base import StereoSource

__all__ = ["MonoRun", "OdometryRun", "run_mono_vo", "run_mono_vo_frames", "run_stereo_vo", "run_teach"]


class _RunCounts:
    """What every VO run reports: frames bridged, and frames per second over the run's wall time."""

    estimates: Sequence[VOEstimate | MonoEstimate]
    wall_time_s: float

    @property
    def bridged_frames(self) -> int:
        return sum(1 for e in self.estimates if e.status == "bridged")

    @property
    def frames_per_second(self) -> float:
        return len(self.estimates) / self.wall_time_s if self.wall_time_s > 0 else float("nan")


@dataclass(frozen=True)
class OdometryRun(_RunCounts):
    """A VO run: the trajectory, each frame's estimate, and what went wrong where."""

    trajectory: Trajectory
    estimates: tuple[VOEstimate, ...]
    unreadable_frames: tuple[int, ...]
    wall_time_s: float

    def stage_ms(self) -> dict[str, float]:
        """Mean milliseconds per stage over the frames that ran every stage."""
        timed = [e.diagnostics.timing_ms for e in self.estimates[1:]]
        keys = sorted({k for t in timed for k in t})
        return {k: float(np.mean([t.get(k, 0.0) for t in timed])) for k in keys} if timed else {}

    def summary(self) -> str:
        inliers = [e.diagnostics.inliers for e in self.estimates if e.status == "ok"]
        return (f"{len(self.estimates)} frames, {self.bridged_frames} bridged, "
                f"{len(self.unreadable_frames)} unreadable, median inliers "
                f"{int(np.median(inliers)) if inliers else 0}, {self.frames_per_second:.1f} frames/s")


def run_stereo_vo(source: StereoSource, config: StereoVOConfig | None = None,
                  on_frame: Callable[[VOEstimate], None] | None = None, vo: StereoVO | None = None) -> OdometryRun:
    """Run VO over every frame of ``source``.

    A frame that cannot be read is skipped and counted (the next frame is matched to the
    last good one); a frame where VO fails is bridged and counted. A source whose every
    frame is unreadable raises DataError.
    """
    if len(source) == 0:
        raise DataError(f"{source.name} has no frames")
    vo = vo or StereoVO(source.rig, config)
    estimates: list[VOEstimate] = []
    unreadable: list[int] = []
    start = time.perf_counter()
    try:
        for index in range(len(source)):
            try:
                frame = source.frame(index)
            except KartpilotError:
                unreadable.append(index)
                continue
            estimate = vo.process(frame)
            estimates.append(estimate)
            if on_frame is not None:
                on_frame(estimate)
    finally:
        vo.close()
    wall = time.perf_counter() - start
    if not estimates:
        raise DataError(f"none of the {len(source)} frames of {source.name} could be read")
    trajectory = Trajectory.from_poses([e.pose_world_cam for e in estimates], [e.stamp_ns * 1e-9 for e in estimates])
    return OdometryRun(trajectory, tuple(estimates), tuple(unreadable), wall)


def run_teach(source: StereoSource, pose_body_cam: Array, config: StereoVOConfig | None = None,
              map_config: MapConfig | None = None) -> tuple[OdometryRun, VisualMap]:
    """VO over a taught drive, keeping keyframes for a visual map as it goes."""
    vo = StereoVO(source.rig, config)
    builder = MapBuilder(map_config)

    def keep(estimate: VOEstimate) -> None:
        latest = vo.last_features()
        if latest is not None and estimate.status != "bridged":
            ground = np.array(vo_ground_pose(estimate.pose_world_cam, pose_body_cam))
            builder.add(estimate.pose_world_cam, ground, *latest)

    run = run_stereo_vo(source, on_frame=keep, vo=vo)
    return run, builder.build()


@dataclass(frozen=True)
class MonoRun(_RunCounts):
    """A monocular VO run: the trajectory (metres, from the ground plane) and each frame's estimate."""

    trajectory: Trajectory
    estimates: tuple[MonoEstimate, ...]
    unreadable_frames: tuple[int, ...]
    wall_time_s: float
    timing_ms: dict[str, float]

    @property
    def scale_source(self) -> str:
        return self.estimates[-1].scale_source if self.estimates else ""

    def summary(self) -> str:
        road = [e.road_inliers for e in self.estimates if e.status == "ok"]
        return (f"{len(self.estimates)} frames, {self.bridged_frames} bridged, {len(self.unreadable_frames)} "
                f"unreadable, median road inliers {int(np.median(road)) if road else 0}, "
                f"{self.frames_per_second:.1f} frames/s; "
                f"scale from the {self.scale_source}")


def run_mono_vo(source: StereoSource, config: MonoVOConfig | None = None,
                on_frame: Callable[[MonoEstimate], None] | None = None) -> MonoRun:
    """Monocular VO on the left camera of ``source`` (its right image is not used)."""
    if len(source) == 0:
        raise DataError(f"{source.name} has no frames")

    def frames() -> Iterator[tuple[int, int, Image] | int]:
        for index in range(len(source)):
            try:
                frame = source.frame(index)
            except KartpilotError:
                yield index
                continue
            yield frame.index, frame.stamp_ns, frame.left

    return run_mono_vo_frames(frames(), source.rig.camera, source.name, config, on_frame)


def run_mono_vo_frames(frames: Iterable[tuple[int, int, Image] | int], camera: PinholeCamera, name: str,
                       config: MonoVOConfig | None = None, on_frame: Callable[[MonoEstimate], None] | None = None
                       ) -> MonoRun:
    """Monocular VO over ``(index, stamp_ns, grey image)`` of one camera; a bare index is a frame that could not
    be read."""
    vo = MonoVO(camera, config)
    estimates: list[MonoEstimate] = []
    unreadable: list[int] = []
    start = time.perf_counter()
    for item in frames:
        if isinstance(item, int):
            unreadable.append(item)
            continue
        estimate = vo.process(*item)
        estimates.append(estimate)
        if on_frame is not None:
            on_frame(estimate)
    wall = time.perf_counter() - start
    if not estimates:
        raise DataError(f"none of the frames of {name} could be read")
    trajectory = Trajectory.from_poses([e.pose_world_cam for e in estimates], [e.stamp_ns * 1e-9 for e in estimates])
    count = max(len(estimates) - 1, 1)
    return MonoRun(trajectory, tuple(estimates), tuple(unreadable), wall,
                   {k: v / count for k, v in vo.timing_ms.items()})

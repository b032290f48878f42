"""Run any VO (stereo or monocular, :class:`~kartpilot.odometry.vo.VisualOdometry`) over a whole frame
sequence and summarise the run."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from kartpilot.core.camera import StereoRig
from kartpilot.core.errors import DataError
from kartpilot.core.geometry import Array, invert_pose, planar_pose, vo_ground_pose
from kartpilot.core.trajectory import Trajectory
from kartpilot.core.types import FrameSet
from kartpilot.odometry.mono_localizer import MonoLocalizer
from kartpilot.odometry.stereo_vo import StereoVO, StereoVOConfig
from kartpilot.odometry.visual_map import MapBuilder, MapConfig, VisualMap, vo_for_map
from kartpilot.odometry.vo import VisualOdometry, VOStep
from kartpilot.sensors.base import StereoSource

__all__ = ["LocalizedRun", "VORun", "bridge_unreadable", "run_mono_localizer", "run_teach", "run_vo",
           "teach_over"]


@dataclass(frozen=True)
class VORun:
    """A VO run, stereo or monocular.

    Attributes:
        trajectory: one pose per frame of the input, in order. A frame that could not be read has no estimate;
            its pose (and its time, when the source could not give it) is interpolated between its
            neighbours, so the trajectory stays aligned with the input frames.
        estimates: each frame's estimate, for the frames that were read.
        unreadable_frames: the indices of the frames that could not be read.
        timing_ms: mean milliseconds per stage, per frame after the first.
        scale_source: where the metres came from.
    """

    trajectory: Trajectory
    estimates: tuple[VOStep, ...]
    unreadable_frames: tuple[int, ...]
    wall_time_s: float
    timing_ms: dict[str, float]
    scale_source: str

    @property
    def bridged_frames(self) -> int:
        return sum(1 for e in self.estimates if e.status == "bridged")

    @property
    def frames_per_second(self) -> float:
        return len(self.estimates) / self.wall_time_s if self.wall_time_s > 0 else float("nan")

    def summary(self) -> str:
        inliers = [e.inliers for e in self.estimates if e.status == "ok"]
        return (f"{len(self.trajectory)} frames, {self.bridged_frames} bridged, "
                f"{len(self.unreadable_frames)} unreadable, median inliers "
                f"{int(np.median(inliers)) if inliers else 0}, {self.frames_per_second:.1f} frames/s; "
                f"scale from the {self.scale_source}")


def run_vo(frames: Iterable[FrameSet | int], vo: VisualOdometry, name: str,
           on_frame: Callable[[VOStep], None] | None = None) -> VORun:
    """Run ``vo`` over every frame set of ``frames`` (a bare index is a frame that could not be read), and
    close it.

    An unreadable frame is skipped and counted: the next frame is matched to the last good one, and the
    trajectory bridges the gap. A frame where VO fails is bridged by the VO and counted. When no frame could
    be read, DataError.
    """
    estimates: list[VOStep] = []
    order: list[int | VOStep] = []
    start = time.perf_counter()
    try:
        for item in frames:
            if isinstance(item, int):
                order.append(item)
                continue
            estimate = vo.process(item)
            estimates.append(estimate)
            order.append(estimate)
            if on_frame is not None:
                on_frame(estimate)
    finally:
        vo.close()
    wall = time.perf_counter() - start
    if not estimates:
        raise DataError(f"none of the {len(order)} frames of {name} could be read")
    count = max(len(estimates) - 1, 1)
    unreadable = tuple(item for item in order if isinstance(item, int))
    return VORun(_aligned_trajectory(order), tuple(estimates), unreadable, wall,
                 {k: v / count for k, v in vo.timing_ms.items()}, vo.scale_source)


def _aligned_trajectory(order: Sequence[int | VOStep]) -> Trajectory:
    known = [e for e in order if not isinstance(e, int)]
    read = Trajectory.from_poses([e.pose_world_cam for e in known], [e.stamp_ns * 1e-9 for e in known])
    return bridge_unreadable(read, [e.index for e in known], [e if isinstance(e, int) else e.index for e in order])


def bridge_unreadable(read: Trajectory, read_indices: Sequence[int], all_indices: Sequence[int]) -> Trajectory:
    """One pose per input frame (``all_indices``, in order): the read frames' own, and, for a frame that could
    not be read, one interpolated at a time interpolated from the frame indices (beyond the first or last read
    frame, the mean frame interval carried on)."""
    if len(read_indices) == len(all_indices):
        return read
    indices = np.asarray(all_indices, dtype=np.float64)
    known_indices = np.asarray(read_indices, dtype=np.float64)
    stamps = np.interp(indices, known_indices, read.stamps_s)
    if len(known_indices) > 1:
        period = (read.stamps_s[-1] - read.stamps_s[0]) / (known_indices[-1] - known_indices[0])
        stamps = np.where(indices < known_indices[0], read.stamps_s[0] - (known_indices[0] - indices) * period,
                          stamps)
        stamps = np.where(indices > known_indices[-1], read.stamps_s[-1] + (indices - known_indices[-1]) * period,
                          stamps)
    return read.at(stamps)


def run_teach(source: StereoSource, pose_body_cam: Array, config: StereoVOConfig | None = None,
              map_config: MapConfig | None = None) -> tuple[VORun, VisualMap]:
    """VO over a taught drive, keeping keyframes for a visual map as it goes."""
    return teach_over(source.frame_sets(), source.rig, source.name, pose_body_cam, config, map_config)


def teach_over(frames: Iterable[FrameSet | int], rig: StereoRig, name: str, pose_body_cam: Array,
               config: StereoVOConfig | None = None, map_config: MapConfig | None = None) -> tuple[VORun, VisualMap]:
    """:func:`run_teach` over rectified stereo frame sets (cameras ``left`` and ``right``) as they come, from a
    source or from a drive as it is driven."""
    builder = MapBuilder(map_config)
    vo = StereoVO(rig, vo_for_map(config, builder.config.keyframe_spacing_m))

    def keep(estimate: VOStep) -> None:
        latest = vo.last_features()
        if latest is not None and estimate.status != "bridged":
            ground = np.array(vo_ground_pose(estimate.pose_world_cam, pose_body_cam))
            builder.add(estimate.pose_world_cam, ground, *latest)

    run = run_vo(frames, vo, name, on_frame=keep)
    return run, builder.build()


@dataclass(frozen=True)
class LocalizedRun:
    """The one-camera localiser over a frame sequence: the camera's poses in the place database's frame, one per
    input frame (before the first fix, the motion model's; an unreadable frame bridged), and its counts."""

    trajectory: Trajectory
    placed_frames: int
    place_fixes: int
    rejected_fixes: int
    unreadable_frames: int
    wall_time_s: float

    @property
    def frames_per_second(self) -> float:
        read = len(self.trajectory) - self.unreadable_frames
        return read / self.wall_time_s if self.wall_time_s > 0 else float("nan")


def run_mono_localizer(frames: Iterable[FrameSet | int], localizer: MonoLocalizer, name: str) -> LocalizedRun:
    """Run ``localizer`` over every frame set of ``frames`` (a bare index is a frame that could not be read), and
    close it; when no frame could be read, DataError."""
    body_cam = localizer.body_cam
    origin_world_body = localizer.places.poses_world_cam[0] @ invert_pose(body_cam)
    poses, stamps_s, read, everything, placed = [], [], [], [], 0
    start = time.perf_counter()
    try:
        for item in frames:
            everything.append(item if isinstance(item, int) else item.index)
            if isinstance(item, int):
                continue
            read.append(item.index)
            pose = localizer.update(item)
            placed += localizer.filter.state is not None
            poses.append(origin_world_body @ planar_pose(pose.x_m, pose.y_m, pose.yaw_rad) @ body_cam)
            stamps_s.append(item.stamp_ns * 1e-9)
    finally:
        localizer.close()
    if not poses:
        raise DataError(f"none of the {len(everything)} frames of {name} could be read")
    trajectory = bridge_unreadable(Trajectory.from_poses(poses, stamps_s), read, everything)
    return LocalizedRun(trajectory, placed, localizer.relocalisations, localizer.rejected_fixes,
                        len(everything) - len(read), time.perf_counter() - start)

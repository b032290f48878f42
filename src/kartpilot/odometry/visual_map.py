"""Teach and repeat: a visual map of the taught drive, and relocalisation against it.

VO alone drifts (about 1 % of the distance), and the reference built from the teach
drive's VO drifts too, differently. Following one drifting estimate with another
leaves the kart metres off after a lap. So the teach drive also keeps keyframes every
``keyframe_spacing_m``: the left image's descriptors and their stereo 3D points, with
the keyframe's pose in the reference's frame. During the repeat drive the current
left features are matched to the nearest keyframe and PnP gives the camera's pose
relative to it, hence in the reference's frame, drift and all: the kart is localised
on the reference itself (the visual teach-and-repeat of Furgale and Barfoot, 2010).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from kartpilot.core.errors import ConfigError, PlanningError
from kartpilot.core.geometry import Array, invert_pose
from kartpilot.odometry.pnp import PnpConfig, estimate_motion_pnp
from kartpilot.odometry.stereo_vo import StereoVOConfig
from kartpilot.perception.features import Features
from kartpilot.perception.matching import MatchConfig, match_descriptors

__all__ = ["MapBuilder", "MapConfig", "RelocConfig", "VisualMap", "load_visual_map", "map_path_for", "relocalize",
           "vo_for_map"]


@dataclass(frozen=True)
class MapConfig:
    """Attributes:
        keyframe_spacing_m: distance driven between keyframes.
        max_points: the strongest features with stereo depth kept per keyframe.
    """

    keyframe_spacing_m: float = 0.5
    max_points: int = 500

    def __post_init__(self) -> None:
        if self.keyframe_spacing_m <= 0 or self.max_points < 8:
            raise ConfigError("map.keyframe_spacing_m must be positive and max_points at least 8")


@dataclass(frozen=True)
class RelocConfig:
    """Attributes:
        enabled: use the map when there is one.
        search_keyframes: how many keyframes ahead of the last nearest one (and two behind) are searched
            for the nearest; it and the next nearest are tried.
        min_inliers: fewest PnP inliers for a relocalisation to count.
        max_correction_m, max_correction_rad: a relocalisation further than this from the current
            estimate is taken for a mismatch and ignored. Under half the spacing of repeated structure
            (cones every metre), so PnP locked onto the neighbouring cones is rejected.
        gain: the fraction of the difference applied per relocalisation (a complementary filter:
            VO carries the pose between relocalisations, the map pulls it onto the reference).
    """

    enabled: bool = True
    search_keyframes: int = 24
    min_inliers: int = 15
    max_correction_m: float = 0.4
    max_correction_rad: float = 0.1
    gain: float = 0.3
    matching: MatchConfig = field(default_factory=lambda: MatchConfig(ratio=0.8))
    pnp: PnpConfig = field(default_factory=lambda: PnpConfig(reprojection_px=2.0, translation_min_disparity_px=0.0))

    def __post_init__(self) -> None:
        if not 0.0 < self.gain <= 1.0:
            raise ConfigError("reloc.gain must be in (0, 1]")
        if self.search_keyframes < 1:
            raise ConfigError("reloc.search_keyframes must be at least 1")


@dataclass(frozen=True)
class VisualMap:
    """Keyframes of a taught drive.

    Attributes:
        poses_world_cam: (K, 4, 4) left-camera poses in the teach VO's world frame.
        ground_xy_yaw: (K, 3) the same poses as rear-axle ground poses in the reference's frame.
        points_m: per keyframe, (N_k, 3) points in its camera frame.
        descriptors: per keyframe, (N_k, D) descriptors of those points.
        binary: Hamming descriptors (ORB) rather than float ones (SIFT).
    """

    poses_world_cam: Array
    ground_xy_yaw: Array
    points_m: tuple[Array, ...]
    descriptors: tuple[np.ndarray, ...]
    binary: bool

    def __len__(self) -> int:
        return len(self.poses_world_cam)

    def save(self, target: str | Path) -> Path:
        target = Path(target)
        target.parent.mkdir(parents=True, exist_ok=True)
        counts = np.array([len(p) for p in self.points_m], np.int64)
        width = self.descriptors[0].shape[1] if self.descriptors else 32
        np.savez_compressed(
            target, poses_world_cam=self.poses_world_cam, ground_xy_yaw=self.ground_xy_yaw, counts=counts,
            points_m=np.concatenate(self.points_m) if len(self) else np.zeros((0, 3)),
            descriptors=np.concatenate(self.descriptors) if len(self) else np.zeros((0, width), np.uint8),
            binary=np.array(self.binary))
        return target


def map_path_for(reference: str | Path) -> Path:
    """Where the map of a reference path lives: ``ref.csv`` -> ``ref.map.npz``."""
    reference = Path(reference)
    return reference.with_name(reference.stem + ".map.npz")


def load_visual_map(source: str | Path) -> VisualMap:
    source = Path(source)
    if not source.is_file():
        raise PlanningError(f"{source}: no such visual map")
    try:
        with np.load(source) as data:
            counts = data["counts"]
            split = np.cumsum(counts)[:-1]
            return VisualMap(data["poses_world_cam"], data["ground_xy_yaw"],
                             tuple(np.split(data["points_m"], split)), tuple(np.split(data["descriptors"], split)),
                             bool(data["binary"]))
    except (OSError, KeyError, ValueError) as exc:
        raise PlanningError(f"{source}: unreadable visual map ({exc})") from exc


class MapBuilder:
    """Collects keyframes while VO runs over the teach drive."""

    def __init__(self, config: MapConfig | None = None) -> None:
        self.config = config or MapConfig()
        self._poses: list[Array] = []
        self._ground: list[Array] = []
        self._points: list[Array] = []
        self._descriptors: list[np.ndarray] = []
        self._binary = True

    def add(self, pose_world_cam: Array, ground_xy_yaw: Array, features: Features, points_m: Array) -> bool:
        """Keep this frame if it lies ``keyframe_spacing_m`` beyond the last keyframe; True if kept."""
        if self._ground and math.dist(self._ground[-1][:2], ground_xy_yaw[:2]) < self.config.keyframe_spacing_m:
            return False
        valid = np.flatnonzero(np.isfinite(points_m[:, 2]))
        if len(valid) < 8:
            return False
        valid = valid[np.argsort(-features.responses[valid])[: self.config.max_points]]
        self._poses.append(np.asarray(pose_world_cam, float))
        self._ground.append(np.asarray(ground_xy_yaw, float))
        self._points.append(points_m[valid].astype(np.float32))
        self._descriptors.append(features.descriptors[valid])
        self._binary = features.binary
        return True

    def build(self) -> VisualMap:
        if not self._poses:
            raise PlanningError("the teach drive gave no keyframes (too short, or no stereo depth)")
        return VisualMap(np.array(self._poses), np.array(self._ground), tuple(self._points),
                         tuple(self._descriptors), self._binary)


def relocalize(visual_map: VisualMap, keyframe: int, features: Features, camera_matrix: Array,
               config: RelocConfig) -> tuple[Array, int] | None:
    """The current camera's pose in the map's world, ``T_world_cam``, from its left ``features``
    matched to ``keyframe``; with the inlier count. None if it does not hold up."""
    if len(features) < config.min_inliers:
        return None
    matches = match_descriptors(visual_map.descriptors[keyframe], features.descriptors, visual_map.binary,
                                config.matching)
    if len(matches.index_a) < config.min_inliers:
        return None
    points = visual_map.points_m[keyframe][matches.index_a].astype(np.float64)
    motion = estimate_motion_pnp(points, features.points_px[matches.index_b], camera_matrix, config.pnp)
    if not motion.ok or len(motion.inliers) < config.min_inliers:
        return None
    return visual_map.poses_world_cam[keyframe] @ invert_pose(motion.pose_cur_prev), len(motion.inliers)


def vo_for_map(config: StereoVOConfig | None, spacing_m: float) -> StereoVOConfig:
    """Stereo VO's settings for building or using a map with keyframes every ``spacing_m``: VO finds features
    on its own keyframes only (``keyframes``), so it makes one at least that often."""
    config = config or StereoVOConfig()
    if not config.keyframes or not math.isfinite(spacing_m) or spacing_m <= 0:
        return config
    return replace(config, keyframe_max_distance_m=min(config.keyframe_max_distance_m, spacing_m))

"""From camera poses to the kart's pose on the road, live.

Stereo VO reports the left camera's pose in the frame of the first left camera
(OpenCV axes). Planning and control want the rear axle on the road plane: the
camera's mount on the body turns one into the other (:func:`ground_poses`), and
the odometry frame is the rear axle at the first frame (x forward, y left).

:class:`StereoVOLocalizer` runs VO frame by frame, filters the speed, bridges a
missing or failed frame with the motion model (constant speed and yaw rate), and
reports ``lost`` once it has bridged for longer than ``max_bridge_s``, so the
caller can stop.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from kartpilot.core.camera import StereoRig
from kartpilot.core.errors import ConfigError, OdometryError, PerceptionError
from kartpilot.core.geometry import Array, invert_pose
from kartpilot.core.types import FrameSet, Image, StereoFrame, VehiclePose
from kartpilot.odometry.stereo_vo import StereoVO, StereoVOConfig

__all__ = ["LocalizerConfig", "StereoVOLocalizer", "ground_poses"]

log = logging.getLogger(__name__)


def ground_poses(poses_world_cam: Array, pose_body_cam: Array) -> Array:
    """``(N, 3)`` rear-axle ``x, y, yaw`` in the frame of the first body pose, from ``(N, 4, 4)`` camera poses.

    Works for any world frame (VO's first camera, the simulator's world): the body poses are
    expressed relative to the first one, then projected onto its ground plane.
    """
    poses = np.asarray(poses_world_cam, float)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) == 0:
        raise ConfigError(f"expected (N, 4, 4) camera poses, got shape {poses.shape}")
    body = poses @ invert_pose(np.asarray(pose_body_cam, float))
    relative = invert_pose(body[0]) @ body
    yaw = np.arctan2(relative[:, 1, 0], relative[:, 0, 0])
    return np.column_stack([relative[:, 0, 3], relative[:, 1, 3], yaw])


@dataclass(frozen=True)
class LocalizerConfig:
    """Attributes:
        vo: the stereo VO's settings.
        left_camera, right_camera: the stereo pair's names in the frame sets.
        max_bridge_s: how long the motion model may stand in for VO before the pose is ``lost``.
        speed_time_constant_s: low-pass time constant of the speed and yaw-rate estimates.
    """

    vo: StereoVOConfig = field(default_factory=StereoVOConfig)
    left_camera: str = "left"
    right_camera: str = "right"
    max_bridge_s: float = 0.5
    speed_time_constant_s: float = 0.15

    def __post_init__(self) -> None:
        if self.max_bridge_s < 0 or self.speed_time_constant_s < 0:
            raise ConfigError("localizer.max_bridge_s and speed_time_constant_s must not be negative")


def _gray(image: Image) -> Image:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


class StereoVOLocalizer:
    """Stereo VO turned into :class:`VehiclePose` messages. Holds the VO and the last pose."""

    def __init__(self, rig: StereoRig, pose_body_cam: Array, config: LocalizerConfig | None = None) -> None:
        self.config = config or LocalizerConfig()
        self.vo = StereoVO(rig, self.config.vo)
        self._body_cam = np.asarray(pose_body_cam, float)
        self._body0_world: Array | None = None  # inverse of the first body pose in VO's world
        self._last: VehiclePose | None = None
        self._last_ok_ns: int | None = None
        self.last_timing_ms: dict[str, float] = {}

    def close(self) -> None:
        self.vo.close()

    def update(self, frames: FrameSet) -> VehiclePose:
        """The pose at ``frames.stamp_ns``."""
        cfg = self.config
        left, right = frames.images.get(cfg.left_camera), frames.images.get(cfg.right_camera)
        if left is None or right is None:
            missing = cfg.left_camera if left is None else cfg.right_camera
            return self._bridge(frames.stamp_ns, f"the {missing} camera delivered nothing")
        try:
            estimate = self.vo.process(StereoFrame(frames.index, frames.stamp_ns, _gray(left), _gray(right)))
        except (PerceptionError, OdometryError) as exc:
            return self._bridge(frames.stamp_ns, str(exc))
        self.last_timing_ms = estimate.diagnostics.timing_ms
        body = estimate.pose_world_cam @ invert_pose(self._body_cam)
        if self._body0_world is None:
            self._body0_world = invert_pose(body)
        relative = self._body0_world @ body
        x, y = float(relative[0, 3]), float(relative[1, 3])
        yaw = math.atan2(relative[1, 0], relative[0, 0])
        if estimate.status == "bridged":
            # VO bridged with its own constant-velocity model; its pose is a prediction
            pose = self._moved(frames.stamp_ns, x, y, yaw, "bridged", estimate.reason)
            return self._check_lost(pose)
        self._last_ok_ns = frames.stamp_ns
        return self._remember(self._moved(frames.stamp_ns, x, y, yaw, "ok", ""))

    def _moved(self, stamp_ns: int, x: float, y: float, yaw: float, status: str, reason: str) -> VehiclePose:
        """A pose with speed and yaw rate filtered from the step since the last pose."""
        last = self._last
        if last is None:
            return VehiclePose(stamp_ns, x, y, yaw, 0.0, 0.0, "ok")
        dt = max((stamp_ns - last.stamp_ns) * 1e-9, 1e-3)
        heading = 0.5 * (yaw + last.yaw_rad)
        speed = ((x - last.x_m) * math.cos(heading) + (y - last.y_m) * math.sin(heading)) / dt
        rate = math.remainder(yaw - last.yaw_rad, math.tau) / dt
        a = dt / (dt + self.config.speed_time_constant_s)
        return VehiclePose(stamp_ns, x, y, yaw, last.speed_mps + a * (speed - last.speed_mps),
                           last.yaw_rate_radps + a * (rate - last.yaw_rate_radps),
                           "ok" if status == "ok" else "bridged", reason)

    def _bridge(self, stamp_ns: int, reason: str) -> VehiclePose:
        """Predict with constant speed and yaw rate from the last pose."""
        last = self._last
        if last is None:
            pose = VehiclePose(stamp_ns, 0.0, 0.0, 0.0, 0.0, 0.0, "bridged", reason)
        else:
            dt = max((stamp_ns - last.stamp_ns) * 1e-9, 0.0)
            yaw = last.yaw_rad + last.yaw_rate_radps * dt
            heading = 0.5 * (yaw + last.yaw_rad)
            pose = VehiclePose(stamp_ns, last.x_m + last.speed_mps * dt * math.cos(heading),
                               last.y_m + last.speed_mps * dt * math.sin(heading), yaw,
                               last.speed_mps, last.yaw_rate_radps, "bridged", reason)
        log.info("pose at %d ns bridged: %s", stamp_ns, reason)
        return self._check_lost(pose)

    def _check_lost(self, pose: VehiclePose) -> VehiclePose:
        since = None if self._last_ok_ns is None else (pose.stamp_ns - self._last_ok_ns) * 1e-9
        if since is None or since > self.config.max_bridge_s:
            pose = VehiclePose(pose.stamp_ns, pose.x_m, pose.y_m, pose.yaw_rad, pose.speed_mps,
                               pose.yaw_rate_radps, "lost",
                               pose.reason + (f" (no measured pose for {since:.2f} s)" if since is not None else ""))
        return self._remember(pose)

    def _remember(self, pose: VehiclePose) -> VehiclePose:
        self._last = pose
        return pose

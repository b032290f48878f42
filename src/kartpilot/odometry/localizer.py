"""From camera poses to the kart's pose on the road, live.

Stereo VO reports the left camera's pose in the frame of the first left camera
(OpenCV axes). Planning and control want the rear axle on the road plane: the
camera's mount on the body turns one into the other (:func:`kartpilot.core.geometry.ground_poses`), and
the odometry frame is the rear axle at the first frame (x forward, y left).

:class:`StereoVOLocalizer` runs VO frame by frame, relocalises against the taught
drive's visual map when it has one (:mod:`kartpilot.odometry.visual_map`), filters
the speed, bridges a missing or failed frame with the motion model (constant speed
and yaw rate), and reports ``lost`` once it has bridged for longer than
``max_bridge_s``, so the caller can stop.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from kartpilot.core.camera import PinholeCamera, StereoRig
from kartpilot.core.errors import ConfigError, OdometryError, PerceptionError
from kartpilot.core.geometry import Array, Pose2D, between_2d, compose_2d, vo_ground_pose
from kartpilot.core.types import FrameSet, Image, VehiclePose
from kartpilot.odometry.stereo_vo import StereoVO, StereoVOConfig, VODiagnostics
from kartpilot.odometry.visual_map import RelocConfig, VisualMap, relocalize
from kartpilot.odometry.vo import grey_images
from kartpilot.perception.features import create_detector, detect_features
from kartpilot.sensors.health import HealthConfig, frame_problem

__all__ = ["LocalizerConfig", "PoseTracker", "StereoVOLocalizer"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LocalizerConfig:
    """Attributes:
        reloc: relocalisation against a visual map of the taught drive, when one is given.
        health: when a frame counts as black, blank or frozen (such a frame is bridged, not used).
        left_camera, right_camera: the stereo pair's names in the frame sets.
        max_bridge_s: how long the motion model may stand in for VO before the pose is ``lost``.
        speed_time_constant_s: low-pass time constant of the speed and yaw-rate estimates.
    """

    reloc: RelocConfig = field(default_factory=RelocConfig)
    health: HealthConfig = field(default_factory=HealthConfig)
    left_camera: str = "left"
    right_camera: str = "right"
    max_bridge_s: float = 0.5
    speed_time_constant_s: float = 0.15

    def __post_init__(self) -> None:
        if self.max_bridge_s < 0 or self.speed_time_constant_s < 0:
            raise ConfigError("localizer.max_bridge_s and speed_time_constant_s must not be negative")




class PoseTracker:
    """What every localiser shares: the last pose, speed and yaw rate filtered from odometry's own steps,
    bridging a missing frame with constant speed and yaw rate, and ``lost`` after ``max_bridge_s``."""

    def __init__(self, max_bridge_s: float, speed_time_constant_s: float) -> None:
        self.max_bridge_s = max_bridge_s
        self.speed_time_constant_s = speed_time_constant_s
        self._last: VehiclePose | None = None
        self._last_ok_ns: int | None = None
        self._wheel: tuple[int, float] | None = None  # (stamp_ns, speed_mps) the kart itself last measured

    def observe_speed(self, stamp_ns: int, speed_mps: float) -> None:
        """The kart's own measured speed (the RDW kart's 0x440): a bridged pose moves at it instead of at
        the last estimate, while it is younger than ``max_bridge_s``."""
        if math.isfinite(speed_mps):
            self._wheel = (stamp_ns, speed_mps)

    def _measured_speed(self, stamp_ns: int) -> float | None:
        if self._wheel is None or abs(stamp_ns - self._wheel[0]) * 1e-9 > self.max_bridge_s:
            return None
        return self._wheel[1]

    def _with_motion(self, stamp_ns: int, pose: Pose2D, step: Pose2D, dt: float, status: str,
                     reason: str) -> VehiclePose:
        """A pose with speed and yaw rate low-pass filtered from the odometry's own step (not the corrections)."""
        last = self._last
        if last is None or dt <= 0:
            return VehiclePose(stamp_ns, pose[0], pose[1], pose[2], 0.0, 0.0, "ok")
        a = dt / (dt + self.speed_time_constant_s)
        speed, rate = step[0] / dt, step[2] / dt
        return VehiclePose(stamp_ns, pose[0], pose[1], pose[2], last.speed_mps + a * (speed - last.speed_mps),
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
            wheel = self._measured_speed(stamp_ns)
            speed = last.speed_mps if wheel is None else wheel
            pose = VehiclePose(stamp_ns, last.x_m + speed * dt * math.cos(heading),
                               last.y_m + speed * dt * math.sin(heading), yaw,
                               speed, last.yaw_rate_radps, "bridged", reason)
        log.info("pose at %d ns bridged: %s", stamp_ns, reason)
        return self._check_lost(pose)

    def _check_lost(self, pose: VehiclePose) -> VehiclePose:
        since = None if self._last_ok_ns is None else (pose.stamp_ns - self._last_ok_ns) * 1e-9
        if since is None or since > self.max_bridge_s:
            pose = VehiclePose(pose.stamp_ns, pose.x_m, pose.y_m, pose.yaw_rad, pose.speed_mps,
                               pose.yaw_rate_radps, "lost",
                               pose.reason + (f" (no measured pose for {since:.2f} s)" if since is not None else ""))
        return self._remember(pose)

    def _remember(self, pose: VehiclePose) -> VehiclePose:
        self._last = pose
        return pose


class StereoVOLocalizer(PoseTracker):
    """Stereo VO (and, with a map, relocalisation) turned into :class:`VehiclePose` messages.

    The pose is carried forward by VO's frame-to-frame motion; each relocalisation against the
    map pulls it a fraction ``reloc.gain`` of the way onto the map's estimate.
    """

    def __init__(self, rig: StereoRig, pose_body_cam: Array, vo_config: StereoVOConfig | None = None,
                 config: LocalizerConfig | None = None, visual_map: VisualMap | None = None, *,
                 wrap_vo: Callable[[StereoVO], StereoVO] | None = None) -> None:
        """``wrap_vo`` is the seam fault injection wraps the VO at (``vo-failure``)."""
        self.config = config or LocalizerConfig()
        super().__init__(self.config.max_bridge_s, self.config.speed_time_constant_s)
        self.map = visual_map if self.config.reloc.enabled else None
        vo = StereoVO(rig, vo_config, (self.config.left_camera, self.config.right_camera))
        # VO finds features on its keyframes only; relocalisation finds its own on the other frames
        self._features = vo.config.features
        self._detector, self._binary = create_detector(self._features)
        self.vo = wrap_vo(vo) if wrap_vo is not None else vo
        self.rig = rig
        self.body_cam = np.asarray(pose_body_cam, float)
        self._raw: Pose2D | None = None  # VO's own ground pose at the last VO frame
        self._raw_stamp_ns = 0
        self._pose_at_raw: Pose2D = (0.0, 0.0, 0.0)  # the localizer's pose at that frame
        self._keyframe = 0
        self._previous_images: dict[str, Image] = {}
        self.relocalisations = 0
        self._reloc_ms: float | None = None  # summed once the map has been tried
        self.last_diagnostics: VODiagnostics | None = None  # what VO's stages kept in the last frame (None: no VO)

    def close(self) -> None:
        self.vo.close()

    def observe_speed(self, stamp_ns: int, speed_mps: float) -> None:
        """The kart's measured speed: for a bridged pose (:class:`PoseTracker`) and VO's motion model."""
        super().observe_speed(stamp_ns, speed_mps)
        self.vo.observe_speed(stamp_ns, speed_mps)

    @property
    def timing_ms(self) -> dict[str, float]:
        """VO's stages and the relocalisation, milliseconds summed over every frame."""
        return {**self.vo.timing_ms, **({"reloc": self._reloc_ms} if self._reloc_ms is not None else {})}

    def update(self, frames: FrameSet) -> VehiclePose:
        """The pose at ``frames.stamp_ns``."""
        cfg = self.config
        self.last_diagnostics = None
        left, right = frames.images.get(cfg.left_camera), frames.images.get(cfg.right_camera)
        if left is None or right is None:
            missing = cfg.left_camera if left is None else cfg.right_camera
            return self._bridge(frames.stamp_ns, f"the {missing} camera delivered nothing")
        for name, image in ((cfg.left_camera, left), (cfg.right_camera, right)):
            # a black or frozen frame would read as a standing kart: it is a missing frame
            problem = frame_problem(image, self._previous_images.get(name), cfg.health)
            self._previous_images[name] = image
            if problem:
                return self._bridge(frames.stamp_ns, f"the {name} camera's frame is {problem}")
        try:
            estimate = self.vo.process(frames)
        except (PerceptionError, OdometryError) as exc:
            return self._bridge(frames.stamp_ns, str(exc))
        self.last_diagnostics = estimate.diagnostics
        raw = vo_ground_pose(estimate.pose_world_cam, self.body_cam)
        step = (0.0, 0.0, 0.0) if self._raw is None else between_2d(self._raw, raw)
        pose = compose_2d(self._pose_at_raw, step) if self._raw is not None else raw
        dt = 0.0 if self._raw is None else (frames.stamp_ns - self._raw_stamp_ns) * 1e-9
        self._raw, self._raw_stamp_ns = raw, frames.stamp_ns
        if estimate.status != "bridged":
            self._last_ok_ns = frames.stamp_ns
            if self.map is not None:
                pose = self._relocalize(pose, frames)
        self._pose_at_raw = pose
        status = "bridged" if estimate.status == "bridged" else "ok"
        result = self._with_motion(frames.stamp_ns, pose, step, dt, status, estimate.reason)
        return self._check_lost(result) if status == "bridged" else self._remember(result)

    def _relocalize(self, pose: Pose2D, frames: FrameSet) -> Pose2D:
        assert self.map is not None
        t0 = time.perf_counter()
        reloc = self.config.reloc
        ground = self.map.ground_xy_yaw
        window = slice(max(self._keyframe - 2, 0), min(self._keyframe + reloc.search_keyframes, len(ground)))
        distance = np.hypot(ground[window, 0] - pose[0], ground[window, 1] - pose[1])
        order = window.start + np.argsort(distance)
        self._keyframe = int(order[0])
        vo_features = self.vo.last_features()
        latest = vo_features[0] if vo_features is not None else detect_features(
            grey_images(frames, (self.config.left_camera, self.config.right_camera))[0], self._detector,
            self._binary, self._features)
        for keyframe in order[: min(2, len(order))]:
            if abs(math.remainder(ground[keyframe, 2] - pose[2], math.tau)) > math.pi / 4:
                continue
            found = relocalize(self.map, int(keyframe), latest, self.rig.camera.matrix, reloc)
            if found is None:
                continue
            measured = vo_ground_pose(found[0], self.body_cam)
            error = between_2d(pose, measured)
            if math.hypot(error[0], error[1]) > reloc.max_correction_m or abs(error[2]) > reloc.max_correction_rad:
                continue
            self.relocalisations += 1
            pose = compose_2d(pose, (reloc.gain * error[0], reloc.gain * error[1], reloc.gain * error[2]))
            break
        self._reloc_ms = (self._reloc_ms or 0.0) + (time.perf_counter() - t0) * 1e3
        return pose

    @property
    def camera_name(self) -> str:
        return self.config.left_camera

    @property
    def camera(self) -> PinholeCamera:
        return self.rig.camera

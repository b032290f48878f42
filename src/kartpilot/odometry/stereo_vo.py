"""Stereo visual odometry: the thesis's pipeline, kept fast and made more accurate.

Per frame k (rectified pair):

1. Detect and describe keypoints in the left image (bucketed) and the right image.
2. Stereo correspondences: descriptor matches searched only along the epipolar
   band (or KLT from left to right), refined to sub-pixel disparity with KLT, then
   the epipolar filter (row difference <= 2 px) and the depth-range filter (1 to 45 m).
   Triangulation gives 3D points in the left camera frame of frame k.
3. Temporal correspondences: the previous left keypoints that have a 3D point are
   matched to this frame's left keypoints (descriptor ratio test, or KLT), and
   the match refined to sub-pixel with KLT. The left features of frame k are
   detected once and serve both the stereo match at k and the temporal match at k+1.
4. Motion: PnP in RANSAC, then Levenberg-Marquardt on the inliers; a sanity check
   bounds speed and rotation rate by the vehicle's limits. On failure the motion
   is bridged with a constant-velocity prediction and the reason is recorded.

The world frame is the left camera at the first frame (x right, y down, z forward),
as in KITTI's pose files.
"""

from __future__ import annotations

import logging
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from kartpilot.core.camera import StereoRig
from kartpilot.core.errors import ConfigError, PerceptionError
from kartpilot.core.geometry import Array, invert_pose, pose_from_rotvec, rotvec_from_pose
from kartpilot.core.types import FrameSet, Image, StereoFrame
from kartpilot.odometry.mono_vo import has_mount, level_mount
from kartpilot.odometry.motion_check import MotionLimits, StepVelocity, check_motion
from kartpilot.odometry.pnp import (
    AttitudePrior,
    MotionEstimate,
    PnpConfig,
    estimate_motion_from_prior,
    estimate_motion_pnp,
    refine_translation_near,
    refine_with_attitude_prior,
)
from kartpilot.odometry.stereo_refine import refine_pose_and_depths
from kartpilot.odometry.vo import grey_images
from kartpilot.odometry.window_ba import WindowBAConfig, WindowObservations, bundle_adjust_window
from kartpilot.perception.features import FeatureConfig, Features, create_detector, detect_features
from kartpilot.perception.matching import MatchConfig, match_descriptors, match_in_band
from kartpilot.perception.stereo import (
    BlockMatchConfig,
    StereoFilterConfig,
    compute_disparity,
    refine_disparity_zncc,
    stereo_filter_mask,
    stereo_match_margin,
    triangulate_rectified,
)
from kartpilot.perception.tracking import KltConfig, track_klt

__all__ = ["VO_STAGES", "StereoVO", "StereoVOConfig", "VODiagnostics", "VOEstimate", "VOStatus"]

logger = logging.getLogger(__name__)

VOStatus = Literal["init", "ok", "bridged"]


@dataclass(frozen=True)
class StereoVOConfig:
    """Stereo VO settings; the defaults are the recommended configuration.

    Attributes:
        stereo_matching: ``band`` (descriptors along the epipolar band), ``klt``, or ``dense``
            (block matching, ``block_match``, sampled at the left keypoints).
        temporal_matching: ``descriptor`` (ratio test, the thesis), ``klt``, or ``auto``: KLT with
            ``keyframes``, descriptors from frame to frame without (KLT from frame to frame drifts more on real
            roads: KITTI 06 1.05 % against 0.84 %, ``benchmarks/vo_ablation.py``).
        subpixel: refine descriptor matches to sub-pixel positions with KLT.
        joint_depth_refinement: after PnP, refine the pose jointly with each inlier's inverse
            depth, observed through its disparity (see ``stereo_refine``).
        window_ba: after PnP, refine the last frames' poses and the points tracked through them together
            (see ``window_ba``; frame-to-frame descriptor matching only: ``keyframes: false``).
        min_stereo_margin: keep a PnP inlier only if its stereo match's ZNCC beats every other disparity
            along its row by this much (``stereo_match_margin``); repeated structure such as a row of cones
            otherwise gives points metres off that pass every other filter. 0 turns the check off.
        motion_limits: what the vehicle can do. A step beyond them, or too far from the recent motion
            (``motion_check.check_motion``), is estimated again from the constant-velocity prediction
            (``pnp.estimate_motion_from_prior``); when that fails too, the frame is bridged.
        max_bridged_frames: consecutive bridged frames after which the estimate is reported lost.
        keyframes: track each frame against the last keyframe's 3D points (KLT from frame to frame, the pose
            from the keyframe's points by PnP), not against the previous frame's: an error is made once per
            keyframe, not once per frame, and stereo runs on keyframes only. ``temporal_matching: klt`` only.
        keyframe_min_share: a new keyframe when fewer than this share of the keyframe's points are still
            inliers (the view has changed: a bend turns them out of sight) ...
        keyframe_min_inliers: ... or fewer than this many, or the kart is ``keyframe_max_distance_m`` from it.
        keyframe_retrack: after KLT carried the points from frame to frame, track them once more straight from
            the keyframe's image, starting there: the chain's sub-pixel errors then do not add up.
        keyframe_prediction: KLT starts each keyframe point's search where the motion model predicts it; off,
            where it was in the previous image.
        motion_check: check each step against ``motion_limits`` and the recent motion; off, every step PnP
            gives is taken (for the ablation: ``benchmarks/vo_ablation.py``).
        attitude_prior_deg: hold the camera's roll and pitch near its mount's, as on a ground vehicle on a level
            world: after PnP, the motion is refined again with the camera's up direction held near the mount's
            within this many degrees (``pnp.refine_with_attitude_prior``). A prior, not a clamp. Off (0) by
            default: real roads slope and bank and a car rolls in a bend, and held to the first frame's attitude
            VO drifted more on every clip measured, real and simulated (KITTI 06 0.80 % against 0.69 %, utrack
            seed 3 1.71 % against 0.55 %: ``benchmarks/vo_ablation.py``). Where set, it applies only where the
            rig's camera has a mount (its pose on a ground vehicle: a kart's rig); a rig without one (a dataset's:
            EuRoC's is hand-held) never gets it, and the log says so.
    """

    features: FeatureConfig = field(default_factory=FeatureConfig)
    matching: MatchConfig = field(default_factory=MatchConfig)
    stereo: StereoFilterConfig = field(default_factory=StereoFilterConfig)
    klt: KltConfig = field(default_factory=KltConfig)
    pnp: PnpConfig = field(default_factory=PnpConfig)
    block_match: BlockMatchConfig = field(default_factory=BlockMatchConfig)
    stereo_matching: Literal["band", "klt", "dense"] = "band"
    temporal_matching: Literal["auto", "descriptor", "klt"] = "auto"
    subpixel: bool = True
    joint_depth_refinement: bool = False
    window_ba: WindowBAConfig = field(default_factory=WindowBAConfig)
    min_stereo_margin: float = 0.0
    motion_limits: MotionLimits = field(default_factory=MotionLimits)
    max_bridged_frames: int = 10
    keyframes: bool = True
    keyframe_min_share: float = 0.5
    keyframe_min_inliers: int = 30
    keyframe_max_distance_m: float = 3.0
    keyframe_retrack: bool = True
    keyframe_prediction: bool = True
    motion_check: bool = True
    attitude_prior_deg: float = 0.0

    def __post_init__(self) -> None:
        if self.keyframes and self.temporal != "klt":
            raise ConfigError("stereo_vo.keyframes needs temporal_matching: klt (set keyframes: false for "
                              "descriptor matching from frame to frame)")
        if self.joint_depth_refinement and self.keyframes:
            raise ConfigError("stereo_vo.joint_depth_refinement works from frame to frame: set keyframes: false")
        if self.window_ba.enabled and (self.keyframes or self.temporal != "descriptor"):
            raise ConfigError("stereo_vo.window_ba needs temporal_matching: descriptor and keyframes: false")
        if not 0.0 < self.keyframe_min_share < 1.0 or self.keyframe_min_inliers < 6 \
                or not self.keyframe_max_distance_m > 0:
            raise ConfigError("stereo_vo: keyframe_min_share must be in (0, 1), keyframe_min_inliers at least 6 "
                              "and keyframe_max_distance_m positive")
        if not 0.0 <= self.min_stereo_margin < 2.0:
            raise ConfigError(f"stereo_vo.min_stereo_margin must be in [0, 2), got {self.min_stereo_margin}")
        if not 0.0 <= self.attitude_prior_deg <= 90.0:
            raise ConfigError(f"stereo_vo.attitude_prior_deg must be in [0, 90], got {self.attitude_prior_deg}")

    @property
    def temporal(self) -> Literal["descriptor", "klt"]:
        """The temporal matching in use (``auto`` resolved)."""
        if self.temporal_matching == "auto":
            return "klt" if self.keyframes else "descriptor"
        return self.temporal_matching


VO_STAGES = ("left_features", "stereo_matches", "epipolar_ok", "depth_ok", "temporal_matches", "inliers")
"""The counts of :class:`VODiagnostics`, filter stage by filter stage, in the order the points go through."""


@dataclass(frozen=True)
class VODiagnostics:
    """What each stage kept in one frame, for the analyses of the thesis's research questions.

    Counts: ``left_features``, ``right_features``, ``stereo_matches`` (before filters),
    ``epipolar_ok``, ``depth_ok`` (3D points kept), ``temporal_matches``, ``inliers``.
    ``motion_from_prior``: RANSAC's motion was implausible (see ``motion_limits``) and the motion was
    found again from the constant-velocity prediction.
    ``inlier_pixels`` (M, 2) and ``inlier_depths_m`` (M,) are the final points in the
    previous left image, for feature-distribution grids and depth histograms.
    """

    left_features: int = 0
    right_features: int = 0
    stereo_matches: int = 0
    epipolar_ok: int = 0
    depth_ok: int = 0
    temporal_matches: int = 0
    inliers: int = 0
    reprojection_rmse_px: float = float("nan")
    motion_from_prior: bool = False
    timing_ms: dict[str, float] = field(default_factory=dict)
    inlier_pixels: Array = field(default_factory=lambda: np.zeros((0, 2)))
    inlier_depths_m: Array = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class VOEstimate:
    """The VO output for one frame.

    Attributes:
        pose_world_cam: 4x4 left-camera pose in the world frame (the first left camera).
        status: ``init`` (first frame), ``ok`` (measured) or ``bridged`` (predicted).
        lost: True once more than ``max_bridged_frames`` consecutive frames were bridged.
    """

    index: int
    stamp_ns: int
    pose_world_cam: Array
    status: VOStatus
    reason: str
    lost: bool
    diagnostics: VODiagnostics

    @property
    def inliers(self) -> int:
        return self.diagnostics.inliers


@dataclass
class _Keyframe:
    """The state carried from one frame to the next."""

    image: Image
    right: Image
    features: Features
    points_m: Array  # (N, 3) per left feature, NaN where no valid stereo depth
    stamp_ns: int


@dataclass
class _Anchor:
    """The keyframe tracked against: its pose, its 3D points (its camera frame) and where KLT has them in the
    latest image."""

    pose_world_kf: Array
    points_m: Array  # (N, 3)
    pixels_px: NDArray[np.float32]  # (N, 2) in the latest image
    image: Image  # the latest left image
    stamp_ns: int  # the latest frame's
    pose_prev_kf: Array  # the latest frame's camera from the keyframe's
    first_count: int  # inliers when it was made (its points with depth)
    kf_image: Image  # the keyframe's left image
    kf_stamp_ns: int
    kf_pixels_px: NDArray[np.float32]  # (N, 2) the points' pixels in it


@dataclass
class _WindowFrame:
    """A frame of the bundle adjustment's window: its pose, and per left feature its track and disparity."""

    pose_world_cam: Array
    tracks: NDArray[np.intp]  # (N,) the track each feature belongs to
    pixels_px: Array  # (N, 2)
    disparities_px: Array  # (N,), NaN where stereo gave no depth


class _Timer:
    def __init__(self) -> None:
        self.timing: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.timing[name] = self.timing.get(name, 0.0) + (now - self._last) * 1e3
        self._last = now


class StereoVO:
    """Frame-to-frame stereo VO. Holds only what must persist between frames."""

    def __init__(self, rig: StereoRig, config: StereoVOConfig | None = None,
                 cameras: tuple[str, str] = ("left", "right")) -> None:
        """``cameras`` names the left and right cameras in the frame sets :meth:`process` takes."""
        self.rig = rig
        self.config = config or StereoVOConfig()
        self.cameras = cameras
        self.timing_ms: dict[str, float] = {}
        self._detector, self._binary = create_detector(self.config.features)
        # OpenCV releases the GIL: the right image is detected on a second thread
        self._right_detector, _ = create_detector(self.config.features)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="vo-detect")
        self._previous: _Keyframe | None = None
        self._pose_world_cam = np.eye(4)
        self._velocity_cur_prev: Array = np.eye(4)  # last accepted motion, for bridging
        self._velocity_dt_s = 0.1
        self._recent: StepVelocity | None = None  # the last accepted step, for the motion check
        self._bridged_in_row = 0
        self._window: list[_WindowFrame] = []
        self._next_track = 0
        self._anchor: _Anchor | None = None
        self._latest_ns = -1
        self._measured_speed: tuple[int, float] | None = None  # (stamp_ns, m/s), the kart's own
        # the body's up seen from the camera on its mount; the world frame is the first camera, on its mount
        self._up_mount = level_mount(rig.camera)[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        # the attitude prior holds a ground vehicle's roll and pitch: a rig that does not say it is on one (no
        # mount: a hand-held or flown rig, EuRoC's) does not get it
        self.attitude_prior = self.config.attitude_prior_deg > 0 and has_mount(rig.camera)
        if self.config.attitude_prior_deg > 0 and not self.attitude_prior:
            logger.info("stereo VO without the attitude prior: the rig's camera has no mount on a ground vehicle")

    def close(self) -> None:
        """Stop the detection thread."""
        self._pool.shutdown(wait=False)

    @property
    def pose_world_cam(self) -> Array:
        return self._pose_world_cam.copy()

    def last_features(self) -> tuple[Features, Array] | None:
        """The latest frame's left features and their 3D points in its camera frame (NaN rows where
        stereo gave no depth), or None before the first frame, and with ``keyframes`` where the latest frame was
        not a keyframe (features are then found on keyframes only). For building and matching maps."""
        if self._previous is None or (self.config.keyframes and self._previous.stamp_ns != self._latest_ns):
            return None
        return self._previous.features, self._previous.points_m

    @property
    def scale_source(self) -> str:
        return f"stereo baseline ({self.rig.baseline_m:g} m)"

    def process(self, frames: FrameSet) -> VOEstimate:
        """Consume one rectified stereo pair (the ``cameras`` of ``frames``) and return the updated pose."""
        left, right = grey_images(frames, self.cameras)
        estimate = self._process(StereoFrame(frames.index, frames.stamp_ns, left, right))
        for stage, ms in estimate.diagnostics.timing_ms.items():
            self.timing_ms[stage] = self.timing_ms.get(stage, 0.0) + ms
        return estimate

    def _process(self, frame: StereoFrame) -> VOEstimate:
        expected = (self.rig.camera.height_px, self.rig.camera.width_px)
        if frame.left.shape != expected or frame.right.shape != expected:
            raise PerceptionError(
                f"frame {frame.index}: images are {frame.left.shape}/{frame.right.shape}, "
                f"the rig expects {expected}"
            )
        timer = _Timer()
        self._latest_ns = frame.stamp_ns
        if self.config.keyframes:
            return self._process_keyframed(frame, timer)
        features, points_m, counts = self._stereo_points(frame, timer)
        current = _Keyframe(frame.left, frame.right, features, points_m, frame.stamp_ns)
        previous, self._previous = self._previous, current
        if previous is None:
            if self.config.window_ba.enabled:
                self._adjust_window(current, None)
            return VOEstimate(frame.index, frame.stamp_ns, self.pose_world_cam, "init", "", False,
                              replace(counts, timing_ms=timer.timing))
        dt_s = max((frame.stamp_ns - previous.stamp_ns) * 1e-9, 1e-3)
        prev_points, cur_pixels, prev_pixels, pairs = self._temporal_correspondences(previous, current, timer)
        disparities = self.rig.camera.fx_px * self.rig.baseline_m / prev_points[:, 2]
        vet = None
        if self.config.min_stereo_margin > 0:
            def vet(index: NDArray[np.intp]) -> NDArray[np.bool_]:
                """The inliers whose stereo match is unambiguous along its row in the previous pair."""
                low, high = self.config.stereo.disparity_range_px(self.rig)
                margins = stereo_match_margin(previous.image, previous.right, prev_pixels[index], disparities[index],
                                              low, high)
                return margins >= self.config.min_stereo_margin
        motion = estimate_motion_pnp(prev_points, cur_pixels, self.rig.camera.matrix, self.config.pnp,
                                     disparities, vet)
        step, reason = self._checked(motion, previous.stamp_ns, frame.stamp_ns)
        from_prior = False
        if reason and self._recent is not None:
            retry = estimate_motion_from_prior(prev_points, cur_pixels, self.rig.camera.matrix, self.config.pnp,
                                               self._predicted(dt_s), disparities)
            retry_step, retry_reason = self._checked(retry, previous.stamp_ns, frame.stamp_ns)
            if not retry_reason:
                logger.info("frame %d: motion from the prediction (%s)", frame.index, reason)
                motion, step, reason, from_prior = retry, retry_step, retry_reason, True
        if motion.ok and self.config.joint_depth_refinement:
            inl = motion.inliers
            refined = refine_pose_and_depths(motion.pose_cur_prev, prev_pixels[inl].astype(np.float64),
                                             disparities[inl], cur_pixels[inl].astype(np.float64),
                                             self.rig.camera.matrix, self.rig.baseline_m)
            motion = replace(motion, pose_cur_prev=refined)
            step, reason = self._checked(motion, previous.stamp_ns, frame.stamp_ns)
        if motion.ok and self.attitude_prior:
            motion = replace(motion, pose_cur_prev=self._with_attitude_prior(motion, prev_points, cur_pixels,
                                                                             self._pose_world_cam, disparities))
            step, reason = self._checked(motion, previous.stamp_ns, frame.stamp_ns)
        timer.lap("pnp")
        diagnostics = replace(
            counts, temporal_matches=len(prev_points), inliers=len(motion.inliers), motion_from_prior=from_prior,
            reprojection_rmse_px=motion.reprojection_rmse_px, timing_ms=timer.timing,
            inlier_pixels=prev_pixels[motion.inliers], inlier_depths_m=prev_points[motion.inliers, 2])
        status: VOStatus
        if motion.ok and not reason:
            pose_cur_prev, status = motion.pose_cur_prev, "ok"
            self._velocity_cur_prev, self._velocity_dt_s = pose_cur_prev, dt_s
            self._recent = step
            self._bridged_in_row = 0
        else:
            pose_cur_prev, status = self._predicted(dt_s), "bridged"
            self._bridged_in_row += 1
            logger.info("frame %d bridged with constant velocity: %s", frame.index, reason)
        self._pose_world_cam = self._pose_world_cam @ invert_pose(pose_cur_prev)
        if self.config.window_ba.enabled:
            self._adjust_window(current, pairs[:, motion.inliers] if status == "ok" else None)
            timer.lap("window_ba")
        lost = self._bridged_in_row > self.config.max_bridged_frames
        return VOEstimate(frame.index, frame.stamp_ns, self.pose_world_cam, status, reason, lost, diagnostics)

    def _new_anchor(self, frame: StereoFrame, timer: _Timer) -> VODiagnostics:
        """Make the frame the keyframe: its stereo points, at the current pose."""
        features, points_m, counts = self._stereo_points(frame, timer)
        self._previous = _Keyframe(frame.left, frame.right, features, points_m, frame.stamp_ns)
        with_depth = np.isfinite(points_m[:, 2])
        pixels = features.points_px[with_depth].astype(np.float32)
        self._anchor = _Anchor(self._pose_world_cam.copy(), points_m[with_depth], pixels, frame.left, frame.stamp_ns,
                               np.eye(4), int(with_depth.sum()), frame.left, frame.stamp_ns, pixels)
        return counts

    def _process_keyframed(self, frame: StereoFrame, timer: _Timer) -> VOEstimate:
        """One frame against the keyframe (``keyframes``): KLT carries the keyframe's points from the previous
        image into this one; PnP (RANSAC, the motion check, the prediction where RANSAC's motion is implausible)
        gives this camera's pose from the keyframe's; a new keyframe where too few of its points remain."""
        anchor = self._anchor
        if anchor is None:
            counts = self._new_anchor(frame, timer)
            return VOEstimate(frame.index, frame.stamp_ns, self.pose_world_cam, "init", "", False,
                              replace(counts, timing_ms=timer.timing))
        config = self.config
        dt_s = max((frame.stamp_ns - anchor.stamp_ns) * 1e-9, 1e-3)
        predicted_kf = self._predicted(dt_s) @ anchor.pose_prev_kf  # this camera from the keyframe's, predicted
        points, pixels, kf_pixels = self._track_anchor(anchor, frame.left, predicted_kf)
        timer.lap("temporal_match")
        motion, step, reason, from_prior = self._solve_from_anchor(anchor, points, pixels, predicted_kf,
                                                                   frame.stamp_ns)
        timer.lap("pnp")
        diagnostics = VODiagnostics(
            temporal_matches=len(points), inliers=len(motion.inliers), motion_from_prior=from_prior,
            reprojection_rmse_px=motion.reprojection_rmse_px,
            inlier_pixels=pixels[motion.inliers], inlier_depths_m=points[motion.inliers, 2])
        if motion.ok and not reason:
            pose_cur_prev = motion.pose_cur_prev @ invert_pose(anchor.pose_prev_kf)
            self._velocity_cur_prev, self._velocity_dt_s = pose_cur_prev, dt_s
            self._recent = step
            self._bridged_in_row = 0
            self._pose_world_cam = anchor.pose_world_kf @ invert_pose(motion.pose_cur_prev)
            keep = motion.inliers
            self._anchor = replace(anchor, points_m=points[keep], pixels_px=pixels[keep], image=frame.left,
                                   stamp_ns=frame.stamp_ns, pose_prev_kf=motion.pose_cur_prev,
                                   kf_pixels_px=kf_pixels[keep])
            status: VOStatus = "ok"
            far = float(np.linalg.norm(motion.pose_cur_prev[:3, 3])) > config.keyframe_max_distance_m
            if far or len(keep) < max(config.keyframe_min_inliers, config.keyframe_min_share * anchor.first_count):
                counts = self._new_anchor(frame, timer)
                diagnostics = replace(counts, temporal_matches=diagnostics.temporal_matches,
                                      inliers=diagnostics.inliers, motion_from_prior=from_prior,
                                      reprojection_rmse_px=diagnostics.reprojection_rmse_px,
                                      inlier_pixels=diagnostics.inlier_pixels,
                                      inlier_depths_m=diagnostics.inlier_depths_m)
        else:
            status = "bridged"
            self._bridged_in_row += 1
            logger.info("frame %d bridged with constant velocity: %s", frame.index, reason)
            self._pose_world_cam = self._pose_world_cam @ invert_pose(self._predicted(dt_s))
            counts = self._new_anchor(frame, timer)  # start again from this frame's own points
            diagnostics = replace(counts, temporal_matches=diagnostics.temporal_matches)
        lost = self._bridged_in_row > config.max_bridged_frames
        return VOEstimate(frame.index, frame.stamp_ns, self.pose_world_cam, status, reason, lost,
                          replace(diagnostics, timing_ms=timer.timing))

    def _track_anchor(self, anchor: _Anchor, image: Image, predicted_kf: Array) -> tuple[Array, Array, Array]:
        """The keyframe's points still seen in ``image``: their 3D points, their pixels here and in the keyframe.
        KLT carries them from the previous image, starting where the predicted motion (``predicted_kf``: this
        camera from the keyframe's) puts them, then (``keyframe_retrack``) from the keyframe's own image, starting
        where the chain put them, so the chain's small errors do not add up from frame to frame."""
        config = self.config
        guess = anchor.pixels_px
        if self._recent is not None and config.keyframe_prediction:
            moved = anchor.points_m @ predicted_kf[:3, :3].T + predicted_kf[:3, 3]
            if np.all(moved[:, 2] > 0.1):
                guess = self.rig.camera.project(moved).astype(np.float32)
        pixels, tracked = track_klt(anchor.image, image, anchor.pixels_px, config.klt, initial_px=guess)
        if config.keyframe_retrack:
            direct, direct_ok = track_klt(anchor.kf_image, image, anchor.kf_pixels_px, _stereo_klt(config.klt),
                                          initial_px=pixels)
            pixels = np.where(direct_ok[:, None], direct, pixels)
            tracked |= direct_ok
        return anchor.points_m[tracked], pixels[tracked], anchor.kf_pixels_px[tracked]

    def _solve_from_anchor(self, anchor: _Anchor, points: Array, pixels: Array, predicted_kf: Array, stamp_ns: int
                           ) -> tuple[MotionEstimate, StepVelocity | None, str, bool]:
        """This camera's motion from the keyframe's: PnP in RANSAC, or from the prediction where RANSAC's motion
        fails the motion check; then the attitude prior. The motion, its step, why it is no step the kart can
        have made (empty when it is), and whether it came from the prediction."""
        config = self.config
        K = self.rig.camera.matrix
        disparities = self.rig.camera.fx_px * self.rig.baseline_m / points[:, 2]
        motion = estimate_motion_pnp(points, pixels, K, config.pnp, disparities)
        step, reason = self._checked_from(motion, anchor, stamp_ns)
        from_prior = False
        if reason and self._recent is not None:
            retry = estimate_motion_from_prior(points, pixels, K, config.pnp, predicted_kf, disparities)
            retry_step, retry_reason = self._checked_from(retry, anchor, stamp_ns)
            if not retry_reason:
                logger.info("at %d ns: motion from the prediction (%s)", stamp_ns, reason)
                motion, step, reason, from_prior = retry, retry_step, retry_reason, True
        if motion.ok and not reason and self.attitude_prior:
            motion = replace(motion, pose_cur_prev=self._with_attitude_prior(motion, points, pixels,
                                                                             anchor.pose_world_kf))
            step, reason = self._checked_from(motion, anchor, stamp_ns)
        return motion, step, reason, from_prior

    def _checked_from(self, motion: MotionEstimate, anchor: _Anchor, stamp_ns: int
                      ) -> tuple[StepVelocity | None, str]:
        """:meth:`_checked` for a motion from the keyframe: its mean velocity since the keyframe is checked (each
        frame's pose is measured from the keyframe, so two frames' small errors do not add up to a jolt)."""
        return self._checked(motion, anchor.kf_stamp_ns, stamp_ns)

    def _with_attitude_prior(self, motion: MotionEstimate, points: Array, pixels: Array, pose_world_from: Array,
                             disparities: Array | None = None) -> Array:
        """The motion from the camera at ``pose_world_from`` refined with the attitude prior on its inliers; with
        ``disparities``, then its translation from the near ones again (as PnP's refinement ends: far points'
        depths are biased long)."""
        inl = motion.inliers
        up_from = pose_world_from[:3, :3].T @ self._up_mount
        prior = AttitudePrior(up_from, self._up_mount, float(np.radians(self.config.attitude_prior_deg)))
        K = self.rig.camera.matrix
        pose = refine_with_attitude_prior(motion.pose_cur_prev, points[inl], pixels[inl], K, prior)
        return refine_translation_near(pose, points, pixels, K, inl, disparities, self.config.pnp)

    def _checked(self, motion: MotionEstimate, start_ns: int, end_ns: int) -> tuple[StepVelocity | None, str]:
        """``motion``'s step, and why it is no step the vehicle can have made (the estimate's own failure, or the
        motion check's; empty when it is)."""
        if not motion.ok:
            return None, motion.reason
        step = StepVelocity.of_step(motion.pose_cur_prev, start_ns, end_ns)
        if not self.config.motion_check:
            return step, ""
        return step, check_motion(step, self.config.motion_limits, self._recent)

    def observe_speed(self, stamp_ns: int, speed_mps: float) -> None:
        """The kart's own measured speed (the RDW kart's 0x440 wheel speed): the motion model's prediction then
        moves at it, in the direction of the last motion, while it is younger than half a second. Without one (a
        dataset) the model is constant velocity."""
        if math.isfinite(speed_mps):
            self._measured_speed = (stamp_ns, speed_mps)

    def _predicted(self, dt_s: float) -> Array:
        """The motion model's ``pose_cur_prev`` over ``dt_s``: the last motion (constant velocity), its length
        the measured speed's where a fresh one was observed."""
        scale = dt_s / self._velocity_dt_s
        rotvec, translation = rotvec_from_pose(self._velocity_cur_prev) * scale, self._velocity_cur_prev[:3, 3] * scale
        measured = self._measured_speed
        length = float(np.linalg.norm(translation))
        if measured is not None and abs(self._latest_ns - measured[0]) <= 5e8 and length > 1e-6:
            translation = translation * (abs(measured[1]) * dt_s / length)
        return pose_from_rotvec(rotvec, translation)

    def _stereo_points(self, frame: StereoFrame, timer: _Timer) -> tuple[Features, Array, VODiagnostics]:
        config = self.config
        right_future = None
        if config.stereo_matching == "band":
            right_future = self._pool.submit(detect_features, frame.right, self._right_detector,
                                             self._binary, config.features)
        left = detect_features(frame.left, self._detector, self._binary, config.features)
        points_m = np.full((len(left), 3), np.nan)
        counts = VODiagnostics(left_features=len(left))
        band = config.stereo.epipolar_band_px
        min_disp, max_disp = config.stereo.disparity_range_px(self.rig)
        if right_future is not None:
            right = right_future.result()
            timer.lap("detect")
            counts = replace(counts, right_features=len(right))
            # search a slightly wider band and range; the filters below apply the exact limits
            matches = match_in_band(left.points_px, left.descriptors, right.points_px, right.descriptors,
                                    self._binary, band + 1.0, 0.5 * min_disp, 1.5 * max_disp + 2.0,
                                    config.matching.ratio)
            left_index = matches.index_a
            right_px = right.points_px[matches.index_b]
            if config.subpixel and len(left_index):
                rounded, disparity, good = refine_disparity_zncc(
                    frame.left, frame.right, left.points_px[left_index],
                    left.points_px[left_index, 0] - right_px[:, 0])
                left_index = left_index[good]
                # the 3D point belongs to the pixel ZNCC measured at: move those keypoints there
                points_px = left.points_px.copy()
                points_px[left_index] = rounded[good]
                left = replace(left, points_px=points_px)
                right_px = rounded[good].copy()
                right_px[:, 0] -= disparity[good]
        elif config.stereo_matching == "dense":
            timer.lap("detect")
            disparity_map = compute_disparity(frame.left, frame.right, config.block_match)
            columns = np.clip(np.rint(left.points_px[:, 0]).astype(np.intp), 0, frame.left.shape[1] - 1)
            rows = np.clip(np.rint(left.points_px[:, 1]).astype(np.intp), 0, frame.left.shape[0] - 1)
            sampled = disparity_map[rows, columns]
            left_index = np.flatnonzero(np.isfinite(sampled))
            right_px = left.points_px[left_index].copy()
            right_px[:, 0] -= sampled[left_index]
        else:
            timer.lap("detect")
            left_index = np.arange(len(left))
            guess = left.points_px.copy()
            guess[:, 0] -= 0.5 * (min_disp + max_disp)
            right_px, tracked = track_klt(frame.left, frame.right, left.points_px, config.klt, initial_px=guess)
            left_index, right_px = left_index[tracked], right_px[tracked]
        timer.lap("stereo_match")
        counts = replace(counts, stereo_matches=len(left_index))
        left_px = left.points_px[left_index]
        epipolar_ok, depth_ok = stereo_filter_mask(self.rig, left_px, right_px, config.stereo)
        counts = replace(counts, epipolar_ok=int(epipolar_ok.sum()), depth_ok=int(depth_ok.sum()))
        points_m[left_index[depth_ok]] = triangulate_rectified(self.rig, left_px[depth_ok], right_px[depth_ok])
        timer.lap("triangulate")
        return left, points_m, counts

    def _temporal_correspondences(self, previous: _Keyframe, current: _Keyframe, timer: _Timer
                                  ) -> tuple[Array, NDArray[np.float32], NDArray[np.float32], NDArray[np.intp]]:
        """(M, 3) previous-frame points, their (M, 2) current pixels and (M, 2) previous pixels, and (2, M) the
        previous and current feature indices (-1 for the current one where KLT tracked the point)."""
        config = self.config
        with_depth = np.flatnonzero(np.isfinite(previous.points_m[:, 2]))
        prev_px = previous.features.points_px[with_depth]
        if config.temporal == "descriptor":
            matches = match_descriptors(previous.features.descriptors[with_depth], current.features.descriptors,
                                        self._binary, config.matching)
            prev_index = with_depth[matches.index_a]
            cur_index = matches.index_b
            prev_px = prev_px[matches.index_a]
            cur_px = current.features.points_px[matches.index_b]
            if config.subpixel and len(prev_index):
                cur_px, tracked = track_klt(previous.image, current.image, prev_px, _stereo_klt(config.klt),
                                            initial_px=cur_px)
                prev_index, prev_px, cur_px = prev_index[tracked], prev_px[tracked], cur_px[tracked]
                cur_index = cur_index[tracked]
        else:
            cur_px, tracked = track_klt(previous.image, current.image, prev_px, config.klt)
            prev_index, prev_px, cur_px = with_depth[tracked], prev_px[tracked], cur_px[tracked]
            cur_index = np.full(len(prev_index), -1, np.intp)
        timer.lap("temporal_match")
        return previous.points_m[prev_index], cur_px, prev_px, np.vstack([prev_index, cur_index])

    def _adjust_window(self, current: _Keyframe, pairs: NDArray[np.intp] | None) -> None:
        """Add the current frame to the window, its features continuing the previous frame's tracks where
        ``pairs`` (previous and current feature indices, the motion's inliers) link them, and refine the
        window (:func:`bundle_adjust_window`). Without pairs (the first frame, a bridged one) the window starts
        again at the current frame."""
        count = len(current.features)
        tracks = self._next_track + np.arange(count)
        self._next_track += count
        if pairs is None:
            self._window.clear()
        else:
            linked = pairs[1] >= 0
            tracks[pairs[1, linked]] = self._window[-1].tracks[pairs[0, linked]]
        disparities = self.rig.camera.fx_px * self.rig.baseline_m / current.points_m[:, 2]
        self._window.append(_WindowFrame(self.pose_world_cam, tracks, current.features.points_px.astype(float),
                                         disparities))
        config = self.config.window_ba
        del self._window[:-config.frames]
        if len(self._window) < 3:
            return
        problem = window_problem(self._window, self.rig, config.min_observations)
        if problem is None:
            return
        points, observations = problem
        poses = np.array([f.pose_world_cam for f in self._window])
        refined, _ = bundle_adjust_window(poses, points, observations, self.rig.camera.matrix, self.rig.baseline_m,
                                          config)
        for frame, pose in zip(self._window, refined, strict=True):
            frame.pose_world_cam = pose
        self._pose_world_cam = refined[-1].copy()


def window_problem(window: list[_WindowFrame], rig: StereoRig, min_observations: int
                   ) -> tuple[Array, WindowObservations] | None:
    """The window's points (triangulated where first seen with a disparity, in the world frame) and their
    observations, for the tracks seen in at least ``min_observations`` frames; None when there are none."""
    frame_of = np.concatenate([np.full(len(f.tracks), i, np.intp) for i, f in enumerate(window)])
    tracks = np.concatenate([f.tracks for f in window])
    pixels = np.concatenate([f.pixels_px for f in window])
    disparities = np.concatenate([f.disparities_px for f in window])
    ids, inverse, counts = np.unique(tracks, return_inverse=True, return_counts=True)
    keep = counts[inverse] >= min_observations
    if not keep.any():
        return None
    frame_of, pixels, disparities, inverse = frame_of[keep], pixels[keep], disparities[keep], inverse[keep]
    seen = np.isfinite(disparities) & (disparities > 0)
    # each point from its first observation with a disparity (the observations are in frame order)
    with_disparity = np.flatnonzero(seen)
    point_ids, first = np.unique(inverse[with_disparity], return_index=True)
    if len(point_ids) == 0:
        return None
    used = np.isin(inverse, point_ids)
    index_of = np.full(len(ids), -1, np.intp)
    index_of[point_ids] = np.arange(len(point_ids))
    k = rig.camera.matrix
    anchors = with_disparity[first]
    z = k[0, 0] * rig.baseline_m / disparities[anchors]
    cam = np.column_stack([(pixels[anchors, 0] - k[0, 2]) * z / k[0, 0], (pixels[anchors, 1] - k[1, 2]) * z / k[1, 1],
                           z, np.ones_like(z)])
    poses = np.array([f.pose_world_cam for f in window])
    world = np.einsum("mij,mj->mi", poses[frame_of[anchors]], cam)[:, :3]
    observations = WindowObservations(frame_of[used], index_of[inverse[used]], pixels[used],
                                      np.where(seen[used], disparities[used], np.nan))
    return world, observations


def _stereo_klt(config: KltConfig) -> KltConfig:
    """KLT settings for refining an existing match: small window, no pyramid needed."""
    return KltConfig(window_px=min(config.window_px, 11), pyramid_levels=1,
                     max_fb_error_px=config.max_fb_error_px, iterations=config.iterations)

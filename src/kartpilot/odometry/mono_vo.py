"""Monocular visual odometry with metric scale from the ground plane.

Per frame k (one camera, rectified or undistorted):

1. Corners (Shi-Tomasi) in frame k-1, tracked into frame k with pyramidal KLT and a
   forward-backward check (the thesis's KLT tracking).
2. Relative motion up to scale: the essential matrix in RANSAC, then ``recoverPose``
   with its chirality check. The translation has unit length.
3. Scale from the ground plane, never from ground truth. The road seen ahead is a plane;
   between two frames its points move by the plane-induced homography ``K (R + t m^T) K^-1``,
   with ``m = n / d``: the plane's normal over its distance in the units of the unit-length
   ``t``. Since the camera's height above the road is known, the metric scale of ``t`` is
   ``camera_height_m * |m|``.
   - Road points are tracked separately, from where the homography of the previous scale
     predicts them. At 10 Hz and 12 m/s, a road point near the camera moves 40 px or more,
     further than KLT finds on weak road texture without a good start.
   - ``m`` is fitted in RANSAC (three points, reprojection error in pixels) with the
     normal within ``max_tilt_deg`` of the camera's down axis. The fit is refined by
     least squares on the inliers.
   - The scale is the median of the last ``scale_window`` estimates, so one bad road
     patch (a car ahead, a shadow) does not carry into the trajectory.
4. The pose: ``T_world_cam(k) = T_world_cam(k-1) @ inv([R | scale * t])``.

Without enough tracks, or without a motion (the camera standing), the frame is
bridged (no motion) and counted.

The road region is taken from geometry: the ground from 2.5 to 15 camera heights ahead and
2.5 to each side, projected with the camera's intrinsics, its height and
its mount (``pose_body_cam``; a camera without a mount is taken as level). The mount
also gives the prior of the plane's normal; the normal itself is then estimated.

That is the ``general`` motion, the thesis's. A camera with a mount uses the ``arc`` instead (``motion:
auto``): the vehicle's step is an arc of a circle (a turn and a length), and both are found by aligning the
road region between the frames through the plane's homography (:func:`align_road_arc`), with no tracks.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array, mount_pose, pitched_mount
from kartpilot.core.types import FrameSet, Image
from kartpilot.core.vehicle import VehicleParams
from kartpilot.odometry.motion_check import MotionLimits, StepVelocity, check_motion
from kartpilot.odometry.vo import grey_images
from kartpilot.perception.tracking import KltConfig, track_klt

__all__ = [
    "GroundConfig",
    "MonoEstimate",
    "MonoVO",
    "MonoVOConfig",
    "align_road_arc",
    "align_road_pitch",
    "arc_step",
    "beyond_ground_mask",
    "fit_ground_homography",
    "ground_normal_prior",
    "ground_region",
    "has_mount",
    "level_mount",
    "mount_normal",
    "relative_pose",
    "rotation_only",
]

log = logging.getLogger(__name__)

ARC_PITCH_MIN_MEASUREMENTS = 5  # the arc keeps the mount's pitch until this many measurements give a median

F32 = NDArray[np.float32]


@dataclass(frozen=True)
class GroundConfig:
    """The ground plane's part in the scale.

    Attributes:
        camera_height_m: the camera's height above the road (1.65 on KITTI's car, 0.6 on the SDC kart).
        near_heights, far_heights, half_width_heights: the road region, ahead of the camera and to each side, in
            camera heights (the region's place in the image depends on these ratios alone: 4 to 25 m ahead on
            KITTI's car, 1.5 to 9 m on the SDC kart).
        corners, corner_quality, corner_spacing_px: road corners detected per frame (weak texture: a low
            quality threshold).
        inlier_px: reprojection error of a road point under the plane's homography.
        iterations: RANSAC hypotheses.
        max_tilt_deg: the plane's normal within this of its prior (from the camera's mount).
        scale_window: the scale is the median of this many recent estimates.
        min_points: fewer road inliers than this give no estimate.
    """

    camera_height_m: float = 1.65
    near_heights: float = 2.5
    far_heights: float = 15.0
    half_width_heights: float = 2.5
    corners: int = 800
    corner_quality: float = 0.001
    corner_spacing_px: int = 5
    inlier_px: float = 1.0
    iterations: int = 300
    max_tilt_deg: float = 10.0
    scale_window: int = 5
    min_points: int = 10

    def __post_init__(self) -> None:
        if self.camera_height_m <= 0:
            raise ConfigError("mono_vo.ground.camera_height_m must be positive (the camera's height above the road)")
        if not 0 < self.near_heights < self.far_heights or self.half_width_heights <= 0:
            raise ConfigError("mono_vo.ground: 0 < near_heights < far_heights and half_width_heights > 0")
        if self.iterations < 1 or self.inlier_px <= 0:
            raise ConfigError("mono_vo.ground.iterations must be at least 1 and mono_vo.ground.inlier_px positive")


FIRST_STEP_HEIGHTS = tuple(float(v) for v in np.geomspace(0.1, 4.0, 20))
"""The step lengths, in camera heights, that :meth:`MonoVO._first_ground` tries before the first scale is known
(0.1 to 4: at KITTI's 1.65 m, 0.17 to 6.6 m between frames)."""


@dataclass(frozen=True)
class MonoVOConfig:
    """Attributes:
        corners, corner_quality, corner_spacing_px: Shi-Tomasi corners tracked per frame.
        klt: the tracker.
        ransac_px, ransac_confidence: the essential matrix's RANSAC.
        min_inliers: fewer inliers bridge the frame.
        min_flow_px: a median flow below this is a standing camera (no motion, no scale).
        motion: ``arc``: the vehicle's motion between frames is an arc of a circle on the road, its turn and
            length aligned directly on the road (see :func:`align_road_arc`); ``general``: the essential
            matrix's five degrees of freedom with the road's scale, as in the thesis; ``auto``: the arc for a
            camera with a mount (its place on the body makes the arc exact), the general motion without one
            (KITTI's cameras).
        max_yaw_step_deg: the arc's turn between two frames is searched within this (when the search starts
            afresh; after that near the last step).
        max_step_heights: the longest arc step between two frames, in camera heights (3 m, 30 m/s at 10 Hz on the kart).
        max_alignment_ratio: an arc step whose road alignment costs more than this times the search's median cost
            is no clear minimum: the frame is bridged.
        min_road_contrast: a road region whose grey levels vary less than this (standard deviation) is blank
            (a black or covered lens, fog): the frame is bridged.
        arc_pitch_every: with the arc, the camera's pitch over the road is measured every this many frames
            (:func:`align_road_pitch`; 0: never, the mount's is trusted) and the median of the last
            ``pitch_window`` replaces the mount's.
        pitch_window: how many of those measurements the median keeps.
        motion_limits: what the vehicle can do (``motion_check``); an arc step beyond them, or too far from
            the last (the road's best fit a car ahead moving with the kart), is bridged with the last step.
        tyre_slip: with the vehicle known, the arc's rear axle slips outward in a bend as its tyres do
            (:meth:`VehicleParams.rear_slip_rad`). Without it, the arc takes a bend's turn about 6 % short at
            4 m/s on the SDC kart (its images' motion explained by a smaller turn instead of the slip).
    """

    corners: int = 3000
    corner_quality: float = 0.005
    corner_spacing_px: int = 7
    klt: KltConfig = field(default_factory=KltConfig)
    ransac_px: float = 1.0
    ransac_confidence: float = 0.999
    min_inliers: int = 30
    min_flow_px: float = 0.5
    ground: GroundConfig = field(default_factory=GroundConfig)
    motion: Literal["auto", "arc", "general"] = "auto"
    max_yaw_step_deg: float = 6.0
    max_step_heights: float = 5.0
    max_alignment_ratio: float = 0.9
    min_road_contrast: float = 2.0
    arc_pitch_every: int = 0
    pitch_window: int = 30
    motion_limits: MotionLimits = field(default_factory=MotionLimits)
    tyre_slip: bool = True
    seed: int = 0

    def __post_init__(self) -> None:
        if self.motion not in ("auto", "arc", "general"):
            raise ConfigError(f"mono_vo.motion must be 'auto', 'arc' or 'general', got {self.motion!r}")
        if min(self.max_yaw_step_deg, self.max_step_heights, self.max_alignment_ratio) <= 0:
            raise ConfigError("mono_vo.max_yaw_step_deg, max_step_heights and max_alignment_ratio must be positive")
        if self.arc_pitch_every < 0 or self.pitch_window < 1:
            raise ConfigError("mono_vo.arc_pitch_every must not be negative and mono_vo.pitch_window must be positive")


@dataclass(frozen=True)
class MonoEstimate:
    """One frame's result. ``scale_source`` says where the metres came from."""

    index: int
    stamp_ns: int
    pose_world_cam: Array
    status: Literal["init", "ok", "bridged"]
    reason: str
    scale_m: float
    scale_source: str
    inliers: int
    road_inliers: int


def relative_pose(p0: F32, p1: F32, camera_matrix: Array, ransac_px: float, confidence: float
                  ) -> tuple[Array, Array, NDArray[np.bool_]] | None:
    """(R, unit t, inlier mask) taking points from the first camera's frame to the second's, or None."""
    if len(p0) < 8:
        return None
    essential, mask = cv2.findEssentialMat(p0, p1, camera_matrix, cv2.RANSAC, confidence, ransac_px)
    if essential is None or essential.shape != (3, 3):
        return None
    _, rotation, translation, mask = cv2.recoverPose(essential, p0, p1, camera_matrix, mask=mask)
    return rotation, translation.ravel(), mask.ravel() > 0


def rotation_only(p0: F32, p1: F32, camera_matrix: Array, threshold_px: float, rounds: int = 3
                  ) -> tuple[Array, NDArray[np.bool_]]:
    """The rotation taking the first camera's frame to the second's that explains the matches with no
    translation, and which matches it explains (the second view's point within ``threshold_px`` of the first's
    turned by it). It turns the rays onto each other (Wahba's problem, scipy's ``align_vectors``), refitted on
    the matches it explains, since the rest pull a least-squares fit off. Where it explains about as many
    matches as the essential matrix does, the views show no parallax (a camera that has not moved, or only
    turned): the essential matrix's translation is then undetermined and its rotation arbitrary (the same two
    views of a kart at rest gave 54 degrees). It explains nothing where too few rays, or rays all but parallel,
    leave the rotation undetermined."""
    points = [np.asarray(p, np.float64).reshape(-1, 2) for p in (p0, p1)]
    inverse = np.linalg.inv(camera_matrix)
    rays = [np.c_[p, np.ones(len(p))] @ inverse.T for p in points]
    rays = [r / np.linalg.norm(r, axis=1, keepdims=True) for r in rays]
    rotation = np.eye(3)
    kept = np.ones(len(points[0]), bool)
    for round_ in range(rounds):
        if kept.sum() < 5:
            return rotation, np.zeros(len(kept), bool)  # too few to fix a rotation: it explains nothing
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            rotation = Rotation.align_vectors(rays[1][kept], rays[0][kept])[0].as_matrix()
        if caught:  # the rays all but parallel (a cluster of points): a turn about them is not fixed
            return np.eye(3), np.zeros(len(kept), bool)
        turned = (rays[0] @ rotation.T) @ camera_matrix.T
        residual = np.linalg.norm(turned[:, :2] / turned[:, 2:] - points[1], axis=1)
        # the first round's fit is pulled by what it cannot explain: keep the better half, then the threshold
        kept = residual <= (max(threshold_px, float(np.median(residual))) if round_ == 0 else threshold_px)
    return rotation, kept


def has_mount(camera: PinholeCamera) -> bool:
    """Whether the camera's pose on the body is known (a camera without a mount has the identity pose)."""
    return not np.allclose(camera.pose_body_cam_array, np.eye(4))


def level_mount(camera: PinholeCamera) -> Array:
    """The camera's pose on the body (rear axle, x forward, z up); a camera without a mount is taken as level,
    looking forward, on the rear axle."""
    return camera.pose_body_cam_array if has_mount(camera) else mount_pose()


def arc_step(yaw_rad: float, length_m: float, pose_body_cam: Array, slip_rad: float = 0.0) -> Array:
    """The camera's pose after the body drove ``length_m`` along a circular arc turning by ``yaw_rad``, in the
    camera's frame before: a kart's rear axle moves along its heading, so a step is a chord at half the turn,
    turned further by the rear axle's slip angle (``slip_rad``: its velocity's angle from the heading, which
    tyres that carry a bend's lateral force have; :meth:`VehicleParams.rear_slip_rad`)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    body = np.eye(4)
    body[:2, :2] = [[c, -s], [s, c]]
    body[:2, 3] = length_m * math.cos(yaw_rad / 2 + slip_rad), length_m * math.sin(yaw_rad / 2 + slip_rad)
    return np.linalg.inv(pose_body_cam) @ body @ pose_body_cam


@dataclass(frozen=True)
class RoadLevel:
    """The road region at one image scale: the scaled camera matrix and the region's mask and bounding box."""

    scale: float
    camera_matrix: Array
    mask: NDArray[np.bool_]
    box: tuple[int, int, int, int]  # rows r0:r1, columns c0:c1


def road_levels(camera: PinholeCamera, region: NDArray[np.uint8], scales: tuple[float, ...]) -> list[RoadLevel]:
    """The road region at each image scale (coarse first), for :func:`align_road_arc`."""
    levels = []
    for scale in scales:
        k = camera.matrix.copy()
        k[:2] *= scale
        k[:2, 2] = (camera.matrix[:2, 2] + 0.5) * scale - 0.5
        size = (round(camera.width_px * scale), round(camera.height_px * scale))
        mask = cv2.resize(region, size, interpolation=cv2.INTER_NEAREST) > 0
        rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
        if len(rows) == 0:
            raise ConfigError("the road region ahead is hardly in the image: check the camera's height and mount")
        box = (int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1)
        levels.append(RoadLevel(scale, k, mask[box[0]:box[1], box[2]:box[3]], box))
    return levels


def road_image(image: Image, level: RoadLevel) -> NDArray[np.float32]:
    """The image at a level's scale, smoothed, as float (the whole image: a warp reads outside the box)."""
    size = (round(image.shape[1] * level.scale), round(image.shape[0] * level.scale))
    small = image if level.scale == 1 else cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return cv2.GaussianBlur(small, (3, 3), 0).astype(np.float32)


def road_alignment_cost(previous: NDArray[np.float32], current: NDArray[np.float32], level: RoadLevel,
                        pose_after: Array, normal: Array, height_m: float) -> float:
    """Mean absolute grey-level difference between the previous image's road and the current image pulled back
    through the road plane's homography for the camera motion ``pose_after`` (metric); inf when the warp
    leaves too little of the road in view."""
    inverse = np.linalg.inv(pose_after)
    k = level.camera_matrix
    homography = k @ (inverse[:3, :3] + np.outer(inverse[:3, 3], normal) / height_m) @ np.linalg.inv(k)
    r0, r1, c0, c1 = level.box
    shift = np.array([[1.0, 0.0, c0], [0.0, 1.0, r0], [0.0, 0.0, 1.0]])
    warped = cv2.warpPerspective(current, homography @ shift, (c1 - c0, r1 - r0),
                                 flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderValue=-1e4)
    valid = level.mask & (warped >= 0)
    if int(valid.sum()) < 0.3 * int(level.mask.sum()):
        return math.inf
    # the difference over the box, then the valid pixels of it: the same values in the same order as taking the
    # valid pixels of each first, with one gather instead of two
    return float(np.abs(warped - previous[r0:r1, c0:c1])[valid].mean())


def align_road_arc(previous: list[NDArray[np.float32]], current: list[NDArray[np.float32]], levels: list[RoadLevel],
                   pose_body_cam: Array, normal: Array, height_m: float, yaw_grid: Array, length_grid: Array,
                   slip: Callable[[float, float], float] | None = None) -> tuple[float, float, float]:
    """The arc step (turn, length in metres) that best aligns the road between two frames, and its cost
    over the median cost of the coarse grid (well below 1 for a clear minimum).

    The road ahead is a plane at the camera's known height, so an arc step predicts where every road
    pixel goes (the plane-induced homography): its length shows in the road's expansion, its turn in its
    sideways shift. Aligning the whole region directly needs no tracks, whose square windows the road's
    foreshortening pulls along the flow. The grid is searched on the coarsest level, then refined four
    times on the finest, halving the steps. ``slip`` gives the rear axle's slip angle of a step (turn, length),
    where the vehicle's tyres are known."""
    def cost(level: int, yaw: float, length: float) -> float:
        step = arc_step(yaw, length, pose_body_cam, slip(yaw, length) if slip is not None else 0.0)
        return road_alignment_cost(previous[level], current[level], levels[level], step, normal, height_m)

    coarse = np.array([[cost(0, float(y), float(d)) for d in length_grid] for y in yaw_grid])
    i, j = np.unravel_index(int(np.argmin(coarse)), coarse.shape)
    yaw, length = float(yaw_grid[i]), float(length_grid[j])
    yaw_step = float(yaw_grid[1] - yaw_grid[0]) if len(yaw_grid) > 1 else math.radians(0.5)
    length_step = float(length_grid[1] - length_grid[0]) if len(length_grid) > 1 else 0.05 * height_m
    finest = len(levels) - 1
    best = cost(finest, yaw, length)
    for _ in range(4):
        yaw_step, length_step = yaw_step / 2, length_step / 2
        for dy, dl in itertools.product((-1, 0, 1), (-1, 0, 1)):
            candidate = (yaw + dy * yaw_step, max(length + dl * length_step, 0.0))
            value = cost(finest, *candidate)
            if value < best:
                best, (yaw, length) = value, candidate
    finite = coarse[np.isfinite(coarse)]
    typical = float(np.median(finite)) if len(finite) else 0.0
    quality = float(coarse[i, j]) / typical if typical > 0 else math.inf  # a blank road aligns everywhere
    return yaw, length, quality


def mount_normal(pose_body_cam: Array) -> Array:
    """The road's normal (pointing down, towards the road) in the camera frame of a mount."""
    normal = pose_body_cam[:3, :3].T @ np.array([0.0, 0.0, -1.0])
    return normal / np.linalg.norm(normal)


def _best_on_grid(values: Array, costs: Array) -> float:
    """The grid's best value, refined by a parabola through it and its neighbours."""
    i = int(np.argmin(costs))
    if 0 < i < len(values) - 1 and np.all(np.isfinite(costs[i - 1:i + 2])):
        curvature = costs[i - 1] - 2 * costs[i] + costs[i + 1]
        shift = 0.5 * (costs[i - 1] - costs[i + 1]) / curvature if curvature > 0 else 0.0
        return float(values[i] + np.clip(shift, -0.5, 0.5) * (values[1] - values[0]))
    return float(values[i])


def align_road_pitch(previous: NDArray[np.float32], current: NDArray[np.float32], level: RoadLevel,
                     pose_body_cam: Array, height_m: float, yaw_rad: float, length_m: float,
                     span_deg: float = 1.5, steps: int = 7) -> float:
    """How much further down the camera looks than ``pose_body_cam`` says, measured on the road (degrees,
    within ``span_deg``), for the arc step (``yaw_rad``, about ``length_m``) found with the mount.

    A pitch error and a length error both change how the road expands between frames, but not alike: the
    length scales every distance, the pitch moves the horizon. So each pitch on a grid gets its best length,
    and a parabola through the best costs gives the pitch. The cost is the arc's own
    (:func:`road_alignment_cost`): road corners tracked in square windows are pulled along the
    foreshortened road and bias a fitted plane by tenths of a degree, which at 15 camera heights ahead is
    several per cent of the distance."""
    pitches = np.linspace(-span_deg, span_deg, steps)
    lengths = length_m * np.linspace(0.9, 1.1, 11)

    def lowest(pitch: float) -> float:
        mount = pitched_mount(pose_body_cam, pitch)
        normal = mount_normal(mount)
        return min(road_alignment_cost(previous, current, level, arc_step(yaw_rad, float(d), mount), normal,
                                       height_m) for d in lengths)

    return _best_on_grid(pitches, np.array([lowest(float(p)) for p in pitches]))


def ground_normal_prior(camera: PinholeCamera) -> Array:
    """The road's normal (pointing down, towards the road) in the camera frame, from the camera's mount; a
    camera without a mount is taken as level: (0, 1, 0)."""
    return mount_normal(level_mount(camera))


def beyond_ground_mask(camera: PinholeCamera, ignore_ground_heights: float) -> NDArray[np.uint8]:
    """255 everywhere but where the ground nearer than ``ignore_ground_heights`` camera heights is seen (the
    ground's direction from the camera's mount, level without one): 0 ignores nothing."""
    mask = np.full((camera.height_px, camera.width_px), 255, np.uint8)
    if ignore_ground_heights <= 0:
        return mask
    rays = camera.rays(np.stack(np.meshgrid(np.arange(camera.width_px), np.arange(camera.height_px)), axis=-1))
    down = rays @ ground_normal_prior(camera)
    with np.errstate(divide="ignore"):
        distance_in_heights = np.where(down > 0, np.linalg.norm(rays, axis=-1) / down, np.inf)
    mask[distance_in_heights < ignore_ground_heights] = 0
    return mask


def ground_region(camera: PinholeCamera, normal: Array, config: GroundConfig) -> NDArray[np.uint8]:
    """A mask of the road in the configured region ahead of the camera."""
    forward = np.array([0.0, 0.0, 1.0]) - normal[2] * normal
    forward /= np.linalg.norm(forward)
    lateral = np.cross(normal, forward)
    h = config.camera_height_m
    near, far, half = h * config.near_heights, h * config.far_heights, h * config.half_width_heights
    corners = [h * normal + d * forward + y * lateral for d, y in ((near, -half), (near, half), (far, half),
                                                                    (far, -half))]
    pixels = camera.project(np.array(corners))
    mask = np.zeros((camera.height_px, camera.width_px), np.uint8)
    cv2.fillConvexPoly(mask, np.round(pixels).astype(np.int32), 255)
    return mask


def _homography_terms(p0: F32, p1: F32, rotation: Array, t: Array, k_inv: Array
                      ) -> tuple[Array, Array, Array, Array, Array, Array]:
    x0 = (k_inv @ np.c_[p0, np.ones(len(p0))].T).T
    x1 = (k_inv @ np.c_[p1, np.ones(len(p1))].T).T
    rx0 = x0 @ rotation.T
    u, v = x1[:, 0] / x1[:, 2], x1[:, 1] / x1[:, 2]
    # x1 ~ R x0 + t (m . x0): two equations per point, linear in m
    a = np.r_[(t[0] - u * t[2])[:, None] * x0, (t[1] - v * t[2])[:, None] * x0]
    b = np.r_[-(rx0[:, 0] - u * rx0[:, 2]), -(rx0[:, 1] - v * rx0[:, 2])]
    return a, b, x0, rx0, u, v


def fit_ground_homography(p0: F32, p1: F32, rotation: Array, t: Array, camera_matrix: Array,
                          config: GroundConfig, rng: np.random.Generator, prior_normal: Array | None = None
                          ) -> tuple[Array, int] | None:
    """The road plane's ``m = n / d`` (in the units of ``t``) from road points moving between two frames,
    and the number of inliers; None when no plane with enough support and a plausible tilt is found."""
    count = len(p0)
    if count < max(config.min_points, 3):
        return None
    a, b, x0, rx0, u, v = _homography_terms(p0, p1, rotation, t, np.linalg.inv(camera_matrix))
    focal = float(camera_matrix[0, 0])
    min_down = math.cos(math.radians(config.max_tilt_deg))
    prior = np.array([0.0, 1.0, 0.0]) if prior_normal is None else prior_normal

    # the hypotheses all at once (the same draws, in the same order, as one at a time): each from three points
    picks = np.array([rng.choice(count, 3, replace=False) for _ in range(config.iterations)])
    equations = np.concatenate([picks, picks + count], axis=1)  # a point's two rows of a and b
    hypotheses = np.einsum("hij,hj->hi", np.linalg.pinv(a[equations]), b[equations])  # each one's least squares
    norms = np.linalg.norm(hypotheses, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        plausible = (norms > 0) & (hypotheses @ prior / norms >= min_down)
        s = x0 @ hypotheses.T  # (points, hypotheses)
        z = rx0[:, 2:3] + t[2] * s
        error = focal * np.hypot((rx0[:, 0:1] + t[0] * s) / z - u[:, None], (rx0[:, 1:2] + t[1] * s) / z - v[:, None])
    inliers = error < config.inlier_px  # NaN (a point at the camera's plane) is no inlier
    counts = np.where(plausible, inliers.sum(axis=0), 0)
    first_best = int(np.argmax(counts))  # the first of the most supported, as a loop keeping the better finds it
    best_count = int(counts[first_best])
    if best_count == 0 or best_count < config.min_points:
        return None
    best = inliers[:, first_best]
    rows = np.r_[np.flatnonzero(best), np.flatnonzero(best) + count]
    m = np.linalg.lstsq(a[rows], b[rows], rcond=None)[0]
    if float(m @ prior) <= 0 or float(m @ prior) / np.linalg.norm(m) < min_down:
        return None
    return m, best_count


class MonoVO:
    """Holds the previous image, the pose, and the recent scales and plane normals."""

    def __init__(self, camera: PinholeCamera, config: MonoVOConfig | None = None, camera_name: str = "left",
                 vehicle: VehicleParams | None = None) -> None:
        """``camera_name`` is the camera :meth:`process` reads in each frame set; ``vehicle``, the kart it is
        mounted on, whose tyres' slip the arc steps take into account (``tyre_slip``)."""
        self.camera = camera
        self.vehicle = vehicle
        self.cameras = (camera_name,)
        self.config = config or MonoVOConfig()
        self.k = camera.matrix
        self.k_inv = np.linalg.inv(self.k)
        self._rng = np.random.default_rng(self.config.seed)
        self._previous: Image | None = None
        self._pose = np.eye(4)
        self._scales: list[float] = []
        self._normals: list[Array] = []
        self._prior_normal = ground_normal_prior(camera)
        self._mount = level_mount(camera)
        self.arc = self.config.motion == "arc" or (self.config.motion == "auto" and has_mount(camera))
        self._road_mask = ground_region(camera, self._prior_normal, self.config.ground)
        if int(np.count_nonzero(self._road_mask)) < 0.01 * camera.width_px * camera.height_px:
            raise ConfigError("the road region ahead is hardly in the image: check the camera's height and mount")
        self._levels = road_levels(camera, self._road_mask, (0.25, 0.5)) if self.arc else []
        self._road_images: list[NDArray[np.float32]] | None = None
        self._last_arc: tuple[float, float] | None = None
        self._previous_stamp_ns: int | None = None
        self._recent: StepVelocity | None = None  # the last accepted arc step, for the motion check
        self._pitches: list[float] = []  # the camera's pitch over the road, measured, less the mount's
        self.timing_ms: dict[str, float] = {"track": 0.0, "pose": 0.0, "ground": 0.0}
        self.frames = 0
        self.bridged = 0

    @property
    def scale_m(self) -> float:
        """The current metres per unit of VO translation (0 before the ground was seen)."""
        window = self._scales[-self.config.ground.scale_window:]
        return float(np.median(window)) if window else 0.0

    def _normal(self) -> Array:
        if not self._normals:
            return self._prior_normal
        normal = np.median(np.array(self._normals[-30:]), axis=0)
        return normal / np.linalg.norm(normal)

    def _estimate(self, index: int, stamp_ns: int, status: Literal["init", "ok", "bridged"], reason: str,
                  inliers: int = 0, road: int = 0) -> MonoEstimate:
        if status == "bridged":
            self.bridged += 1
        return MonoEstimate(index, stamp_ns, self._pose.copy(), status, reason, self.scale_m, self.scale_source,
                            inliers, road)

    def close(self) -> None:
        """Nothing to release (the interface's counterpart of stereo VO's thread)."""

    @property
    def scale_source(self) -> str:
        return f"ground plane (camera {self.config.ground.camera_height_m:g} m above the road)"

    def process(self, frames: FrameSet) -> MonoEstimate:
        """Consume the frame set's image of this VO's camera and return the updated pose."""
        (gray,) = grey_images(frames, self.cameras)
        index, stamp_ns = frames.index, frames.stamp_ns
        self.frames += 1
        previous, self._previous = self._previous, gray
        previous_stamp_ns, self._previous_stamp_ns = self._previous_stamp_ns, stamp_ns
        if previous is None:
            self._road_images = [road_image(gray, level) for level in self._levels]
            return self._estimate(index, stamp_ns, "init", "")
        if self.arc:
            return self._arc(index, stamp_ns, previous_stamp_ns, previous, gray)
        cfg = self.config
        t0 = time.perf_counter()
        corners = cv2.goodFeaturesToTrack(previous, cfg.corners, cfg.corner_quality, cfg.corner_spacing_px)
        if corners is None:
            return self._estimate(index, stamp_ns, "bridged", "no corners in the image")
        p0 = corners.reshape(-1, 2).astype(np.float32)
        p1, ok = track_klt(previous, gray, p0, cfg.klt)
        p0, p1 = p0[ok], p1[ok]
        t1 = time.perf_counter()
        self.timing_ms["track"] += (t1 - t0) * 1e3
        if len(p0) < cfg.min_inliers:
            return self._estimate(index, stamp_ns, "bridged", f"{len(p0)} tracks")
        if float(np.median(np.linalg.norm(p1 - p0, axis=1))) < cfg.min_flow_px:
            return self._estimate(index, stamp_ns, "ok", "standing", len(p0))
        motion = relative_pose(p0, p1, self.k, cfg.ransac_px, cfg.ransac_confidence)
        t2 = time.perf_counter()
        self.timing_ms["pose"] += (t2 - t1) * 1e3
        if motion is None or int(motion[2].sum()) < cfg.min_inliers:
            return self._estimate(index, stamp_ns, "bridged", "no essential matrix with enough inliers")
        rotation, t, inliers = motion
        road = self._ground(previous, gray, rotation, t)
        self.timing_ms["ground"] += (time.perf_counter() - t2) * 1e3
        if self.scale_m <= 0:
            return self._estimate(index, stamp_ns, "bridged", "no ground plane seen yet: no scale",
                                  int(inliers.sum()), road)
        step = np.eye(4)
        step[:3, :3], step[:3, 3] = rotation, t * self.scale_m
        self._pose = self._pose @ np.linalg.inv(step)
        return self._estimate(index, stamp_ns, "ok", "", int(inliers.sum()), road)

    def _pitch(self) -> float:
        """The median of the recent measurements of the camera's pitch over the road, less its mount's
        (degrees); 0 until ``ARC_PITCH_MIN_MEASUREMENTS`` measurements give a median."""
        if len(self._pitches) < ARC_PITCH_MIN_MEASUREMENTS:
            return 0.0
        return float(np.median(self._pitches[-self.config.pitch_window:]))

    def _arc_mount(self) -> Array:
        """The camera's mount, pitched as measured on the road (:func:`align_road_pitch`)."""
        pitch = self._pitch()
        return self._mount if pitch == 0.0 else pitched_mount(self._mount, pitch)

    def _slip(self, stamp_ns: int, previous_stamp_ns: int | None) -> Callable[[float, float], float]:
        """The rear axle's slip angle of an arc step (turn, length) over this frame's time, from the vehicle's
        tyres (none without a vehicle, without ``tyre_slip``, or without the time)."""
        vehicle = self.vehicle
        if vehicle is None or not self.config.tyre_slip or previous_stamp_ns is None or stamp_ns <= previous_stamp_ns:
            return lambda yaw, length: 0.0
        dt_s = (stamp_ns - previous_stamp_ns) * 1e-9
        return lambda yaw, length: vehicle.rear_slip_rad(length / dt_s, yaw / dt_s)

    def _arc(self, index: int, stamp_ns: int, previous_stamp_ns: int | None, previous_image: Image, gray: Image
             ) -> MonoEstimate:
        """One arc step, aligned on the road (:func:`align_road_arc`); searched near the last step, or over
        the whole range at the start, after a bridged frame, or when the best lies on the window's edge.
        Every ``arc_pitch_every`` frames, the camera's pitch over the road is measured again
        (:func:`align_road_pitch`): a camera pitched a degree further down than its mount says misjudges a
        road point 15 camera heights ahead by a quarter of its distance."""
        cfg, g = self.config, self.config.ground
        mount = self._arc_mount()
        normal = self._prior_normal if mount is self._mount else mount_normal(mount)
        t0 = time.perf_counter()
        previous, self._road_images = self._road_images, [road_image(gray, level) for level in self._levels]
        assert previous is not None
        last = self._last_arc
        self._last_arc = None
        r0, r1, c0, c1 = self._levels[-1].box
        if float(previous[-1][r0:r1, c0:c1][self._levels[-1].mask].std()) < cfg.min_road_contrast:
            return self._estimate(index, stamp_ns, "bridged", "the road ahead has no texture to align")
        slip = self._slip(stamp_ns, previous_stamp_ns)
        result = None
        if last is not None:
            yaw_grid = last[0] + np.radians(np.arange(-2.0, 2.01, 0.5))
            spread = 0.4 * last[1] + 0.05 * g.camera_height_m
            length_grid = np.linspace(max(last[1] - spread, 0.0), last[1] + spread, 9)
            result = align_road_arc(previous, self._road_images, self._levels, mount, normal,
                                    g.camera_height_m, yaw_grid, length_grid, slip)
            edge = (abs(result[0] - last[0]) > math.radians(1.9) or not length_grid[0] + 1e-9 < result[1]
                    or result[1] > length_grid[-1] - 1e-9)
            if edge and result[1] > 0:
                result = None
        if result is None:
            wide = math.radians(cfg.max_yaw_step_deg)
            result = align_road_arc(previous, self._road_images, self._levels, mount, normal,
                                    g.camera_height_m, np.arange(-wide, wide + 1e-9, math.radians(0.5)),
                                    np.linspace(0.0, cfg.max_step_heights * g.camera_height_m, 25), slip)
        yaw, length, quality = result
        self.timing_ms["ground"] += (time.perf_counter() - t0) * 1e3
        if not quality <= cfg.max_alignment_ratio:
            return self._estimate(index, stamp_ns, "bridged", f"the road does not align (cost ratio {quality:.2f})")
        step = arc_step(yaw, length, mount, slip(yaw, length))
        if previous_stamp_ns is not None:
            velocity = StepVelocity.of_motion(step, previous_stamp_ns, stamp_ns)
            reason = check_motion(velocity, cfg.motion_limits, self._recent)
            if reason:
                # a car ahead moving with the kart, a shadow: the road's best fit is not a motion the kart
                # can make. Keep the last step (none before the first) and search near it again next frame.
                if last is not None:
                    self._last_arc = last
                    self._pose = self._pose @ arc_step(*last, mount, slip(*last))
                return self._estimate(index, stamp_ns, "bridged", f"the road's best fit is implausible: {reason}")
            self._recent = velocity
        self._last_arc = (yaw, length)
        self._scales.append(float(np.linalg.norm(step[:3, 3])))
        self._pose = self._pose @ step
        if cfg.arc_pitch_every and self.frames % cfg.arc_pitch_every == 0 and length > 0.05 * g.camera_height_m:
            t1 = time.perf_counter()
            finest = len(self._levels) - 1
            pitch = align_road_pitch(previous[finest], self._road_images[finest], self._levels[finest], mount,
                                     g.camera_height_m, yaw, length)
            self._pitches.append(pitch + self._pitch())  # measured against the mount pitched as now
            if len(self._pitches) == ARC_PITCH_MIN_MEASUREMENTS:
                self._recent = None  # the steps so far were measured with the mount's pitch, not the road's
            self.timing_ms["pitch"] = self.timing_ms.get("pitch", 0.0) + (time.perf_counter() - t1) * 1e3
        return self._estimate(index, stamp_ns, "ok", "standing" if length < 1e-3 else "")

    def _first_ground(self, previous: Image, gray: Image, q0: F32, rotation: Array, t: Array
                      ) -> tuple[Array, int] | None:
        """The road's first fit where tracking it from where it was found nothing: with no scale yet there is no
        prediction, and where the steps between frames are long (a car at 20 m/s, or every second frame at 10 Hz)
        the near road moves farther than KLT's pyramid reaches, so no scale is ever found. Each step length of
        :data:`FIRST_STEP_HEIGHTS` (in camera heights) predicts where the road went; the length whose fit holds
        the most road points wins."""
        g = self.config.ground
        klt = replace(self.config.klt, pyramid_levels=2)

        def fit_from(length_m: float) -> tuple[Array, int] | None:
            q1, ok = track_klt(previous, gray, q0, klt, self._road_moved(q0, rotation, t, length_m))
            return fit_ground_homography(q0[ok], q1[ok], rotation, t, self.k, g, self._rng, self._prior_normal)

        best: tuple[Array, int] | None = None
        for heights in FIRST_STEP_HEIGHTS:
            fit = fit_from(heights * g.camera_height_m)
            if fit is not None and (best is None or fit[1] > best[1]):
                best = fit
        if best is None:
            return None
        # once more from the length the best fit gives: a step between two tried lengths is tracked from its own
        again = fit_from(g.camera_height_m * float(np.linalg.norm(best[0])))
        return again if again is not None and again[1] >= best[1] else best

    def _road_moved(self, q0: F32, rotation: Array, t: Array, length_m: float) -> F32:
        """Where road points ``q0`` go for a step of ``length_m`` along the unit translation ``t`` (the road plane's
        homography at the camera's height)."""
        g = self.config.ground
        homography = self.k @ (rotation + np.outer(t * length_m, self._normal()) / g.camera_height_m) @ self.k_inv
        return cv2.perspectiveTransform(q0.reshape(-1, 1, 2), homography).reshape(-1, 2).astype(np.float32)

    def _ground(self, previous: Image, gray: Image, rotation: Array, t: Array) -> int:
        """Track the road from its predicted position and update the scale; the road inliers."""
        g = self.config.ground
        corners = cv2.goodFeaturesToTrack(previous, g.corners, g.corner_quality, g.corner_spacing_px,
                                          mask=self._road_mask)
        if corners is None:
            return 0
        q0 = corners.reshape(-1, 2).astype(np.float32)
        guess = self._road_moved(q0, rotation, t, self.scale_m) if self.scale_m > 0 else None
        klt = self.config.klt if guess is None else replace(self.config.klt, pyramid_levels=1)
        q1, ok = track_klt(previous, gray, q0, klt, guess)
        fit = fit_ground_homography(q0[ok], q1[ok], rotation, t, self.k, g, self._rng, self._prior_normal)
        if fit is None and self.scale_m <= 0:
            fit = self._first_ground(previous, gray, q0, rotation, t)
        if fit is None:
            return 0
        m, count = fit
        norm = float(np.linalg.norm(m))
        self._normals.append(m / norm)
        self._scales.append(g.camera_height_m * norm)
        return count

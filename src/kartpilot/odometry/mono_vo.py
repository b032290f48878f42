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
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array
from kartpilot.core.types import Image
from kartpilot.perception.tracking import KltConfig, track_klt

__all__ = ["GroundConfig", "MonoEstimate", "MonoVO", "MonoVOConfig", "arc_step", "beyond_ground_mask", "fit_arc_yaw",
           "fit_ground_homography", "ground_normal_prior", "ground_region", "level_mount", "relative_pose"]

log = logging.getLogger(__name__)

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


@dataclass(frozen=True)
class MonoVOConfig:
    """Attributes:
        corners, corner_quality, corner_spacing_px: Shi-Tomasi corners tracked per frame.
        klt: the tracker.
        ransac_px, ransac_confidence: the essential matrix's RANSAC.
        min_inliers: fewer inliers bridge the frame.
        min_flow_px: a median flow below this is a standing camera (no motion, no scale).
        motion: ``arc``: the vehicle's motion between frames is an arc of a circle on the road, fitted to the
            tracks by its one angle (see :func:`fit_arc_yaw`); ``general``: the essential matrix's five degrees of
            freedom, as in the thesis; ``auto``: the arc for a camera with a mount (its place on the body makes the
            arc exact), the general motion without one (KITTI's cameras: 1.2 % end drift on sequence 06, against
            3 to 4 % with an arc about a guessed axle).
        max_yaw_step_deg: the arc's turn between two frames is searched within this.
        arc_ignore_ground_heights: with the arc, corners on the ground nearer than this many camera heights are not
            tracked. The turn is measured best far away, where a view moves by the turn alone; the near road
            changes its shape from frame to frame (foreshortening), which pulls KLT's square windows along its
            flow, and at 1 px those biased tracks outvote the far ones in a bend. (The road still gives the
            scale, with its own tracks.)
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
    max_yaw_step_deg: float = 12.0
    arc_ignore_ground_heights: float = 20.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.motion not in ("auto", "arc", "general"):
            raise ConfigError(f"mono_vo.motion must be 'auto', 'arc' or 'general', got {self.motion!r}")
        if self.max_yaw_step_deg <= 0 or self.arc_ignore_ground_heights < 0:
            raise ConfigError("mono_vo.max_yaw_step_deg must be positive and arc_ignore_ground_heights not negative")


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


def level_mount(camera: PinholeCamera) -> Array:
    """The camera's pose on the body (rear axle, x forward, z up); a camera without a mount (identity pose) is
    taken as level, looking forward, on the rear axle."""
    pose = camera.pose_body_cam_array
    if not np.allclose(pose, np.eye(4)):
        return pose
    level = np.eye(4)
    level[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    return level


def arc_step(yaw_rad: float, length_m: float, pose_body_cam: Array) -> Array:
    """The camera's pose after the body drove ``length_m`` along a circular arc turning by ``yaw_rad``, in the
    camera's frame before: a kart's rear axle moves along its heading, so a step is a chord at half the turn."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    body = np.eye(4)
    body[:2, :2] = [[c, -s], [s, c]]
    body[:2, 3] = length_m * math.cos(yaw_rad / 2), length_m * math.sin(yaw_rad / 2)
    return np.linalg.inv(pose_body_cam) @ body @ pose_body_cam


def _sampson_px(x0: Array, x1: Array, steps: Array, focal_px: float) -> Array:
    """Sampson distances in pixels (``(G, N)``) of normalised rays ``x0 -> x1`` under each of ``G`` camera
    poses after the step (``(G, 4, 4)``, as :func:`arc_step`)."""
    inverse = np.linalg.inv(steps)
    rotation, t = inverse[:, :3, :3], inverse[:, :3, 3]
    t = t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
    skew = np.zeros_like(rotation)
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -t[:, 2], t[:, 1], -t[:, 0]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = t[:, 2], -t[:, 1], t[:, 0]
    essential = skew @ rotation
    line1 = np.einsum("gij,nj->gni", essential, x0)
    line0 = np.einsum("gji,nj->gni", essential, x1)
    residual = np.einsum("ni,gni->gn", x1, line1)
    norm = line1[..., 0] ** 2 + line1[..., 1] ** 2 + line0[..., 0] ** 2 + line0[..., 1] ** 2
    return focal_px * np.abs(residual) / np.sqrt(np.maximum(norm, 1e-18))


def fit_arc_yaw(p0: F32, p1: F32, camera_matrix: Array, pose_body_cam: Array, length_m: float,
                max_yaw_rad: float, threshold_px: float) -> tuple[float, NDArray[np.bool_]]:
    """The turn of an arc step of ``length_m`` (negative: reversing) that best explains tracks ``p0 -> p1``,
    and its inliers (Sampson distance within ``threshold_px``).

    The one-parameter motion model of a wheeled vehicle (Scaramuzza, "1-point RANSAC", 2009), with the camera's
    mount: where the general essential matrix trades a turn for a sideways translation (the two look alike
    through a narrow lens), the arc has no sideways translation to trade. The turn is searched exhaustively
    on a 0.25 degree grid with a truncated quadratic cost (every track votes, outliers count a constant), then
    refined on the inliers."""
    k_inv = np.linalg.inv(camera_matrix)
    x0 = np.c_[p0, np.ones(len(p0))] @ k_inv.T
    x1 = np.c_[p1, np.ones(len(p1))] @ k_inv.T
    focal = float(camera_matrix[0, 0])

    def cost(yaws: Array) -> Array:
        steps = np.array([arc_step(float(y), length_m, pose_body_cam) for y in yaws])
        return np.minimum(_sampson_px(x0, x1, steps, focal), threshold_px) ** 2

    grid_step = math.radians(0.25)
    grid = np.arange(-max_yaw_rad, max_yaw_rad + grid_step / 2, grid_step)
    best = float(grid[int(np.argmin(cost(grid).sum(1)))])
    fine = np.linspace(best - grid_step, best + grid_step, 21)
    best = float(fine[int(np.argmin(cost(fine).sum(1)))])
    inliers = cost(np.array([best]))[0] < threshold_px ** 2
    return best, inliers


def _points_motion(pose_after: Array) -> tuple[Array, Array]:
    """``(R, unit t)`` taking points from the camera's frame before a step to its frame after it."""
    inverse = np.linalg.inv(pose_after)
    t = inverse[:3, 3]
    return inverse[:3, :3], t / max(float(np.linalg.norm(t)), 1e-12)


def ground_normal_prior(camera: PinholeCamera) -> Array:
    """The road's normal (pointing down, towards the road) in the camera frame, from the camera's mount; a
    camera without a mount (identity pose) is taken as level: (0, 1, 0)."""
    pose = camera.pose_body_cam_array
    if np.allclose(pose, np.eye(4)):
        return np.array([0.0, 1.0, 0.0])
    normal = pose[:3, :3].T @ np.array([0.0, 0.0, -1.0])
    return normal / np.linalg.norm(normal)


def beyond_ground_mask(camera: PinholeCamera, ignore_ground_heights: float) -> NDArray[np.uint8]:
    """255 everywhere but where the ground nearer than ``ignore_ground_heights`` camera heights is seen (the
    ground's direction from the camera's mount, level without one): 0 ignores nothing."""
    mask = np.full((camera.height_px, camera.width_px), 255, np.uint8)
    if ignore_ground_heights <= 0:
        return mask
    u, v = np.meshgrid(np.arange(camera.width_px), np.arange(camera.height_px))
    rays = np.stack([(u - camera.cx_px) / camera.fx_px, (v - camera.cy_px) / camera.fy_px, np.ones(u.shape)], -1)
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

    def errors(m: Array) -> Array:
        s = x0 @ m
        z = rx0[:, 2] + t[2] * s
        with np.errstate(divide="ignore", invalid="ignore"):
            px, py = (rx0[:, 0] + t[0] * s) / z, (rx0[:, 1] + t[1] * s) / z
        return np.nan_to_num(focal * np.hypot(px - u, py - v), nan=np.inf)

    best: NDArray[np.bool_] | None = None
    best_count = 0
    for _ in range(config.iterations):
        pick = rng.choice(count, 3, replace=False)
        m = np.linalg.lstsq(a[np.r_[pick, pick + count]], b[np.r_[pick, pick + count]], rcond=None)[0]
        norm = float(np.linalg.norm(m))
        if norm <= 0 or float(m @ prior) / norm < min_down:
            continue
        inliers = errors(m) < config.inlier_px
        if inliers.sum() > best_count:
            best, best_count = inliers, int(inliers.sum())
    if best is None or best_count < config.min_points:
        return None
    rows = np.r_[np.flatnonzero(best), np.flatnonzero(best) + count]
    m = np.linalg.lstsq(a[rows], b[rows], rcond=None)[0]
    if float(m @ prior) <= 0 or float(m @ prior) / np.linalg.norm(m) < min_down:
        return None
    return m, best_count


class MonoVO:
    """Holds the previous image, the pose, and the recent scales and plane normals."""

    def __init__(self, camera: PinholeCamera, config: MonoVOConfig | None = None) -> None:
        self.camera = camera
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
        self.arc = self.config.motion == "arc" or (self.config.motion == "auto"
                                                   and not np.allclose(camera.pose_body_cam_array, np.eye(4)))
        self._corner_mask = beyond_ground_mask(camera, self.config.arc_ignore_ground_heights) if self.arc else None
        self._road_mask = ground_region(camera, self._prior_normal, self.config.ground)
        if int(np.count_nonzero(self._road_mask)) < 0.01 * camera.width_px * camera.height_px:
            raise ConfigError("the road region ahead is hardly in the image: check the camera's height and mount")
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
        return MonoEstimate(index, stamp_ns, self._pose.copy(), status, reason, self.scale_m,
                            f"ground plane (camera {self.config.ground.camera_height_m:g} m above the road)", inliers,
                            road)

    def process(self, index: int, stamp_ns: int, image: Image) -> MonoEstimate:
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        self.frames += 1
        previous, self._previous = self._previous, gray
        if previous is None:
            return self._estimate(index, stamp_ns, "init", "")
        cfg = self.config
        t0 = time.perf_counter()
        corners = cv2.goodFeaturesToTrack(previous, cfg.corners, cfg.corner_quality, cfg.corner_spacing_px,
                                          mask=self._corner_mask)
        if corners is None:
            return self._estimate(index, stamp_ns, "bridged", "no corners in the image")
        p0 = corners.reshape(-1, 2).astype(np.float32)
        p1, ok = track_klt(previous, gray, p0, cfg.klt)
        p0, p1 = p0[ok], p1[ok]
        t1 = time.perf_counter()
        self.timing_ms["track"] += (t1 - t0) * 1e3
        if len(p0) < cfg.min_inliers:
            return self._estimate(index, stamp_ns, "bridged", f"{len(p0)} tracks")
        flow = np.linalg.norm(p1 - p0, axis=1)
        # the far tracks (with the arc) hardly move on a straight, the near ones at the sides do
        if float(np.percentile(flow, 90 if self.arc else 50)) < cfg.min_flow_px:
            return self._estimate(index, stamp_ns, "ok", "standing", len(p0))
        if self.arc:  # driving forward; before the first scale, a step of one camera height stands in for the length
            length = self.scale_m if self.scale_m > 0 else cfg.ground.camera_height_m
            yaw, inliers = fit_arc_yaw(p0, p1, self.k, self._mount, length, math.radians(cfg.max_yaw_step_deg),
                                       cfg.ransac_px)
            rotation, t = _points_motion(arc_step(yaw, length, self._mount))
        else:
            motion = relative_pose(p0, p1, self.k, cfg.ransac_px, cfg.ransac_confidence)
            if motion is None:
                return self._estimate(index, stamp_ns, "bridged", "no essential matrix")
            rotation, t, inliers = motion
        t2 = time.perf_counter()
        self.timing_ms["pose"] += (t2 - t1) * 1e3
        if int(inliers.sum()) < cfg.min_inliers:
            return self._estimate(index, stamp_ns, "bridged", f"{int(inliers.sum())} inliers to the motion")
        road = self._ground(previous, gray, rotation, t)
        self.timing_ms["ground"] += (time.perf_counter() - t2) * 1e3
        if self.scale_m <= 0:
            return self._estimate(index, stamp_ns, "bridged", "no ground plane seen yet: no scale",
                                  int(inliers.sum()), road)
        if self.arc:
            # the arc whose camera translation has the scale's length (the mount's lever arm makes it a little
            # longer or shorter than the rear axle's chord)
            for _ in range(2):
                length *= self.scale_m / float(np.linalg.norm(arc_step(yaw, length, self._mount)[:3, 3]))
            self._pose = self._pose @ arc_step(yaw, length, self._mount)
        else:
            step = np.eye(4)
            step[:3, :3], step[:3, 3] = rotation, t * self.scale_m
            self._pose = self._pose @ np.linalg.inv(step)
        return self._estimate(index, stamp_ns, "ok", "", int(inliers.sum()), road)

    def _ground(self, previous: Image, gray: Image, rotation: Array, t: Array) -> int:
        """Track the road from its predicted position and update the scale; the road inliers."""
        g = self.config.ground
        corners = cv2.goodFeaturesToTrack(previous, g.corners, g.corner_quality, g.corner_spacing_px,
                                          mask=self._road_mask)
        if corners is None:
            return 0
        q0 = corners.reshape(-1, 2).astype(np.float32)
        guess = None
        if self.scale_m > 0:
            homography = self.k @ (rotation + np.outer(t * self.scale_m, self._normal()) / g.camera_height_m) @ \
                self.k_inv
            guess = cv2.perspectiveTransform(q0.reshape(-1, 1, 2), homography).reshape(-1, 2).astype(np.float32)
        klt = self.config.klt if guess is None else KltConfig(self.config.klt.window_px, 1,
                                                              self.config.klt.max_fb_error_px,
                                                              self.config.klt.iterations)
        q1, ok = track_klt(previous, gray, q0, klt, guess)
        fit = fit_ground_homography(q0[ok], q1[ok], rotation, t, self.k, g, self._rng, self._prior_normal)
        if fit is None:
            return 0
        m, count = fit
        norm = float(np.linalg.norm(m))
        self._normals.append(m / norm)
        self._scales.append(g.camera_height_m * norm)
        return count

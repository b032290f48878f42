"""The road from above: bird's-eye views of the ground plane, and the planar pose between two of them.

A camera at a known height and mount sees the road as a plane, so every ground point ``(x, y)`` of the
body frame (rear axle, x forward, y left, the road at z = 0) has one pixel: remapping the image through
that pixel grid gives a top view with square, metric pixels (inverse perspective mapping). Two top views
of the same road taken from different poses differ by a planar rigid motion, which is the relative pose of
the two bodies. :func:`register_birdseye` finds it:

1. the reference view (a rectangle of road wholly in view) is slid over the query's wider view by
   normalised cross-correlation (``cv2.matchTemplate``) for each heading on a grid, so the search is global
   within the margins and no starting guess beyond the heading is needed;
2. the best cell is refined by the enhanced correlation coefficient (``cv2.findTransformECC``, a rigid
   motion, the query's out-of-view pixels masked), to a fraction of a pixel.

Both scores are invariant to the light's gain and offset (a reference driven at noon, a query at dusk).
Along a straight road whose texture is streaked along the track, the along-track part is the weakest;
across the track and in heading the road's texture and lines pin it (see the places database, which
uses this across the track and in heading).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError, PerceptionError
from kartpilot.core.geometry import Array, invert_pose
from kartpilot.core.types import Image

__all__ = ["BirdseyeConfig", "BirdseyeGrid", "RoadRegistration", "birdseye", "birdseye_grid", "planar_transform",
           "register_birdseye", "road_grids"]


@dataclass(frozen=True)
class BirdseyeConfig:
    """The road patch compared between a reference image and a query, in the camera's heights above the road.

    Attributes:
        resolution_m: the top view's pixel size.
        near_heights, far_heights: the reference patch's extent ahead of the camera.
        half_width_heights: its half width at most (narrowed to what the camera sees at the near edge).
        margin_heights: the query's view extends this much further on every side: the largest offset found.
        yaw_span_deg, yaw_step_deg: the headings tried, around the guess.
        min_correlation: the refined match's least correlation coefficient.
    """

    resolution_m: float = 0.04
    near_heights: float = 3.5
    far_heights: float = 12.0
    half_width_heights: float = 4.0
    margin_heights: float = 2.0
    yaw_span_deg: float = 5.0
    yaw_step_deg: float = 1.0
    min_correlation: float = 0.2

    def __post_init__(self) -> None:
        if min(self.resolution_m, self.near_heights, self.half_width_heights, self.yaw_step_deg) <= 0:
            raise ConfigError("places.road.resolution_m, near_heights, half_width_heights and yaw_step_deg must be "
                              "positive")
        if self.far_heights <= self.near_heights:
            raise ConfigError("places.road.far_heights must be beyond near_heights")
        if self.margin_heights < 0 or self.yaw_span_deg < 0 or not 0 <= self.min_correlation < 1:
            raise ConfigError("places.road.margin_heights and yaw_span_deg must not be negative, and "
                              "min_correlation must lie in [0, 1)")


@dataclass(frozen=True)
class BirdseyeGrid:
    """Where each top-view pixel's ground point lies in the image (``map_x``, ``map_y`` for ``cv2.remap``),
    which of them the camera sees (``mask``, 255), and ``pixel_from_body``: the 3x3 affine taking body-frame
    ground points in metres to top-view pixels (row 0 is the farthest, column 0 the leftmost)."""

    map_x: NDArray[np.float32]
    map_y: NDArray[np.float32]
    mask: NDArray[np.uint8]
    pixel_from_body: Array

    @property
    def shape(self) -> tuple[int, int]:
        return self.mask.shape


@dataclass(frozen=True)
class RoadRegistration:
    """The query body's planar pose in the reference body's frame: ``x_m`` forward, ``y_m`` left, ``yaw_rad``;
    ``peak`` the cross-correlation's best value and ``correlation`` the refined coefficient."""

    x_m: float
    y_m: float
    yaw_rad: float
    peak: float
    correlation: float


def planar_transform(x_m: float, y_m: float, yaw_rad: float) -> Array:
    """The 3x3 homogeneous transform of a planar pose."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, x_m], [s, c, y_m], [0.0, 0.0, 1.0]])


def birdseye_grid(camera: PinholeCamera, near_m: float, far_m: float, half_width_m: float, resolution_m: float
                  ) -> BirdseyeGrid:
    """The top view of the body-frame ground from ``near_m`` to ``far_m`` ahead of the rear axle and
    ``half_width_m`` to each side, through the camera's mount and intrinsics (with its distortion)."""
    xs = np.arange(far_m, near_m - 1e-9, -resolution_m)
    ys = np.arange(half_width_m, -half_width_m - 1e-9, -resolution_m)
    if len(xs) < 8 or len(ys) < 8:
        raise ConfigError(f"a {far_m - near_m:.2f} by {2 * half_width_m:.2f} m road patch is too small at "
                          f"{resolution_m} m a pixel")
    x, y = np.meshgrid(xs, ys, indexing="ij")
    ground = np.stack([x, y, np.zeros_like(x), np.ones_like(x)], -1).reshape(-1, 4)
    in_cam = (ground @ invert_pose(camera.pose_body_cam_array).T)[:, :3]
    ahead = in_cam[:, 2] > 1e-3
    pixels = np.full((len(in_cam), 2), -1.0)
    if ahead.any():
        projected, _ = cv2.projectPoints(in_cam[ahead], np.zeros(3), np.zeros(3), camera.matrix,
                                         camera.distortion_array)
        pixels[ahead] = projected.reshape(-1, 2)
    seen = ahead & (pixels[:, 0] >= 0) & (pixels[:, 0] <= camera.width_px - 1) & (pixels[:, 1] >= 0) & (
        pixels[:, 1] <= camera.height_px - 1)
    pixels[~seen] = -10.0  # remapped to the border's 0, and masked
    pixel_from_body = np.array([[0.0, -1.0 / resolution_m, half_width_m / resolution_m],
                                [-1.0 / resolution_m, 0.0, far_m / resolution_m], [0.0, 0.0, 1.0]])
    return BirdseyeGrid(pixels[:, 0].reshape(x.shape).astype(np.float32),
                        pixels[:, 1].reshape(x.shape).astype(np.float32),
                        (seen.reshape(x.shape) * 255).astype(np.uint8), pixel_from_body)


def road_grids(camera: PinholeCamera, config: BirdseyeConfig) -> tuple[BirdseyeGrid, BirdseyeGrid]:
    """The reference patch (narrowed until the camera sees all of it) and the query's view around it."""
    mount = camera.pose_body_cam_array
    height = float(mount[2, 3])
    if height <= 0:
        raise ConfigError("the road's top view needs the camera's mount (its height above the road)")
    near, far = mount[0, 3] + config.near_heights * height, mount[0, 3] + config.far_heights * height
    half = config.half_width_heights * height
    while True:
        reference = birdseye_grid(camera, near, far, half, config.resolution_m)
        if reference.mask.all():
            break
        half *= 0.9
        if half < 8 * config.resolution_m:
            raise ConfigError("the camera does not see the road patch ahead (places.road.near_heights, "
                              "far_heights): check its mount")
    margin = config.margin_heights * height
    return reference, birdseye_grid(camera, near - margin, far + margin, half + margin, config.resolution_m)


def birdseye(image: Image, grid: BirdseyeGrid) -> NDArray[np.uint8]:
    """The grey top view of an image (out of view: 0)."""
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    return cv2.remap(gray, grid.map_x, grid.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def register_birdseye(reference: NDArray[np.uint8], query: NDArray[np.uint8], reference_grid: BirdseyeGrid,
                      query_grid: BirdseyeGrid, yaw_guess_rad: float, config: BirdseyeConfig
                      ) -> RoadRegistration | None:
    """The query body's planar pose in the reference body's frame, from their top views (see the module's
    description); None when the best match lies on the search's edge, the refinement fails or its
    correlation is below ``min_correlation``."""
    if reference.shape != reference_grid.shape or query.shape != query_grid.shape:
        raise PerceptionError(f"top views of {reference.shape} and {query.shape} do not fit their grids "
                              f"{reference_grid.shape} and {query_grid.shape}")
    template = reference.astype(np.float32)
    seen = query_grid.mask > 0
    if template.std() < 1.0 or not seen.any() or float(query[seen].std()) < 1.0:
        return None  # a blank road matches anywhere
    measured = query.astype(np.float32)
    filled = measured.copy()  # the search's correlation sees no edge where the view ends; ECC masks it instead
    filled[~seen] = float(measured[seen].mean())
    to_query_px, from_query_px = query_grid.pixel_from_body, np.linalg.inv(query_grid.pixel_from_body)
    from_reference_px = np.linalg.inv(reference_grid.pixel_from_body)
    step = math.radians(config.yaw_step_deg)
    count = round(config.yaw_span_deg / config.yaw_step_deg)
    best: tuple[float, float, tuple[int, int], Array] | None = None
    for yaw in yaw_guess_rad + step * np.arange(-count, count + 1):
        # the query's view turned by the heading about the rear axle: pixel p shows body point R^T q(p)
        turn = to_query_px @ planar_transform(0.0, 0.0, -float(yaw)) @ from_query_px
        turned = cv2.warpAffine(filled, turn[:2], query.shape[::-1], flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_REPLICATE)
        scores = cv2.matchTemplate(turned, template, cv2.TM_CCOEFF_NORMED)
        _, peak, _, corner = cv2.minMaxLoc(scores)
        if best is None or peak > best[0]:
            best = (float(peak), float(yaw), corner, scores)
    assert best is not None
    peak, yaw, corner, scores = best
    if corner[0] in (0, scores.shape[1] - 1) or corner[1] in (0, scores.shape[0] - 1):
        return None  # the best lies on the edge: the true offset may lie beyond the margins
    # the reference's pixel p sits on the turned query's pixel p + corner, so the reference body's point b and
    # the turned query's g = b - t differ by the shift t (read at p = 0)
    shift = from_reference_px @ [0.0, 0.0, 1.0] - from_query_px @ [corner[0], corner[1], 1.0]
    guess = planar_transform(float(shift[0]), float(shift[1]), yaw)
    warp = to_query_px @ np.linalg.inv(guess) @ from_reference_px
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-5)
    try:
        correlation, warp = cv2.findTransformECC(template, measured, warp[:2].astype(np.float32),
                                                 cv2.MOTION_EUCLIDEAN, criteria, query_grid.mask, 3)
    except cv2.error:
        return None  # the refinement diverged: no pose
    if correlation < config.min_correlation:
        return None
    pose = np.linalg.inv(from_query_px @ np.r_[warp, [[0.0, 0.0, 1.0]]] @ reference_grid.pixel_from_body)
    return RoadRegistration(float(pose[0, 2]), float(pose[1, 2]), math.atan2(pose[1, 0], pose[0, 0]), peak,
                            float(correlation))

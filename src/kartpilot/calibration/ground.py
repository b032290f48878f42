"""Ground calibration from one ChArUco board on the floor: what a team does on its first morning.

Each camera sees the board (some of its corners at least) in one image. From the corners:

* **Intrinsics**, when the rig file has none for the camera: the focal length from the one view of the board,
  with the principal point at the image's centre, square pixels and no distortion (one tilted view of a
  plane fixes one focal length; Zhang 2000). A rig file's own intrinsics, from ``kartpilot calibrate``, are
  better and are used when given.
* **The board's pose** in the camera (PnP, refined by Levenberg-Marquardt).
* **The ground frame** is the board's plane with z up. **The body frame** stands on the ground under the
  reference camera (``center``) at ``reference_x_m`` ahead of the body's origin (the rear axle in kartpilot's
  rigs), x forward along the reference camera's view projected on the ground, y left, z up. Every camera that
  sees the same board gets its pose on the body through it, so the three cameras' poses agree with each other
  even where their views do not overlap.
* **Mount**: height, pitch down, roll and yaw of each camera from its pose (``mount_angles``).

The bird's-eye view (:func:`birdseye_homography`, :func:`stitch_birdseye`) maps each image onto the ground
through its pose; with all three cameras it is the stitched view of the ground around the kart.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from kartpilot.calibration.board import BoardView
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import CalibrationError
from kartpilot.core.geometry import Array, invert_pose
from kartpilot.core.types import Image

__all__ = ["BirdseyeView", "GroundMount", "birdseye_homography", "board_pose", "calibrate_ground",
           "ground_coverage", "ground_points", "mount_angles", "single_view_intrinsics", "stitch_birdseye"]

# the board's own frame (OpenCV: z into the board, so down for a board lying face up) to a ground frame with z up
_BOARD_TO_GROUND = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class GroundMount:
    """One camera's calibration on the ground.

    Attributes:
        camera: the camera with its pose on the body (``pose_body_cam``).
        height_m, pitch_down_deg, roll_deg, yaw_deg: the mount as a person measures it (yaw left of forward).
        reprojection_px: RMS distance of the board's corners from their projection through the pose.
        corners: how many of the board's corners the camera saw.
        intrinsics_estimated: the focal length came from this one view (the rig file had none).
    """

    camera: PinholeCamera
    height_m: float
    pitch_down_deg: float
    roll_deg: float
    yaw_deg: float
    reprojection_px: float
    corners: int
    intrinsics_estimated: bool


def single_view_intrinsics(view: BoardView, size_wh: tuple[int, int]) -> PinholeCamera:
    """A camera with the focal length that one view of the board fixes (principal point at the centre, square
    pixels, no distortion)."""
    if len(view.pixels) < 6:
        raise CalibrationError(f"{view.name or 'the view'}: {len(view.pixels)} board corners; six or more are "
                               "needed to estimate the focal length")
    w, h = size_wh
    guess = np.array([[float(w), 0.0, (w - 1) / 2], [0.0, float(w), (h - 1) / 2], [0.0, 0.0, 1.0]])
    flags = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO
             | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3)
    _, K, _, _, _ = cv2.calibrateCamera([view.points_m.astype(np.float32)], [view.pixels.astype(np.float32)],
                                        (w, h), guess, np.zeros(5), flags=flags)
    if not (np.isfinite(K).all() and 0.1 * w < K[0, 0] < 20 * w):
        raise CalibrationError(f"{view.name or 'the view'}: the focal length from one view is implausible "
                               f"({K[0, 0]:.0f} px for a {w} px wide image); give the camera's intrinsics in the rig")
    return PinholeCamera.from_matrix(K, size_wh)


def board_pose(view: BoardView, camera: PinholeCamera) -> tuple[Array, float]:
    """(4x4 pose of the board in the camera, RMS reprojection error in pixels)."""
    if len(view.pixels) < 4:
        raise CalibrationError(f"{view.name or 'the view'}: {len(view.pixels)} board corners; four or more needed")
    K, dist = camera.matrix, camera.distortion_array
    points, pixels = view.points_m.astype(np.float64), view.pixels.astype(np.float64)
    ok, rvec, tvec = cv2.solvePnP(points, pixels, K, dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise CalibrationError(f"{view.name or 'the view'}: the board's pose could not be found")
    rvec, tvec = cv2.solvePnPRefineLM(points, pixels, K, dist, rvec, tvec)
    projected, _ = cv2.projectPoints(points, rvec, tvec, K, dist)
    rms = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - pixels) ** 2, axis=1))))
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rvec)[0]
    pose[:3, 3] = tvec.ravel()
    return pose, rms


def mount_angles(pose_body_cam: Array) -> tuple[float, float, float, float]:
    """(height_m, pitch_down_deg, roll_deg, yaw_deg) of a camera's pose on the body, the inverse of
    :func:`kartpilot.core.geometry.mount_pose`."""
    base = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    m = np.asarray(pose_body_cam, float)[:3, :3] @ base.T  # Rz(yaw) Ry(pitch) Rx(roll)
    pitch = math.asin(float(np.clip(-m[2, 0], -1.0, 1.0)))
    yaw = math.atan2(float(m[1, 0]), float(m[0, 0]))
    roll = math.atan2(float(m[2, 1]), float(m[2, 2]))
    return float(pose_body_cam[2][3]), math.degrees(pitch), math.degrees(roll), math.degrees(yaw)


def calibrate_ground(views: Mapping[str, BoardView], sizes: Mapping[str, tuple[int, int]],
                     cameras: Mapping[str, PinholeCamera] | None = None, reference: str = "center",
                     reference_x_m: float = 0.0) -> dict[str, GroundMount]:
    """Every camera's pose on the body from its view of one board lying on the ground (see the module's text).

    Args:
        views: the board as each camera saw it (the same board, not moved between the images).
        sizes: each camera's image size (width, height).
        cameras: known intrinsics by camera name (their poses are replaced); others are estimated from the view.
        reference: the camera whose view sets the body's forward direction.
        reference_x_m: how far ahead of the body's origin the reference camera stands.
    """
    if reference not in views:
        raise CalibrationError(f"the reference camera {reference!r} has no view of the board "
                               f"(views: {', '.join(views) or 'none'})")
    known = dict(cameras or {})
    intrinsics, board_in_cam, errors = {}, {}, {}
    for name, view in views.items():
        if name in known:
            if known[name].size_wh != tuple(sizes[name]):
                raise CalibrationError(f"camera {name!r}: the rig's calibration is {known[name].width_px}x"
                                       f"{known[name].height_px}, its image {sizes[name][0]}x{sizes[name][1]}")
            intrinsics[name] = known[name]
        else:
            intrinsics[name] = single_view_intrinsics(view, sizes[name])
        board_in_cam[name], errors[name] = board_pose(view, intrinsics[name])
    ground_board = np.eye(4)
    ground_board[:3, :3] = _BOARD_TO_GROUND
    # the reference camera in the ground frame: its position, and its optical axis flattened onto the ground
    ground_ref = ground_board @ invert_pose(board_in_cam[reference])
    axis = ground_ref[:3, 2].copy()
    axis[2] = 0.0
    if np.linalg.norm(axis) < 1e-6:
        raise CalibrationError(f"the {reference} camera looks straight down: it sets no forward direction")
    forward = axis / np.linalg.norm(axis)
    left = np.cross([0.0, 0.0, 1.0], forward)
    body_ground = np.eye(4)
    body_ground[:3, :3] = np.vstack([forward, left, [0.0, 0.0, 1.0]])
    origin = np.array([ground_ref[0, 3], ground_ref[1, 3], 0.0]) - reference_x_m * forward
    body_ground[:3, 3] = -body_ground[:3, :3] @ origin
    mounts = {}
    for name in views:
        pose = body_ground @ ground_board @ invert_pose(board_in_cam[name])
        height, pitch, roll, yaw = mount_angles(pose)
        if height <= 0:
            raise CalibrationError(f"camera {name!r} is below the board's plane: the board was not lying on the "
                                   "ground under the cameras, or its corners were mismatched")
        mounts[name] = GroundMount(intrinsics[name].on_body(pose), height, pitch, roll, yaw, errors[name],
                                   len(views[name].pixels), name not in known)
    return mounts


def ground_points(camera: PinholeCamera, pixels: Array) -> Array:
    """(N, 2) body x, y on the ground (z = 0) of (N, 2) pixels (undistorted first); NaN for pixels above the
    horizon."""
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    if camera.distortion:
        pixels = cv2.undistortPoints(pixels.reshape(-1, 1, 2), camera.matrix, camera.distortion_array,
                                     P=camera.matrix).reshape(-1, 2)
    pose = camera.pose_body_cam_array
    rays = camera.rays(pixels) @ pose[:3, :3].T
    origin = pose[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origin[2] / rays[:, 2]
    t = np.where(t > 0, t, np.nan)
    return (origin[:2] + t[:, None] * rays[:, :2]).reshape(-1, 2)


@dataclass(frozen=True)
class BirdseyeView:
    """The ground from above: ``x_range_m`` ahead (image up), ``y_range_m`` to the left (image left), at
    ``pixels_per_m``."""

    x_range_m: tuple[float, float] = (0.0, 8.0)
    y_range_m: tuple[float, float] = (-5.0, 5.0)
    pixels_per_m: float = 100.0

    @property
    def size_wh(self) -> tuple[int, int]:
        return (round((self.y_range_m[1] - self.y_range_m[0]) * self.pixels_per_m),
                round((self.x_range_m[1] - self.x_range_m[0]) * self.pixels_per_m))

    def to_pixels(self, xy_m: Array) -> Array:
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        return np.column_stack([(self.y_range_m[1] - xy[:, 1]) * self.pixels_per_m,
                                (self.x_range_m[1] - xy[:, 0]) * self.pixels_per_m])

    def ground_from_pixels(self) -> Array:
        """3x3: bird's-eye pixel (u, v, 1) to ground (x, y, 1)."""
        s = 1.0 / self.pixels_per_m
        return np.array([[0.0, -s, self.x_range_m[1]], [-s, 0.0, self.y_range_m[1]], [0.0, 0.0, 1.0]])


def birdseye_homography(camera: PinholeCamera, view: BirdseyeView) -> Array:
    """3x3: bird's-eye pixel to the camera's (undistorted) image pixel."""
    cam_body = invert_pose(camera.pose_body_cam_array)
    ground_to_image = camera.matrix @ np.column_stack([cam_body[:3, 0], cam_body[:3, 1], cam_body[:3, 3]])
    return ground_to_image @ view.ground_from_pixels()


def ground_coverage(camera: PinholeCamera, polygons_m: Sequence[Array],
                    view: BirdseyeView = BirdseyeView((1.0, 30.0), (-12.0, 12.0), 50.0)) -> np.ndarray:
    """How much of each pixel of the camera's image the polygons lying on the ground (N x 2, metres in the body
    frame) cover, 0 to 1 (float32, the camera's image size): drawn on a fine bird's-eye ``view`` and seen through
    the camera's mount. Paint whose place is known exactly, to lay onto a real frame or a synthetic one."""
    canvas = np.zeros((view.size_wh[1], view.size_wh[0]), np.float32)
    to_view = np.linalg.inv(view.ground_from_pixels())
    for polygon in polygons_m:
        px = (np.column_stack([polygon, np.ones(len(polygon))]) @ to_view.T)[:, :2]
        cv2.fillPoly(canvas, [np.round(px).astype(np.int32)], 1.0)
    return cv2.warpPerspective(canvas, birdseye_homography(camera, view), (camera.width_px, camera.height_px))


def stitch_birdseye(images: Mapping[str, Image], cameras: Mapping[str, PinholeCamera], view: BirdseyeView,
                    max_range_m: float = 12.0) -> Image:
    """The ground around the kart from every camera, each ground pixel from the camera nearest to it (the
    sharpest view); ground farther than ``max_range_m`` from a camera, behind it or outside its image is not
    taken from it."""
    w, h = view.size_wh
    out = np.zeros((h, w, 3), np.uint8)
    best = np.full((h, w), np.inf)
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), axis=-1).reshape(-1, 2).astype(np.float64)
    ground = np.column_stack([grid, np.ones(len(grid))]) @ view.ground_from_pixels().T
    for name, image in images.items():
        camera = cameras[name]
        colour = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        if camera.distortion:
            colour = cv2.undistort(colour, camera.matrix, camera.distortion_array)
        warped = cv2.warpPerspective(colour, birdseye_homography(camera, view), (w, h),
                                     flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        cam_body = invert_pose(camera.pose_body_cam_array)
        in_cam = np.column_stack([ground[:, :2], np.zeros(len(ground))]) @ cam_body[:3, :3].T + cam_body[:3, 3]
        depth = in_cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = camera.fx_px * in_cam[:, 0] / depth + camera.cx_px
            v = camera.fy_px * in_cam[:, 1] / depth + camera.cy_px
        seen = (depth > 0.05) & (u >= 0) & (u <= camera.width_px - 1) & (v >= 0) & (v <= camera.height_px - 1)
        distance = np.hypot(ground[:, 0] - camera.pose_body_cam_array[0, 3],
                            ground[:, 1] - camera.pose_body_cam_array[1, 3])
        take = (seen & (distance <= max_range_m) & (distance < best.ravel())).reshape(h, w)
        out[take] = warped[take]
        best[take] = distance.reshape(h, w)[take]
    return out

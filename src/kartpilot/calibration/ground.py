"""Ground calibration from one ChArUco board on the floor: what a team does on its first morning.

Each camera sees the board (part of it at least) in one image. From its points (the inner corners and the
markers' own corners, :func:`kartpilot.calibration.board.board_points`):

* **Intrinsics**, when the rig file has none for the camera: the focal length from the one view of the board,
  with the principal point at the image's centre, square pixels and no distortion (one tilted view of a
  plane fixes one focal length; Zhang 2000). Seen nearly square-on it fixes none, and the fit's covariance says
  so: such a camera is refused with the command that measures its lens (``MAX_FOCAL_SD``). A rig file's own
  intrinsics, from ``kartpilot calibrate mono``, are better and are used when given.
* **The board's pose** in the camera (PnP, refined by Levenberg-Marquardt).
* **The ground frame** is the board's plane with z up. **The body frame** stands on the ground under the
  reference camera (``center``) at ``reference_x_m`` ahead of the body's origin (the rear axle in kartpilot's
  rigs), x forward along the reference camera's view projected on the ground, y left, z up. Every camera that
  sees the same board gets its pose on the body through it, so the three cameras' poses agree with each other
  even where their views do not overlap.
* **Mount**: height, pitch down, roll and yaw of each camera from its pose (``mount_angles``), and the optical
  axis's tilt from straight down and heading on the ground (``axis_angles``), which stay meaningful for a camera
  looking down, where roll and yaw trade off; each with its standard deviation from resampling the points.
* **Agreement**: where two cameras see the same board points, their ground points' distances
  (:func:`ground_agreement`).

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
from kartpilot.core.errors import CalibrationError, ConfigError
from kartpilot.core.geometry import Array, invert_pose
from kartpilot.core.types import Image

__all__ = ["AGREEMENT_WARN_M", "Agreement", "BirdseyeView", "GroundMount", "MountSpread", "axis_angles",
           "birdseye_homography", "board_pose", "board_tilt_deg", "calibrate_ground", "ground_agreement",
           "ground_coverage", "ground_points", "mount_angles", "single_view_intrinsics", "stitch_birdseye"]

# the board's own frame (OpenCV: z into the board, so down for a board lying face up) to a ground frame with z up
_BOARD_TO_GROUND = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class MountSpread:
    """One standard deviation of each figure of a :class:`GroundMount`, from refitting on the board's points
    resampled with replacement (the bootstrap): what the points' noise and their spread over the image leave
    uncertain, the focal length's too where it was estimated."""

    height_m: float
    pitch_down_deg: float
    roll_deg: float
    yaw_deg: float
    tilt_deg: float
    heading_deg: float


@dataclass(frozen=True)
class GroundMount:
    """One camera's calibration on the ground.

    Attributes:
        camera: the camera with its pose on the body (``pose_body_cam``).
        height_m, pitch_down_deg, roll_deg, yaw_deg: the mount as a person measures it (yaw left of forward).
        tilt_deg, heading_deg: the optical axis's angle from straight down (0: looking straight down, 90: at the
            horizon) and the heading of its foot on the ground (left of forward; NaN within a degree of straight
            down, where it has none). Unlike roll and yaw, both stay meaningful for a camera looking down.
        reprojection_px: RMS distance of the board's points from their projection through the pose.
        corners: how many of the board's points the camera saw.
        intrinsics_estimated: the focal length came from this one view (the rig file had none).
        focal_sd_px: the estimated focal length's standard deviation (0 when the rig gave it).
        spread: the figures' standard deviations (None when not resampled).
    """

    camera: PinholeCamera
    height_m: float
    pitch_down_deg: float
    roll_deg: float
    yaw_deg: float
    reprojection_px: float
    corners: int
    intrinsics_estimated: bool
    tilt_deg: float = math.nan
    heading_deg: float = math.nan
    focal_sd_px: float = 0.0
    spread: MountSpread | None = None


MAX_FOCAL_SD = 0.02
"""The largest standard deviation of a focal length estimated from one view, as a share of it. Seen nearly
square-on, a board's size in the image is the focal length over the distance, and one cannot be told from the
other (Zhang 2000): the height then errs by the focal length's share. At 2 % (1 cm at 0.56 m) the bird's-eye
view's squares stay within the 2 % that the ground calibration promises; beyond it the lens must be given."""

LENS_HINT = ("give the lens: `kartpilot calibrate mono PHOTOS... --charuco --board ... --out lens.yaml` "
             "(a dozen photos of the board, or --video of it moved before the camera), then --rig lens.yaml")


def board_tilt_deg(board_in_cam: Array) -> float:
    """The angle between the board's plane and the image plane: 0 when the camera sees it square-on."""
    normal = np.asarray(board_in_cam, float)[:3, 2]
    return float(np.degrees(np.arccos(np.clip(abs(normal[2]), 0.0, 1.0))))


def single_view_intrinsics(view: BoardView, size_wh: tuple[int, int]) -> tuple[PinholeCamera, float]:
    """(a camera with the focal length that one view of the board fixes (principal point at the centre, square
    pixels, no distortion), the focal length's standard deviation in pixels from the fit's covariance). Refused
    where the view cannot tell the focal length (``MAX_FOCAL_SD``), naming the command that measures the lens."""
    name = view.name or "the view"
    if len(view.pixels) < 6:
        raise CalibrationError(f"{name}: {view.counted()} of the board; six or more are needed to estimate the "
                               f"focal length; or {LENS_HINT}")
    w, h = size_wh
    guess = np.array([[float(w), 0.0, (w - 1) / 2], [0.0, float(w), (h - 1) / 2], [0.0, 0.0, 1.0]])
    flags = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO
             | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3)
    _, K, _, rvecs, _, deviations, _, _ = cv2.calibrateCameraExtended(
        [view.points_m.astype(np.float32)], [view.pixels.astype(np.float32)], (w, h), guess, np.zeros(5), flags=flags)
    focal = float(K[0, 0])
    # with the aspect ratio fixed OpenCV fits fy (fx follows): its deviation is the focal length's
    focal_sd = float(np.max(np.ravel(deviations)[:2])) if deviations is not None else math.inf
    plausible = bool(np.isfinite(K).all()) and 0.1 * w < focal < 20 * w
    if not (plausible and math.isfinite(focal_sd) and focal_sd <= MAX_FOCAL_SD * focal):
        pose = np.eye(4)
        pose[:3, :3] = cv2.Rodrigues(np.asarray(rvecs[0], np.float64))[0]
        tilt = board_tilt_deg(pose)
        found = (f"the fit gives fx {focal:.0f} +- {focal_sd:.0f} px, more than {MAX_FOCAL_SD:.0%}" if plausible else
                 f"the fit finds no focal length for a {w} px wide image (fx {focal:.0f} px)")
        raise CalibrationError(f"{name}: one view cannot tell this camera's focal length: it sees the board "
                               f"{tilt:.0f} deg from square-on, and {found}; {LENS_HINT}")
    return PinholeCamera.from_matrix(K, size_wh), focal_sd


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


STRAIGHT_DOWN_DEG = 1.0
"""Within this of straight down, an optical axis has no heading on the ground."""


def axis_angles(pose_body_cam: Array) -> tuple[float, float]:
    """(tilt_deg, heading_deg): the optical axis's angle from straight down, and the heading (left of forward) of
    its foot on the ground, NaN within ``STRAIGHT_DOWN_DEG`` of straight down."""
    axis = np.asarray(pose_body_cam, float)[:3, 2]
    tilt = math.degrees(math.acos(float(np.clip(-axis[2], -1.0, 1.0))))
    heading = math.degrees(math.atan2(float(axis[1]), float(axis[0]))) if tilt > STRAIGHT_DOWN_DEG else math.nan
    return tilt, heading


@dataclass(frozen=True)
class _Fit:
    intrinsics: dict[str, PinholeCamera]
    focal_sd_px: dict[str, float]
    poses: Mapping[str, Array]
    errors: dict[str, float]


def _fit(views: Mapping[str, BoardView], sizes: Mapping[str, tuple[int, int]], known: Mapping[str, PinholeCamera],
         reference: str, reference_x_m: float) -> _Fit:
    intrinsics, focal_sd, board_in_cam, errors = {}, {}, {}, {}
    for name, view in views.items():
        if name in known:
            intrinsics[name], focal_sd[name] = known[name], 0.0
        else:
            intrinsics[name], focal_sd[name] = single_view_intrinsics(view, sizes[name])
        board_in_cam[name], errors[name] = board_pose(view, intrinsics[name])
    ground_board = np.eye(4)
    ground_board[:3, :3] = _BOARD_TO_GROUND
    # the reference camera in the ground frame: its position, and its optical axis flattened onto the ground
    ground_ref = ground_board @ invert_pose(board_in_cam[reference])
    axis = ground_ref[:3, 2].copy()
    axis[2] = 0.0
    if np.linalg.norm(axis) < math.sin(math.radians(STRAIGHT_DOWN_DEG)):
        raise CalibrationError(f"the {reference} camera looks straight down: it sets no forward direction (give "
                               "--reference a camera that looks ahead)")
    forward = axis / np.linalg.norm(axis)
    left = np.cross([0.0, 0.0, 1.0], forward)
    body_ground = np.eye(4)
    body_ground[:3, :3] = np.vstack([forward, left, [0.0, 0.0, 1.0]])
    origin = np.array([ground_ref[0, 3], ground_ref[1, 3], 0.0]) - reference_x_m * forward
    body_ground[:3, 3] = -body_ground[:3, :3] @ origin
    poses = {name: body_ground @ ground_board @ invert_pose(board_in_cam[name]) for name in views}
    return _Fit(intrinsics, focal_sd, poses, errors)


def _figures(pose: Array) -> Array:
    height, pitch, roll, yaw = mount_angles(pose)
    tilt, heading = axis_angles(pose)
    return np.array([height, pitch, roll, yaw, tilt, heading])


def _angle_sd_deg(values: Array) -> float:
    """The standard deviation of angles in degrees, about their circular mean (a yaw near 180 wraps)."""
    radians = np.radians(values[np.isfinite(values)])
    if len(radians) < 2:
        return math.nan
    mean = math.atan2(float(np.mean(np.sin(radians))), float(np.mean(np.cos(radians))))
    return float(np.degrees(np.std(np.angle(np.exp(1j * (radians - mean))), ddof=1)))


def calibrate_ground(views: Mapping[str, BoardView], sizes: Mapping[str, tuple[int, int]],
                     cameras: Mapping[str, PinholeCamera] | None = None, reference: str = "center",
                     reference_x_m: float = 0.0, resamples: int = 0, seed: int = 0) -> dict[str, GroundMount]:
    """Every camera's pose on the body from its view of one board lying on the ground (see the module's text).

    Args:
        views: the board as each camera saw it (the same board, not moved between the images).
        sizes: each camera's image size (width, height).
        cameras: known intrinsics by camera name (their poses are replaced); others are estimated from the view,
            where it can tell them (``MAX_FOCAL_SD``).
        reference: the camera whose view sets the body's forward direction.
        reference_x_m: how far ahead of the body's origin the reference camera stands.
        resamples: refit this many times on the points resampled with replacement, for each figure's standard
            deviation (``GroundMount.spread``; 0: none).
        seed: the resampling's seed.
    """
    if reference not in views:
        raise CalibrationError(f"the reference camera {reference!r} has no view of the board "
                               f"(views: {', '.join(views) or 'none'})")
    known = {name: camera for name, camera in (cameras or {}).items() if name in views}
    for name, camera in known.items():
        if camera.size_wh != tuple(sizes[name]):
            raise CalibrationError(f"camera {name!r}: the rig's calibration is {camera.width_px}x{camera.height_px}, "
                                   f"its image {sizes[name][0]}x{sizes[name][1]}")
    fit = _fit(views, sizes, known, reference, reference_x_m)
    for name, pose in fit.poses.items():
        if pose[2, 3] <= 0:
            raise CalibrationError(f"camera {name!r} is below the board's plane: the board was not lying on the "
                                   "ground under the cameras, or its corners were mismatched")
    spreads: dict[str, MountSpread] = {}
    if resamples > 1:
        rng = np.random.default_rng(seed)
        samples: dict[str, list[Array]] = {name: [] for name in views}
        for _ in range(resamples):
            drawn = {}
            for name, view in views.items():
                pick = rng.integers(0, len(view.ids), len(view.ids))
                drawn[name] = BoardView(view.name, view.pixels[pick], view.points_m[pick], view.ids[pick])
            try:
                again = _fit(drawn, sizes, known, reference, reference_x_m)
            except CalibrationError:
                continue  # a draw of too few distinct points: the others tell the spread
            for name, pose in again.poses.items():
                samples[name].append(_figures(pose))
        for name, rows in samples.items():
            if len(rows) >= 2:
                table = np.array(rows)
                spreads[name] = MountSpread(float(np.std(table[:, 0], ddof=1)),
                                            *(_angle_sd_deg(table[:, k]) for k in range(1, 6)))
    mounts = {}
    for name, pose in fit.poses.items():
        height, pitch, roll, yaw, tilt, heading = _figures(pose)
        mounts[name] = GroundMount(fit.intrinsics[name].on_body(pose), height, pitch, roll, yaw, fit.errors[name],
                                   len(views[name].pixels), name not in known, tilt, heading, fit.focal_sd_px[name],
                                   spreads.get(name))
    return mounts


AGREEMENT_WARN_M = 0.03
"""Two cameras' ground points of the same board point further apart than this are worth a warning: a lane line is
5 to 10 cm wide, and at 3 cm a line seen by two cameras lands as two lines a third of its width apart (issue 57
asks 3 cm of another team's kart; the Hanze kart's cameras agree within about a centimetre, docs/real-kart.md)."""


@dataclass(frozen=True)
class Agreement:
    """Where two cameras see the same board points: how many, and how far apart their ground points land."""

    first: str
    second: str
    points: int
    median_m: float
    max_m: float


def ground_agreement(views: Mapping[str, BoardView], cameras: Mapping[str, PinholeCamera]) -> list[Agreement]:
    """For each pair of cameras that see four or more of the same board points, those points mapped onto the ground
    through each camera's pose, and the distances between them."""
    names = list(views)
    out = []
    for k, first in enumerate(names):
        for second in names[k + 1:]:
            shared = np.intersect1d(views[first].ids, views[second].ids)
            if len(shared) < 4:
                continue
            a = ground_points(cameras[first], _pixels_of(views[first], shared))
            b = ground_points(cameras[second], _pixels_of(views[second], shared))
            gap = np.linalg.norm(a - b, axis=1)
            gap = gap[np.isfinite(gap)]
            if len(gap):
                out.append(Agreement(first, second, len(gap), float(np.median(gap)), float(np.max(gap))))
    return out


def _pixels_of(view: BoardView, ids: Array) -> Array:
    order = {int(i): k for k, i in enumerate(view.ids)}
    return view.pixels[[order[int(i)] for i in ids]]


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


MAX_BIRDSEYE_PIXELS = 40_000_000
"""The largest bird's-eye view kartpilot draws (8 m by 10 m at 100 px/m is 0.8 megapixels)."""


@dataclass(frozen=True)
class BirdseyeView:
    """The ground from above: ``x_range_m`` ahead (image up), ``y_range_m`` to the left (image left), at
    ``pixels_per_m``."""

    x_range_m: tuple[float, float] = (0.0, 8.0)
    y_range_m: tuple[float, float] = (-5.0, 5.0)
    pixels_per_m: float = 100.0

    def __post_init__(self) -> None:
        values = (*self.x_range_m, *self.y_range_m, self.pixels_per_m)
        if not (all(math.isfinite(v) for v in values) and self.x_range_m[0] < self.x_range_m[1]
                and self.y_range_m[0] < self.y_range_m[1] and self.pixels_per_m > 0):
            raise ConfigError(f"bird's-eye view: ranges from low to high and a positive scale, got "
                              f"{self.x_range_m}, {self.y_range_m}, {self.pixels_per_m} px/m")
        w, h = self.size_wh
        if w * h > MAX_BIRDSEYE_PIXELS:
            raise ConfigError(f"bird's-eye view of {w}x{h} px: more than {MAX_BIRDSEYE_PIXELS / 1e6:.0f} "
                              "megapixels; a smaller reach or fewer pixels per metre")

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


OUTLINE_COLOURS = ((0, 200, 255), (255, 160, 0), (80, 255, 80), (255, 80, 255), (80, 80, 255))
"""BGR: each camera's outline in the stitched view, in the order of the images."""


def stitch_birdseye(images: Mapping[str, Image], cameras: Mapping[str, PinholeCamera], view: BirdseyeView,
                    max_range_m: float = 12.0, outline: bool = False) -> Image:
    """The ground around the kart from every camera, each ground pixel from the camera nearest to it (the
    sharpest view); ground farther than ``max_range_m`` from a camera, behind it or outside its image is not
    taken from it. ``outline``: each camera's part outlined in its colour and labelled with its name."""
    w, h = view.size_wh
    out = np.zeros((h, w, 3), np.uint8)
    owner = np.full((h, w), -1, np.int32)
    best = np.full((h, w), np.inf)
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), axis=-1).reshape(-1, 2).astype(np.float64)
    ground = np.column_stack([grid, np.ones(len(grid))]) @ view.ground_from_pixels().T
    for index, (name, image) in enumerate(images.items()):
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
        owner[take] = index
        best[take] = distance.reshape(h, w)[take]
    if outline:
        for index, name in enumerate(images):
            mask = (owner == index).astype(np.uint8)
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            if not contours:
                continue
            colour = OUTLINE_COLOURS[index % len(OUTLINE_COLOURS)]
            cv2.drawContours(out, contours, -1, colour, 2)
            x, y, _, bh = cv2.boundingRect(max(contours, key=cv2.contourArea))
            cv2.putText(out, name, (x + 6, y + bh // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2, cv2.LINE_AA)
    return out

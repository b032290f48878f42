"""Camera models: a pinhole camera with distortion and a rectified stereo rig.

Pixel convention is OpenCV's: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from kartpilot.core.errors import CalibrationError
from kartpilot.core.geometry import Array

__all__ = ["DISTORTION_COUNTS", "CaptureSettings", "PinholeCamera", "StereoRig", "body_mask_from_data",
           "camera_from_dict", "camera_to_dict"]

DISTORTION_COUNTS = (0, 4, 5, 8, 12, 14)  # how many coefficients OpenCV's lens models take (0: none)


@dataclass(frozen=True)
class CaptureSettings:
    """How to open a live camera (the size comes from its calibration).

    Attributes:
        device: a V4L2 index (``"0"``), a device path (``/dev/video2``, or a stable
            ``/dev/v4l/by-id/...`` link) or a video file (a bench test without cameras).
        fps: the frame rate to ask for.
        exposure: the driver's manual exposure value (V4L2: units of 100 us); None leaves
            auto exposure on. Outdoors a fixed exposure keeps the image from pumping.
        fourcc: the pixel format to ask for; MJPG fits 960x540 at 30 fps through USB 2.
    """

    device: str
    fps: float = 30.0
    exposure: float | None = None
    fourcc: str = "MJPG"

    def __post_init__(self) -> None:
        if not self.device:
            raise CalibrationError("a camera's capture device must not be empty")
        if not self.fps > 0:
            raise CalibrationError(f"capture fps must be positive, got {self.fps}")
        if len(self.fourcc) != 4:
            raise CalibrationError(f"fourcc must have 4 characters, got {self.fourcc!r}")


MAX_FOCAL_PER_PX = 100.0
"""The longest focal length a camera may have, in multiples of its image's longest side: a field of view of about
half a degree. A kart's cameras have 0.4 to 1.5 (a 30 to 100 degree view); an infinite focal length is a typo."""


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of one camera.

    Attributes:
        fx_px, fy_px: focal lengths in pixels.
        cx_px, cy_px: principal point in pixels.
        width_px, height_px: image size.
        distortion: OpenCV coefficients (k1, k2, p1, p2[, k3...]); empty for none.
        pose_body_cam: 4x4 camera-to-body transform (the camera's pose on the kart).
        body_mask: polygons of what belongs to the kart itself in this camera's view (its frame, bumper, nose),
            each a tuple of (x, y) corners as fractions of the width and height, so one mask serves every
            resolution of the camera. Nothing in them is the world: detectors leave them out.
    """

    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    width_px: int
    height_px: int
    distortion: tuple[float, ...] = ()
    pose_body_cam: tuple[tuple[float, ...], ...] = field(
        default=((1.0, 0, 0, 0), (0, 1.0, 0, 0), (0, 0, 1.0, 0), (0, 0, 0, 1.0))
    )
    body_mask: tuple[tuple[tuple[float, float], ...], ...] = ()

    def __post_init__(self) -> None:
        if not (self.fx_px > 0 and self.fy_px > 0):
            raise CalibrationError(f"focal lengths must be positive, got {self.fx_px}, {self.fy_px}")
        if self.width_px <= 0 or self.height_px <= 0:
            raise CalibrationError(f"image size must be positive, got {self.width_px}x{self.height_px}")
        longest = max(self.width_px, self.height_px)
        if not (self.fx_px <= MAX_FOCAL_PER_PX * longest and self.fy_px <= MAX_FOCAL_PER_PX * longest):
            raise CalibrationError(f"focal lengths {self.fx_px}, {self.fy_px} px for a {self.width_px}x"
                                   f"{self.height_px} image: a field of view under half a degree (at most "
                                   f"{MAX_FOCAL_PER_PX} times the image's side)")
        if not all(math.isfinite(v) for v in self.distortion):
            raise CalibrationError(f"distortion coefficients must be finite numbers, got {list(self.distortion)}")
        pose = np.asarray(self.pose_body_cam, dtype=np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise CalibrationError("the camera's pose on the body must be a 4x4 of finite numbers")
        rotation = pose[:3, :3]
        if not (np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4) and np.linalg.det(rotation) > 0
                and np.allclose(pose[3], (0.0, 0.0, 0.0, 1.0))):
            raise CalibrationError("the camera's pose on the body is not a rigid motion (its 3x3 part must be a "
                                   "rotation: orthonormal, not mirrored)")
        if not (0 <= self.cx_px <= self.width_px and 0 <= self.cy_px <= self.height_px):
            raise CalibrationError(
                f"principal point ({self.cx_px}, {self.cy_px}) lies outside the "
                f"{self.width_px}x{self.height_px} image"
            )
        if len(self.distortion) not in DISTORTION_COUNTS:
            raise CalibrationError(f"distortion needs 4, 5, 8, 12 or 14 values, got {len(self.distortion)}")
        for polygon in self.body_mask:
            corners = np.asarray(polygon, dtype=np.float64)
            if corners.ndim != 2 or corners.shape[1] != 2 or len(corners) < 3:
                raise CalibrationError("a body mask polygon needs at least three (x, y) corners")
            if not (np.all(np.isfinite(corners)) and corners.min() >= 0.0 and corners.max() <= 1.0):
                raise CalibrationError("a body mask's corners are fractions of the image, from 0 to 1")

    def body_mask_image(self, width_px: int | None = None, height_px: int | None = None
                        ) -> np.ndarray[Any, np.dtype[np.uint8]] | None:
        """The body mask as a uint8 image (255 on the kart's body) of the given size (the calibration's by
        default); None when the camera has none."""
        if not self.body_mask:
            return None
        w, h = width_px or self.width_px, height_px or self.height_px
        mask = np.zeros((h, w), np.uint8)
        import cv2  # the camera model itself needs no OpenCV; only drawing the mask does

        polygons = [np.round(np.asarray(p) * [w - 1, h - 1]).astype(np.int32) for p in self.body_mask]
        cv2.fillPoly(mask, polygons, 255)
        return mask

    @classmethod
    def from_matrix(
        cls,
        camera_matrix: Array,
        size_wh: tuple[int, int],
        distortion: Array | tuple[float, ...] = (),
    ) -> PinholeCamera:
        """Build from a 3x3 camera matrix and an image size (width, height)."""
        K = np.asarray(camera_matrix, dtype=np.float64)
        dist = tuple(float(d) for d in np.asarray(distortion, dtype=np.float64).ravel())
        if dist and not any(dist):
            dist = ()
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                   int(size_wh[0]), int(size_wh[1]), dist)

    @property
    def matrix(self) -> Array:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    @property
    def distortion_array(self) -> Array:
        """Distortion coefficients as an array for OpenCV (zeros when there are none)."""
        return np.asarray(self.distortion if self.distortion else (0.0,) * 5, dtype=np.float64)

    @property
    def size_wh(self) -> tuple[int, int]:
        return (self.width_px, self.height_px)

    @property
    def pose_body_cam_array(self) -> Array:
        return np.asarray(self.pose_body_cam, dtype=np.float64)

    def on_body(self, pose_body_cam: Array) -> PinholeCamera:
        """The same camera mounted at ``pose_body_cam`` (4x4) on the kart."""
        return replace(self, pose_body_cam=tuple(tuple(float(v) for v in row) for row in np.asarray(pose_body_cam)))

    def rays(self, pixels: Array) -> Array:
        """The (..., 3) directions with z = 1 in the camera frame of (..., 2) pixels (no distortion): what
        :meth:`project` maps back to each pixel."""
        pixels = np.asarray(pixels, dtype=np.float64)
        return np.stack([(pixels[..., 0] - self.cx_px) / self.fx_px, (pixels[..., 1] - self.cy_px) / self.fy_px,
                         np.ones(pixels.shape[:-1])], axis=-1)

    def ros_calibration(self, baseline_m: float = 0.0) -> dict[str, Any]:
        """The camera in ROS's CameraInfo terms, which Foxglove's CameraCalibration shares: the distortion model,
        D (at least five values), K, R (identity: the images are as recorded) and P, whose ``P[0, 3]`` is
        ``-fx * baseline_m`` for a stereo pair's right camera. Matrices as row-major lists."""
        distortion = [float(v) for v in self.distortion_array]
        distortion += [0.0] * (5 - len(distortion))
        k = self.matrix
        p = np.hstack([k, np.array([[-k[0, 0] * baseline_m], [0.0], [0.0]])])
        return {"distortion_model": "rational_polynomial" if len(distortion) > 5 else "plumb_bob",
                "D": distortion, "K": k.ravel().tolist(), "R": np.eye(3).ravel().tolist(), "P": p.ravel().tolist()}

    def project(self, points_cam: Array) -> Array:
        """Project (N, 3) points in the camera frame to (N, 2) pixels (no distortion)."""
        points = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        z = points[:, 2]
        return np.stack(
            [self.fx_px * points[:, 0] / z + self.cx_px, self.fy_px * points[:, 1] / z + self.cy_px],
            axis=1,
        )


@dataclass(frozen=True)
class StereoRig:
    """A rectified stereo pair: both images share K; the right camera sits ``baseline_m`` to the right.

    ``P0 = K [I | 0]`` and ``P1 = K [I | (-baseline_m, 0, 0)]`` as in KITTI's calib.txt.
    A point at depth Z has disparity ``d = fx * baseline / Z`` pixels.
    """

    camera: PinholeCamera
    baseline_m: float

    def __post_init__(self) -> None:
        if not self.baseline_m > 0:
            raise CalibrationError(
                f"stereo baseline must be positive (right camera to the right), got {self.baseline_m} m"
            )
        if self.camera.distortion:
            raise CalibrationError("a rectified stereo rig cannot carry lens distortion")

    @classmethod
    def from_projections(cls, P0: Array, P1: Array, size_wh: tuple[int, int]) -> StereoRig:
        """Build from KITTI-style 3x4 projection matrices of the rectified left and right cameras."""
        P0 = np.asarray(P0, dtype=np.float64).reshape(3, 4)
        P1 = np.asarray(P1, dtype=np.float64).reshape(3, 4)
        if not np.allclose(P0[:, :3], P1[:, :3], rtol=1e-6, atol=1e-6):
            raise CalibrationError("P0 and P1 must share the same rectified camera matrix")
        if abs(P0[2, 2] - 1.0) > 1e-9 or abs(P0[0, 1]) > 1e-9:
            raise CalibrationError("P0 is not a rectified pinhole projection [K | 0]")
        fx = P0[0, 0]
        baseline = -(P1[0, 3] - P0[0, 3]) / fx
        return cls(PinholeCamera.from_matrix(P0[:, :3], size_wh), float(baseline))

    @property
    def P0(self) -> Array:
        projection = np.zeros((3, 4))
        projection[:, :3] = self.camera.matrix
        return projection

    @property
    def P1(self) -> Array:
        projection = self.P0
        projection[0, 3] = -self.camera.fx_px * self.baseline_m
        return projection

    def depth_from_disparity(self, disparity_px: Array) -> Array:
        """Depth in metres for disparities in pixels (inf where the disparity is not positive)."""
        disparity = np.asarray(disparity_px, dtype=np.float64)
        with np.errstate(divide="ignore"):
            return np.where(disparity > 0, self.camera.fx_px * self.baseline_m / disparity, np.inf)


def body_mask_from_data(data: Any) -> tuple[tuple[tuple[float, float], ...], ...]:
    """A body mask from its YAML or JSON form (a list of polygons, each a list of [x, y]); the camera checks it."""
    if not isinstance(data, (list, tuple)) or not all(isinstance(p, (list, tuple)) for p in data):
        raise CalibrationError("body_mask must be a list of polygons, each a list of [x, y] fractions")
    try:
        return tuple(tuple((float(x), float(y)) for x, y in polygon) for polygon in data)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"body_mask: each corner is [x, y] ({exc})") from exc


def camera_to_dict(camera: PinholeCamera) -> dict[str, Any]:
    """A plain, JSON-serialisable dict of a camera (recording manifests, place databases)."""
    data = asdict(camera)
    data["distortion"] = list(camera.distortion)
    data["pose_body_cam"] = [list(row) for row in camera.pose_body_cam]
    data["body_mask"] = [[list(corner) for corner in polygon] for polygon in camera.body_mask]
    return data


def camera_from_dict(name: str, data: dict[str, Any], where: str = "") -> PinholeCamera:
    """The camera that :func:`camera_to_dict` wrote; a malformed one raises CalibrationError naming it."""
    try:
        return PinholeCamera(
            float(data["fx_px"]), float(data["fy_px"]), float(data["cx_px"]), float(data["cy_px"]),
            int(data["width_px"]), int(data["height_px"]), tuple(float(d) for d in data.get("distortion", ())),
            tuple(tuple(float(v) for v in row) for row in data.get("pose_body_cam", np.eye(4).tolist())),
            body_mask_from_data(data.get("body_mask") or ()),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise CalibrationError(" ".join(filter(None, (f"camera {name!r}", where, f"is malformed ({exc})")))) from exc

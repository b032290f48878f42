"""SE(3) and SO(3) helpers on plain 4x4 / 3x3 NumPy arrays.

Convention: ``T_a_b`` maps points from frame ``b`` into frame ``a``
(``p_a = T_a_b @ p_b``). A camera pose ``T_world_cam`` is camera-to-world, as in
KITTI's pose files. Camera frames are x right, y down, z forward.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from kartpilot.core.errors import ConfigError

__all__ = [
    "Array",
    "Pose2D",
    "arc_2d",
    "between_2d",
    "compose_2d",
    "cross_matrix",
    "ground_poses",
    "invert_pose",
    "mount_pose",
    "pitched_mount",
    "planar_pose",
    "pose_from_quaternion",
    "pose_from_rotvec",
    "pose_from_rt",
    "projection_jacobian",
    "quaternion_xyzw_from_pose",
    "relative_pose",
    "rotation_angle_rad",
    "rotvec_from_pose",
    "transform_points",
    "vo_ground_pose",
]

Array = NDArray[np.floating[Any]]


def pose_from_rt(rotation: Array, translation: Array) -> Array:
    """A 4x4 pose from a 3x3 rotation and a 3-vector translation."""
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = np.asarray(translation, dtype=np.float64).reshape(3)
    return pose


def pose_from_rotvec(rotvec: Array, translation: Array) -> Array:
    """A 4x4 pose from an axis-angle vector (rad) and a translation (m)."""
    rotation = Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64).reshape(3)).as_matrix()
    return pose_from_rt(rotation, translation)


def rotvec_from_pose(pose: Array) -> Array:
    """The axis-angle vector (rad) of a pose's rotation."""
    return np.asarray(Rotation.from_matrix(pose[:3, :3]).as_rotvec(), dtype=np.float64)


def pose_from_quaternion(quat_xyzw: Array, translation: Array) -> Array:
    """A 4x4 pose from a unit quaternion in (x, y, z, w) order, as TUM files store it."""
    rotation = Rotation.from_quat(np.asarray(quat_xyzw, dtype=np.float64)).as_matrix()
    return pose_from_rt(rotation, translation)


def quaternion_xyzw_from_pose(pose: Array) -> Array:
    """The (x, y, z, w) unit quaternion of a pose's rotation, with w >= 0."""
    quat = np.asarray(Rotation.from_matrix(pose[:3, :3]).as_quat(), dtype=np.float64)
    return quat if quat[3] >= 0 else -quat


def invert_pose(pose: Array) -> Array:
    """The inverse of a rigid transform, without a general matrix inverse."""
    inverse = np.eye(4)
    rotation_t = pose[:3, :3].T
    inverse[:3, :3] = rotation_t
    inverse[:3, 3] = -rotation_t @ pose[:3, 3]
    return inverse


def relative_pose(pose_a: Array, pose_b: Array) -> Array:
    """``T_a_b = inv(T_w_a) @ T_w_b``: pose ``b`` seen from pose ``a``."""
    return invert_pose(pose_a) @ pose_b


def rotation_angle_rad(pose_or_rotation: Array) -> float:
    """The rotation angle (rad) of a pose or rotation matrix, in [0, pi]."""
    rotation = pose_or_rotation[:3, :3]
    cos_angle = (np.trace(rotation) - 1.0) / 2.0
    return float(np.arccos(np.clip(cos_angle, -1.0, 1.0)))


def cross_matrix(v: Array) -> Array:
    """(..., 3) vectors as (..., 3, 3) cross-product matrices: ``cross_matrix(a) @ b == a x b``."""
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1), np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def projection_jacobian(points: Array, fx: float, fy: float) -> Array:
    """(N, 2, 3): how a pinhole camera's pixel (u, v) moves with each (N, 3) point in its frame."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    zeros = np.zeros_like(z)
    return np.stack([np.stack([fx / z, zeros, -fx * x / z**2], axis=1),
                     np.stack([zeros, fy / z, -fy * y / z**2], axis=1)], axis=1)


def transform_points(pose: Array, points: Array) -> Array:
    """Apply a 4x4 pose to an (N, 3) array of points."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return points @ pose[:3, :3].T + pose[:3, 3]


def mount_pose(x_m: float = 0.0, y_m: float = 0.0, z_m: float = 0.0, yaw_deg: float = 0.0,
               pitch_down_deg: float = 0.0, roll_deg: float = 0.0) -> Array:
    """The 4x4 pose on the body of an OpenCV camera looking forward, then yawed left, pitched down and
    rolled (clockwise as seen from behind)."""
    base = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # camera axes in body axes
    yaw, pitch, roll = (math.radians(a) for a in (yaw_deg, pitch_down_deg, roll_deg))
    rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    ry = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0], [-math.sin(pitch), 0, math.cos(pitch)]])
    rx = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)], [0, math.sin(roll), math.cos(roll)]])
    pose = np.eye(4)
    pose[:3, :3] = rz @ ry @ rx @ base
    pose[:3, 3] = (x_m, y_m, z_m)
    return pose


# planar poses of the rear axle on the road: x forward, y left, yaw (the odometry frame)
Pose2D = tuple[float, float, float]


def pitched_mount(pose_body_cam: Array, pitch_down_deg: float) -> Array:
    """The mount turned about the camera's own horizontal axis, its view ``pitch_down_deg`` further down."""
    tilted = np.array(pose_body_cam, dtype=float)
    tilted[:3, :3] = tilted[:3, :3] @ Rotation.from_rotvec([-math.radians(pitch_down_deg), 0.0, 0.0]).as_matrix()
    return tilted


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


def vo_ground_pose(pose_world_cam: Array, pose_body_cam: Array) -> tuple[float, float, float]:
    """A camera pose in VO's world (the first camera) as the rear axle's planar ``x, y, yaw`` in the
    odometry frame; the first body pose is ``inverse(pose_body_cam)`` in that world."""
    relative = pose_body_cam @ pose_world_cam @ invert_pose(pose_body_cam)
    return float(relative[0, 3]), float(relative[1, 3]), math.atan2(relative[1, 0], relative[0, 0])


def planar_pose(x_m: float, y_m: float, yaw_rad: float) -> Array:
    """The 4x4 pose of a planar ``x, y, yaw`` (z up), such as a :data:`Pose2D` on the road."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    pose = np.eye(4)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:2, 3] = x_m, y_m
    return pose


def transform_points_2d(points: Array, x_m: float, y_m: float, yaw_rad: float) -> NDArray[np.float64]:
    """(M, 2) points in a frame at planar pose ``x_m, y_m, yaw_rad``, in the frame that pose is given in."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return np.column_stack([x_m + c * points[:, 0] - s * points[:, 1], y_m + s * points[:, 0] + c * points[:, 1]])


def arc_2d(speed_mps: float, yaw_rate_radps: float, dt_s: float) -> tuple[float, float, float]:
    """The planar motion ``(dx, dy, dyaw)``, in the frame it starts from, of ``dt_s`` at a constant speed along x
    and a constant yaw rate: an arc integrated exactly, a line when the yaw rate is 0 (negative ``dt_s``: the
    motion that led here)."""
    turn = yaw_rate_radps * dt_s
    if abs(turn) < 1e-9:
        return speed_mps * dt_s, 0.0, turn
    radius = speed_mps / yaw_rate_radps
    return radius * math.sin(turn), radius * (1.0 - math.cos(turn)), turn


def compose_2d(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """Planar pose ``a`` followed by the motion ``b`` expressed in ``a``'s frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.remainder(a[2] + b[2], math.tau)


def between_2d(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """The motion from planar pose ``a`` to ``b``, in ``a``'s frame (so ``compose_2d(a, between_2d(a, b)) == b``)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return c * dx + s * dy, -s * dx + c * dy, math.remainder(b[2] - a[2], math.tau)

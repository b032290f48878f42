"""A timestamped trajectory of 4x4 poses, read and written in KITTI and TUM formats.

KITTI: one line per pose, the 12 values of the top 3x4 of a camera-to-world
pose, row-major, no timestamps (``times.txt`` holds them separately).
TUM: ``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments allowed.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from kartpilot.core.errors import DataError
from kartpilot.core.files import is_torn_last_line, read_text_file, write_text_atomic
from kartpilot.core.geometry import Array, pose_from_quaternion, quaternion_xyzw_from_pose

__all__ = [
    "Trajectory",
    "TrajectoryFormat",
    "guess_format",
    "read_kitti_poses",
    "read_trajectory",
    "read_tum",
    "write_kitti_poses",
    "write_trajectory",
    "write_tum",
]

TrajectoryFormat = Literal["kitti", "tum"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Trajectory:
    """Poses ``T_world_cam`` (N, 4, 4) at times ``stamps_s`` (N,), seconds, strictly increasing."""

    stamps_s: Array
    poses: Array

    def __post_init__(self) -> None:
        if self.poses.ndim != 3 or self.poses.shape[1:] != (4, 4):
            raise DataError(f"poses must have shape (N, 4, 4), got {self.poses.shape}")
        if self.stamps_s.shape != (self.poses.shape[0],):
            raise DataError(
                f"{self.stamps_s.shape[0]} timestamps for {self.poses.shape[0]} poses"
            )
        if not np.all(np.isfinite(self.stamps_s)):
            raise DataError(f"timestamp of pose {int(np.argmin(np.isfinite(self.stamps_s)))} is not a number")
        back = np.flatnonzero(np.diff(self.stamps_s) <= 0)
        if len(back):  # every reader of poses with times builds one: the order of time is checked here, once
            k = int(back[0]) + 1
            raise DataError(f"timestamps go backwards or repeat at pose {k}: {self.stamps_s[k]:.9g} s after "
                            f"{self.stamps_s[k - 1]:.9g} s")

    @classmethod
    def from_poses(cls, poses: Sequence[Array] | Array, stamps_s: Sequence[float] | Array | None = None) -> Trajectory:
        stack = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        stamps = (np.arange(len(stack), dtype=np.float64) if stamps_s is None
                  else np.asarray(stamps_s, dtype=np.float64))
        return cls(stamps, stack)

    def __len__(self) -> int:
        return int(self.poses.shape[0])

    @property
    def positions(self) -> Array:
        """(N, 3) positions in metres."""
        return self.poses[:, :3, 3]

    @property
    def path_length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())

    def at(self, stamps_s: Array) -> Trajectory:
        """The poses at ``stamps_s``: positions interpolated linearly, rotations spherically; a stamp outside
        the trajectory's time span takes the nearest end's pose. The stamps must increase."""
        stamps = np.asarray(stamps_s, dtype=np.float64)
        if len(self) == 0:
            raise DataError("cannot interpolate an empty trajectory")
        if len(self) == 1:
            return Trajectory(stamps, np.repeat(self.poses, len(stamps), axis=0))
        if not np.all(np.diff(self.stamps_s) > 0):
            raise DataError("the trajectory's timestamps do not increase: it cannot be interpolated")
        clipped = np.clip(stamps, self.stamps_s[0], self.stamps_s[-1])
        poses = np.repeat(np.eye(4)[None], len(stamps), axis=0)
        poses[:, :3, :3] = Slerp(self.stamps_s, Rotation.from_matrix(self.poses[:, :3, :3]))(clipped).as_matrix()
        for axis in range(3):
            poses[:, axis, 3] = np.interp(clipped, self.stamps_s, self.poses[:, axis, 3])
        return Trajectory(stamps, poses)


def _row(text: str, columns: int, where: str) -> list[float]:
    parts = text.replace(",", " ").split()
    if len(parts) != columns:
        raise DataError(f"{where}: expected {columns} numbers, found {len(parts)}")
    try:
        values = [float(p) for p in parts]
    except ValueError as exc:
        raise DataError(f"{where}: not a number ({exc})") from None
    if not all(math.isfinite(v) for v in values):
        raise DataError(f"{where}: a value is not finite (NaN or infinity)")
    return values


def _read_rows(path: Path, columns: int) -> Array:
    if not path.is_file():
        raise DataError(f"trajectory file not found: {path}")
    rows = []
    content = read_text_file(path)
    lines = content.splitlines()
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        try:
            rows.append(_row(text, columns, f"{path}:{number}"))
        except DataError:
            if is_torn_last_line(content, number, len(lines)):
                log.warning("%s:%d: skipped the last line, cut off mid-write", path, number)
                continue
            raise
    if not rows:
        raise DataError(f"trajectory file {path} holds no poses")
    return np.asarray(rows, dtype=np.float64)


def read_kitti_poses(path: str | Path, stamps_s: Array | None = None) -> Trajectory:
    """Read a KITTI pose file; timestamps default to the frame index."""
    rows = _read_rows(Path(path), 12)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :4] = rows.reshape(-1, 3, 4)
    if stamps_s is not None and len(stamps_s) != len(rows):
        raise DataError(f"{path}: {len(rows)} poses but {len(stamps_s)} timestamps")
    rotations = poses[:, :3, :3]
    error = np.abs(np.einsum("nji,njk->nik", rotations, rotations) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((error > 1e-3) | (np.linalg.det(rotations) < 0))
    if len(bad):
        raise DataError(f"{path}: pose {int(bad[0])} (line {int(bad[0]) + 1}) is not a rotation and a translation "
                        f"(its 3x3 part is {error[bad[0]]:.3g} off orthonormal, or a mirror)")
    try:
        return Trajectory.from_poses(poses, stamps_s)
    except DataError as exc:
        raise DataError(f"{path}: {exc}") from None


def write_kitti_poses(path: str | Path, trajectory: Trajectory) -> None:
    lines = [" ".join(f"{v:.9e}" for v in pose[:3, :4].ravel()) for pose in trajectory.poses]
    write_text_atomic(path, "\n".join(lines) + "\n")


def read_tum(path: str | Path) -> Trajectory:
    rows = _read_rows(Path(path), 8)
    return _quaternion_trajectory(path, rows[:, 0].copy(), rows[:, 1:4], rows[:, 4:8],
                                  "a TUM line is: time tx ty tz qx qy qz qw")


def read_euroc_groundtruth(path: str | Path) -> Trajectory:
    """A EuRoC ground-truth CSV (``state_groundtruth_estimate0/data.csv``: ``#timestamp [ns], p_RS_R x y z [m],
    q_RS w x y z``, then nine velocity and bias columns): the body's poses in the world, stamped in seconds."""
    rows = _read_rows(Path(path), 17)
    return _quaternion_trajectory(path, rows[:, 0] * 1e-9, rows[:, 1:4], rows[:, [5, 6, 7, 4]],
                                  "a EuRoC line is: stamp_ns, px, py, pz, qw, qx, qy, qz, then velocity and biases")


def _quaternion_trajectory(path: str | Path, stamps_s: Array, positions: Array, quaternions_xyzw: Array,
                           line_format: str) -> Trajectory:
    """Poses from positions and unit quaternions (x, y, z, w) read from ``path``; a quaternion far from unit length
    or a stamp out of order is a DataError naming the file and ``line_format``."""
    norms = np.linalg.norm(quaternions_xyzw, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 0.1)
    if len(bad):
        raise DataError(f"{path}: pose {int(bad[0])} has a quaternion of length {norms[bad[0]]:.3g}, not a unit one "
                        f"({line_format})")
    poses = np.stack([pose_from_quaternion(q, t) for q, t in zip(quaternions_xyzw, positions, strict=True)])
    try:
        return Trajectory(stamps_s, poses)
    except DataError as exc:
        raise DataError(f"{path}: {exc}") from None


def write_tum(path: str | Path, trajectory: Trajectory) -> None:
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for stamp, pose in zip(trajectory.stamps_s, trajectory.poses, strict=True):
        quat = quaternion_xyzw_from_pose(pose)
        values = [*pose[:3, 3], *quat]
        lines.append(f"{stamp:.9f} " + " ".join(f"{v:.9f}" for v in values))
    write_text_atomic(path, "\n".join(lines) + "\n")


def guess_format(path: str | Path) -> TrajectoryFormat:
    """``tum`` for .tum/.csv files or 8-column text, else ``kitti``."""
    path = Path(path)
    if path.suffix.lower() in (".tum", ".csv"):
        return "tum"
    if path.is_file():
        for line in read_text_file(path).splitlines():
            if line.strip() and not line.startswith("#"):
                return "tum" if len(line.split()) == 8 else "kitti"
    return "kitti"


def read_trajectory(path: str | Path, fmt: TrajectoryFormat | None = None) -> Trajectory:
    fmt = fmt or guess_format(path)
    return read_tum(path) if fmt == "tum" else read_kitti_poses(path)


def write_trajectory(path: str | Path, trajectory: Trajectory, fmt: TrajectoryFormat | None = None) -> None:
    fmt = fmt or guess_format(path)
    (write_tum if fmt == "tum" else write_kitti_poses)(path, trajectory)

"""The KITTI odometry layout.

``ROOT/sequences/NN/{image_0,image_1}/NNNNNN.png`` (rectified grayscale left and
right), ``calib.txt`` (``P0:`` and ``P1:`` projection matrices), ``times.txt``
(seconds), and optionally ``ROOT/poses/NN.txt`` (left-camera poses, camera to
world of the first frame).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kartpilot.core.camera import StereoRig
from kartpilot.core.errors import CalibrationError, DataError
from kartpilot.core.files import read_text_file
from kartpilot.core.trajectory import Trajectory, read_kitti_poses
from kartpilot.core.types import StereoFrame
from kartpilot.sensors.base import StereoSource, read_gray

__all__ = ["KittiOdometrySource", "read_kitti_calib"]


def read_kitti_calib(path: Path) -> dict[str, np.ndarray]:
    """Parse ``calib.txt`` into named 3x4 matrices."""
    if not path.is_file():
        raise CalibrationError(f"calibration file not found: {path}")
    matrices: dict[str, np.ndarray] = {}
    for number, line in enumerate(read_text_file(path).splitlines(), start=1):
        if ":" not in line:
            continue
        key, values = line.split(":", 1)
        try:
            numbers = [float(v) for v in values.split()]
        except ValueError as exc:
            raise CalibrationError(f"{path}:{number}: not a number ({exc})") from exc
        if len(numbers) == 12:
            matrices[key.strip()] = np.asarray(numbers).reshape(3, 4)
    for key in ("P0", "P1"):
        if key not in matrices:
            raise CalibrationError(f"{path} has no {key}: line with 12 numbers")
    return matrices


def read_times(path: Path) -> np.ndarray:
    """A KITTI ``times.txt``: one time in seconds a line; blank lines and a header line (a first line that is not a
    number, as some exports write) are skipped; any other line that is not a finite number raises DataError naming
    the file and the line."""
    times = []
    for number, line in enumerate(read_text_file(path).splitlines(), 1):
        text = line.strip()
        if not text:
            continue
        try:
            value = float(text.split()[0])
        except ValueError:
            if number == 1:
                continue
            raise DataError(f"{path}, line {number}: {text[:40]!r} is not a time in seconds") from None
        if not np.isfinite(value):
            raise DataError(f"{path}, line {number}: {text[:40]!r} is not a finite time")
        times.append(value)
    return np.array(times, float)


class KittiOdometrySource(StereoSource):
    """Frames of one KITTI odometry sequence."""

    def __init__(self, root: str | Path, sequence: str | int) -> None:
        self.root = Path(root)
        self.sequence = f"{int(sequence):02d}" if str(sequence).isdigit() else str(sequence)
        self.name = f"kitti-{self.sequence}"
        sequence_dir = self.root / "sequences" / self.sequence
        if not self.root.is_dir():
            raise DataError(f"KITTI root not found: {self.root}")
        if not sequence_dir.is_dir():
            raise DataError(f"KITTI sequence {self.sequence} not found under {self.root / 'sequences'}")
        self._left = sorted((sequence_dir / "image_0").glob("*.png"))
        self._right = sorted((sequence_dir / "image_1").glob("*.png"))
        if not self._left:
            raise DataError(f"no frames in {sequence_dir / 'image_0'}")
        if [p.name for p in self._left] != [p.name for p in self._right]:
            raise DataError(f"image_0 and image_1 of {sequence_dir} do not hold the same frames")
        calib = read_kitti_calib(sequence_dir / "calib.txt")
        first = read_gray(self._left[0])
        self._rig = StereoRig.from_projections(calib["P0"], calib["P1"], (first.shape[1], first.shape[0]))
        times_path = sequence_dir / "times.txt"
        if times_path.is_file():
            times = read_times(times_path)
            if len(times) < len(self._left):
                raise DataError(f"{times_path} has {len(times)} times for {len(self._left)} frames")
            self._stamps_s = times[: len(self._left)]
        else:
            self._stamps_s = np.arange(len(self._left)) / 10.0
        self._poses_path = self.root / "poses" / f"{self.sequence}.txt"

    @property
    def rig(self) -> StereoRig:
        return self._rig

    def __len__(self) -> int:
        return len(self._left)

    def frame(self, index: int) -> StereoFrame:
        left = read_gray(self._left[index])
        right = read_gray(self._right[index])
        if left.shape != right.shape:
            raise DataError(f"frame {index}: left {left.shape} and right {right.shape} differ in size")
        return StereoFrame(index, round(self._stamps_s[index] * 1e9), left, right)

    def ground_truth(self) -> Trajectory | None:
        if not self._poses_path.is_file():
            return None
        trajectory = read_kitti_poses(self._poses_path)
        count = min(len(trajectory), len(self))
        return Trajectory(self._stamps_s[:count].copy(), trajectory.poses[:count])

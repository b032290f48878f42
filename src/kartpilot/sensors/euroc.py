"""The EuRoC MAV ASL layout.

``ROOT/mav0/cam{0,1}/{sensor.yaml,data.csv,data/<stamp_ns>.png}``. The images are
raw and distorted (radial-tangential); they are rectified with the maps computed
once from ``sensor.yaml`` (intrinsics, distortion, ``T_BS`` body-to-sensor).
Frames are paired by timestamp, keeping only stamps present in both cameras
with an existing file. Where the sequence has its ground truth
(``state_groundtruth_estimate0/data.csv``: the body's pose in the world), the
rectified left camera's poses follow from it through cam0's ``T_BS`` and the
rectification's rotation.

The rig is hand-held or flown, not on a ground vehicle: its camera has no
mount, and nothing that assumes a level ground vehicle (stereo VO's attitude
prior) applies to it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from kartpilot.calibration.rectify import StereoRectification, rectify_stereo
from kartpilot.core.camera import PinholeCamera, StereoRig
from kartpilot.core.errors import CalibrationError, DataError
from kartpilot.core.files import parse_yaml, read_text_file
from kartpilot.core.geometry import invert_pose
from kartpilot.core.trajectory import Trajectory, read_euroc_groundtruth
from kartpilot.core.types import StereoFrame
from kartpilot.sensors.base import StereoSource, read_gray

__all__ = ["EurocSource", "read_euroc_camera"]


def _load_opencv_yaml(path: Path) -> dict[str, Any]:
    if not path.exists():  # a folder or a pipe is said by the text reader's own check
        raise CalibrationError(f"camera calibration not found: {path}")
    text = "\n".join(line for line in read_text_file(path).splitlines() if not line.startswith("%YAML"))
    try:
        data = parse_yaml(text, path)
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{path} is not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise CalibrationError(f"{path} does not hold a mapping")
    return data


def read_euroc_camera(path: Path) -> tuple[PinholeCamera, np.ndarray]:
    """Read a EuRoC ``sensor.yaml``: the camera and its 4x4 body-from-sensor pose."""
    data = _load_opencv_yaml(path)
    try:
        fu, fv, cu, cv = (float(v) for v in data["intrinsics"])
        width, height = (int(v) for v in data["resolution"])
        distortion = tuple(float(v) for v in data.get("distortion_coefficients", ()))
        pose = np.asarray(data["T_BS"]["data"], dtype=np.float64).reshape(4, 4)
    except (KeyError, TypeError, ValueError) as exc:
        raise CalibrationError(f"{path}: missing or malformed field ({exc})") from exc
    model = data.get("distortion_model", "radial-tangential")
    if model not in ("radial-tangential", "radtan", "none"):
        raise CalibrationError(f"{path}: unsupported distortion model {model!r}")
    return PinholeCamera(fu, fv, cu, cv, width, height, distortion), pose


def _read_stamps(csv_path: Path) -> dict[int, Path]:
    """The frame list ``stamp_ns,file``: stamps are integers and strictly increasing (a repeat or a step back
    is a broken list, refused with its line: sorting it would pair the wrong images)."""
    if not csv_path.is_file():
        raise DataError(f"frame list not found: {csv_path}")
    frames: dict[int, Path] = {}
    last: int | None = None
    for number, line in enumerate(read_text_file(csv_path).splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        text, _, name = line.partition(",")
        try:
            stamp = int(text.strip())
        except ValueError:
            raise DataError(f"{csv_path}, line {number}: the stamp {text.strip()!r} is not whole nanoseconds"
                            ) from None
        if last is not None and stamp <= last:
            raise DataError(f"{csv_path}, line {number}: stamp {stamp} {'repeats' if stamp == last else 'goes back'}"
                            f" (the previous one is {last}); the frames must be in time order")
        last = stamp
        path = csv_path.parent / "data" / name.strip()
        if path.is_file():
            frames[stamp] = path
    return frames


class EurocSource(StereoSource):
    """Rectified stereo frames of one EuRoC sequence."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        mav = self.root / "mav0" if (self.root / "mav0").is_dir() else self.root
        if not (mav / "cam0").is_dir() or not (mav / "cam1").is_dir():
            raise DataError(f"no EuRoC cam0/cam1 folders under {self.root}")
        self.name = f"euroc-{self.root.name}"
        left_cam, body_left = read_euroc_camera(mav / "cam0" / "sensor.yaml")
        right_cam, body_right = read_euroc_camera(mav / "cam1" / "sensor.yaml")
        pose_right_left = invert_pose(body_right) @ body_left
        self.rectification: StereoRectification = rectify_stereo(left_cam, right_cam, pose_right_left)
        rect_raw = np.eye(4)
        rect_raw[:3, :3] = self.rectification.rotation_rect_left.T  # the rectified axes in the raw camera's frame
        self._body_rect = body_left @ rect_raw  # the rectified left camera in the body (IMU) frame
        self._truth_path = mav / "state_groundtruth_estimate0" / "data.csv"
        left_frames = _read_stamps(mav / "cam0" / "data.csv")
        right_frames = _read_stamps(mav / "cam1" / "data.csv")
        self._stamps = sorted(set(left_frames) & set(right_frames))
        if not self._stamps:
            raise DataError(f"no stereo frames with images in both cameras under {mav}")
        self._left = [left_frames[s] for s in self._stamps]
        self._right = [right_frames[s] for s in self._stamps]

    @property
    def rig(self) -> StereoRig:
        return self.rectification.rig

    def __len__(self) -> int:
        return len(self._stamps)

    def frame(self, index: int) -> StereoFrame:
        left, right = self.rectification.rectify(read_gray(self._left[index]), read_gray(self._right[index]))
        return StereoFrame(index, self._stamps[index], left, right)

    def ground_truth(self) -> Trajectory | None:
        """The rectified left camera's poses at the frames' stamps, in the first frame's camera frame (as KITTI's
        are), from the body's ground truth: interpolated between its samples (200 Hz in EuRoC), positions
        linearly and rotations spherically. Frames outside the truth's time span are left out; None where the
        sequence has no ground truth."""
        if not self._truth_path.is_file():
            return None
        body = read_euroc_groundtruth(self._truth_path)
        stamps_s = np.array(self._stamps, dtype=np.float64) * 1e-9
        inside = (stamps_s >= body.stamps_s[0] - _TRUTH_SLACK_S) & (stamps_s <= body.stamps_s[-1] + _TRUTH_SLACK_S)
        if inside.sum() < 2:
            raise DataError(f"{self._truth_path}: its {len(body)} poses span {body.stamps_s[0]:.3f} to "
                            f"{body.stamps_s[-1]:.3f} s, and hold fewer than two of the frames' stamps")
        cameras = body.at(stamps_s[inside]).poses @ self._body_rect
        return Trajectory(stamps_s[inside], invert_pose(cameras[0]) @ cameras)


_TRUTH_SLACK_S = 0.005
"""A frame this close outside the ground truth's span takes its nearest end's pose (EuRoC's truth runs at 200 Hz)."""

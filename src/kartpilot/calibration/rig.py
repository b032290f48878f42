"""Rig files: every camera's calibration and pose on the kart, in one YAML file.

A rig file is calibration, not algorithm parameters; everything that consumes images
takes its cameras from here. Example::

    cameras:
      left:
        width_px: 960
        height_px: 540
        fx_px: 743.0
        fy_px: 743.0
        cx_px: 479.5
        cy_px: 269.5
        distortion: [-0.1, 0.02, 0.0, 0.0, 0.0]
        mount: {x_m: 0.40, y_m: 0.07, z_m: 0.19, yaw_deg: 0.0, pitch_down_deg: 0.0}
        capture: {device: /dev/video0, fps: 30, exposure: 150, fourcc: MJPG}
      right: {...}
    stereo_pair: [left, right]

A camera's pose on the body (x forward, y left, z up, at the rear axle) is either a
``mount`` (position and yaw left / pitch down, as a person measures it) or the full
4x4 ``pose_body_cam``. Calibrated stereo extrinsics are written as ``pose_body_cam``
so that the measured relative pose is kept exactly. ``capture`` (optional) says how
to open the live camera (:class:`~kartpilot.core.camera.CaptureSettings`); its
resolution is the calibration's.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from kartpilot.core.camera import CaptureSettings, PinholeCamera
from kartpilot.core.errors import CalibrationError
from kartpilot.core.geometry import Array

__all__ = ["Rig", "load_rig", "mount_pose", "save_rig"]

CAMERA_KEYS = {"width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px", "distortion", "mount", "pose_body_cam",
               "capture"}
CAPTURE_KEYS = {"device", "fps", "exposure", "fourcc"}
MOUNT_KEYS = {"x_m", "y_m", "z_m", "yaw_deg", "pitch_down_deg", "roll_deg"}


@dataclass(frozen=True)
class Rig:
    """The cameras by name, which two (if any) form the stereo pair (left first), and how to open
    each live camera (for the cameras whose rig file says)."""

    cameras: dict[str, PinholeCamera]
    stereo_pair: tuple[str, str] | None = None
    capture: dict[str, CaptureSettings] = field(default_factory=dict)

    def camera(self, name: str) -> PinholeCamera:
        if name not in self.cameras:
            raise CalibrationError(f"the rig has no camera {name!r} (it has {', '.join(self.cameras)})")
        return self.cameras[name]


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


def _check_mapping(data: Any, where: str, known: set[str], required: frozenset[str] | set[str] = frozenset()
                   ) -> dict[str, Any]:
    """``data`` as a mapping with only ``known`` keys and every ``required`` one; errors name the place."""
    if not isinstance(data, dict):
        raise CalibrationError(f"{where} must be a mapping")
    unknown = set(data) - known
    if unknown:
        raise CalibrationError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    missing = required - set(data)
    if missing:
        raise CalibrationError(f"{where}: missing {', '.join(sorted(missing))}")
    return data


def _camera_from_yaml(name: str, data: Any, source: Path) -> PinholeCamera:
    where = f"{source}: cameras.{name}"
    data = _check_mapping(data, where, CAMERA_KEYS, {"width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px"})
    if "mount" in data and "pose_body_cam" in data:
        raise CalibrationError(f"{where}: give either mount or pose_body_cam, not both")
    try:
        if "pose_body_cam" in data:
            pose = np.asarray(data["pose_body_cam"], float)
            if pose.shape != (4, 4) or not np.allclose(pose[3], [0, 0, 0, 1]):
                raise CalibrationError(f"{where}.pose_body_cam must be a 4x4 rigid transform")
            if not np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-5):
                raise CalibrationError(f"{where}.pose_body_cam: the rotation is not orthonormal")
        else:
            mount = _check_mapping(data.get("mount") or {}, f"{where}.mount", MOUNT_KEYS)
            pose = mount_pose(**{k: float(v) for k, v in mount.items()})
        return PinholeCamera(float(data["fx_px"]), float(data["fy_px"]), float(data["cx_px"]), float(data["cy_px"]),
                             int(data["width_px"]), int(data["height_px"]),
                             tuple(float(d) for d in data.get("distortion") or ()),
                             tuple(tuple(float(v) for v in row) for row in pose))
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: {exc}") from exc


def _capture_from_yaml(name: str, data: Any, source: Path) -> CaptureSettings:
    where = f"{source}: cameras.{name}.capture"
    data = _check_mapping(data, where, CAPTURE_KEYS, {"device"})
    try:
        exposure = data.get("exposure")
        return CaptureSettings(str(data["device"]), float(data.get("fps", 30.0)),
                               None if exposure is None else float(exposure), str(data.get("fourcc", "MJPG")))
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: {exc}") from exc


def load_rig(path: str | Path) -> Rig:
    """Read and check a rig file."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: no such rig file")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{path}: not valid YAML ({exc})") from exc
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), dict) or not data["cameras"]:
        raise CalibrationError(f"{path}: a rig file needs a 'cameras' mapping with at least one camera")
    _check_mapping(data, str(path), {"cameras", "stereo_pair"})
    cameras = {str(name): _camera_from_yaml(str(name), cam, path) for name, cam in data["cameras"].items()}
    pair = data.get("stereo_pair")
    if pair is not None:
        if not (isinstance(pair, list) and len(pair) == 2 and all(p in cameras for p in pair)):
            raise CalibrationError(f"{path}: stereo_pair must name two of the cameras ({', '.join(cameras)})")
        left, right = cameras[pair[0]], cameras[pair[1]]
        if left.size_wh != right.size_wh:
            raise CalibrationError(f"{path}: the stereo pair's cameras differ in size")
    capture = {str(name): _capture_from_yaml(str(name), cam["capture"], path)
               for name, cam in data["cameras"].items() if isinstance(cam, dict) and "capture" in cam}
    return Rig(cameras, (str(pair[0]), str(pair[1])) if pair else None, capture)


def save_rig(rig: Rig, path: str | Path) -> Path:
    """Write a rig file (poses as 4x4 ``pose_body_cam``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cameras = {}
    for name, cam in rig.cameras.items():
        cameras[name] = {
            "width_px": cam.width_px, "height_px": cam.height_px,
            "fx_px": round(float(cam.fx_px), 4), "fy_px": round(float(cam.fy_px), 4),
            "cx_px": round(float(cam.cx_px), 4), "cy_px": round(float(cam.cy_px), 4),
            "distortion": [round(float(d), 8) for d in cam.distortion],  # plain floats, also from NumPy
            "pose_body_cam": [[round(float(v), 8) for v in row] for row in cam.pose_body_cam],
        }
        if name in rig.capture:
            cameras[name]["capture"] = asdict(rig.capture[name])
    data: dict[str, Any] = {"cameras": cameras}
    if rig.stereo_pair:
        data["stereo_pair"] = list(rig.stereo_pair)
    path.write_text(yaml.safe_dump(data, sort_keys=False, default_flow_style=None))
    return path

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
        body_mask: [[[0.0, 0.8], [1.0, 0.8], [1.0, 1.0], [0.0, 1.0]]]
      right: {...}
    stereo_pair: [left, right]
    steering: {value_sign: -1, rad_per_value: 0.31, counts_per_value: -598.2, count_offset: 3.5}
    camera_maps: [kart1.json, kart2.json]

A camera's pose on the body (x forward, y left, z up, at the rear axle) is either a
``mount`` (position and yaw left / pitch down, as a person measures it) or the full
4x4 ``pose_body_cam``. Calibrated stereo extrinsics are written as ``pose_body_cam``
so that the measured relative pose is kept exactly. ``capture`` (optional) says how
to open the live camera (:class:`~kartpilot.core.camera.CaptureSettings`); its
resolution is the calibration's.

``body_mask`` (optional) lists polygons of the kart's own body in a camera's view, corners as fractions of the
width and height (``kartpilot calibrate ground`` finds them; they may be drawn by hand): detectors leave them out.

``steering`` (optional) is the kart's steering calibration as ``kartpilot calibrate steering`` wrote
it (:class:`~kartpilot.core.vehicle.SteeringCalibration`); it overrides the vehicle's default.
``lidar`` (optional) is the kart's planar LiDAR: its ``mount`` (``x_m``, ``y_m``, ``z_m`` of its scan plane above the
road, ``yaw_deg`` left) and its ``device`` (an RPLIDAR's settings, :class:`kartpilot.sensors.lidar.RplidarConfig`:
``port``, ``baudrate``, ``scan_mode``, ``motor_pwm``, ``step_deg``, ...; checked by name when a drive opens it)::

    lidar:
      mount: {x_m: 1.45, y_m: 0.0, z_m: 0.30, yaw_deg: 0.0}
      device: {port: /dev/ttyUSB0, baudrate: 115200}

``camera_maps`` (optional) lists the Self Driving Challenge organiser's camera-mapping files, relative
to the rig file: each maps ``front``, ``left`` and ``right`` to a ``/dev/v4l/by-path/...`` device, and
the first whose paths all exist on this machine says which device each camera is (``front`` is our
``center``), since a team may get another kart on the day. They are applied when the cameras are
opened (:func:`apply_camera_maps`), not when the file is read, so a rig file written back keeps them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from kartpilot.core.camera import CaptureSettings, PinholeCamera, body_mask_from_data
from kartpilot.core.config import config_to_dict, merge_config
from kartpilot.core.errors import CalibrationError, ConfigError, DataError
from kartpilot.core.files import parse_yaml, read_json_file, read_text_file, write_text_atomic
from kartpilot.core.geometry import mount_pose
from kartpilot.core.types import LidarMount
from kartpilot.core.vehicle import SteeringCalibration

__all__ = ["ORGANISER_CAMERA_NAMES", "Rig", "apply_camera_maps", "load_rig", "save_rig"]

ORGANISER_CAMERA_NAMES = {"front": "center", "left": "left", "right": "right"}

CAMERA_KEYS = {"width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px", "distortion", "mount", "pose_body_cam",
               "capture", "body_mask"}
CAPTURE_KEYS = {"device", "fps", "exposure", "fourcc"}
MOUNT_KEYS = {"x_m", "y_m", "z_m", "yaw_deg", "pitch_down_deg", "roll_deg"}
LIDAR_KEYS = {"mount", "device"}
LIDAR_MOUNT_KEYS = {"x_m", "y_m", "z_m", "yaw_deg"}


@dataclass(frozen=True)
class Rig:
    """The cameras by name, which two (if any) form the stereo pair (left first), and how to open
    each live camera (for the cameras whose rig file says)."""

    cameras: dict[str, PinholeCamera]
    stereo_pair: tuple[str, str] | None = None
    capture: dict[str, CaptureSettings] = field(default_factory=dict)
    steering: SteeringCalibration | None = None
    camera_maps: tuple[str, ...] = ()
    lidar: LidarMount | None = None
    lidar_device: dict[str, Any] = field(default_factory=dict)

    def camera(self, name: str) -> PinholeCamera:
        if name not in self.cameras:
            raise CalibrationError(f"the rig has no camera {name!r} (it has {', '.join(self.cameras)})")
        return self.cameras[name]


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
                             tuple(tuple(float(v) for v in row) for row in pose),
                             _body_mask(data, where))
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: {exc}") from exc


def _body_mask(data: dict[str, Any], where: str) -> tuple[tuple[tuple[float, float], ...], ...]:
    try:
        mask = body_mask_from_data(data.get("body_mask") or ())
        PinholeCamera(1.0, 1.0, 0.0, 0.0, 1, 1, body_mask=mask)  # the camera's own check of the polygons
    except CalibrationError as exc:
        raise CalibrationError(f"{where}.body_mask: {exc}") from exc
    return mask


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
    if not path.exists():  # a folder or a pipe is said by the text reader's own check
        raise CalibrationError(f"{path}: no such rig file")
    try:
        data = parse_yaml(read_text_file(path), path)
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{path}: not valid YAML ({exc})") from exc
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), dict) or not data["cameras"]:
        raise CalibrationError(f"{path}: a rig file needs a 'cameras' mapping with at least one camera")
    _check_mapping(data, str(path), {"cameras", "stereo_pair", "steering", "camera_maps", "lidar"})
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
    steering = None
    if data.get("steering") is not None:
        try:
            steering = merge_config(SteeringCalibration(), data["steering"], "steering")
        except ConfigError as exc:
            raise CalibrationError(f"{path}: {exc}") from exc
    maps = data.get("camera_maps") or []
    if not isinstance(maps, list) or not all(isinstance(m, str) for m in maps):
        raise CalibrationError(f"{path}: camera_maps must be a list of file names")
    lidar, device = _lidar_from_yaml(data.get("lidar"), path)
    return Rig(cameras, (str(pair[0]), str(pair[1])) if pair else None, capture, steering,
               tuple(str(path.parent / m) for m in maps), lidar, device)


def _lidar_from_yaml(data: Any, source: Path) -> tuple[LidarMount | None, dict[str, Any]]:
    """The rig file's ``lidar``: its mount, and its device's settings as given (checked when it is opened)."""
    if data is None:
        return None, {}
    where = f"{source}: lidar"
    data = _check_mapping(data, where, LIDAR_KEYS, {"mount"})
    mount = _check_mapping(data["mount"], f"{where}.mount", LIDAR_MOUNT_KEYS, {"x_m", "y_m", "z_m"})
    device = data.get("device") or {}
    if not isinstance(device, dict):
        raise CalibrationError(f"{where}.device must be a mapping (port, baudrate, ...)")
    try:
        return LidarMount(float(mount["x_m"]), float(mount["y_m"]), float(mount["z_m"]),
                          float(np.radians(float(mount.get("yaw_deg", 0.0))))), dict(device)
    except (TypeError, ValueError, ConfigError) as exc:
        raise CalibrationError(f"{where}.mount: {exc}") from None


def _read_camera_map(path: Path) -> dict[str, str]:
    """One organiser camera-mapping file: our camera name -> device path."""
    try:
        data = read_json_file(path)
    except DataError as exc:
        raise CalibrationError(f"camera map: {exc}") from None
    if not isinstance(data, dict) or not data or not all(isinstance(v, str) for v in data.values()):
        raise CalibrationError(f"camera map {path}: expected an object mapping front, left, right to device paths")
    unknown = set(data) - set(ORGANISER_CAMERA_NAMES)
    if unknown:
        raise CalibrationError(f"camera map {path}: unknown camera(s) {', '.join(sorted(unknown))} "
                               f"({', '.join(ORGANISER_CAMERA_NAMES)})")
    return {ORGANISER_CAMERA_NAMES[k]: v for k, v in data.items()}


def apply_camera_maps(rig: Rig, paths: Sequence[str | Path] = ()) -> Rig:
    """The rig with each camera's device from the first organiser camera map whose paths all exist
    (``paths``, or else the rig file's ``camera_maps``; with neither, the rig as it is).

    Only the rig's own cameras are mapped (a camera needs its calibration); the capture settings the rig
    gives (fps, exposure) are kept. When no file fits, the error names each file and its missing paths.
    """
    paths = paths or rig.camera_maps
    if not paths:
        return rig
    misses = []
    for path in (Path(p) for p in paths):
        if not path.is_file():
            misses.append(f"{path}: no such file")
            continue
        mapping = {name: device for name, device in _read_camera_map(path).items() if name in rig.cameras}
        if not mapping:
            misses.append(f"{path}: maps none of the rig's cameras ({', '.join(rig.cameras)})")
            continue
        missing = [device for device in mapping.values() if not Path(device).exists()]
        if missing:
            misses.append(f"{path}: missing {', '.join(missing)}")
            continue
        capture = dict(rig.capture)
        for name, device in mapping.items():
            capture[name] = replace(capture[name], device=device) if name in capture else CaptureSettings(device)
        return replace(rig, capture=capture)
    raise CalibrationError("no camera map fits this kart: " + "; ".join(misses))


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
        if cam.body_mask:
            cameras[name]["body_mask"] = [[[round(x, 5), round(y, 5)] for x, y in polygon] for polygon in cam.body_mask]
        if name in rig.capture:
            cameras[name]["capture"] = asdict(rig.capture[name])
    data: dict[str, Any] = {"cameras": cameras}
    if rig.stereo_pair:
        data["stereo_pair"] = list(rig.stereo_pair)
    if rig.steering is not None:
        data["steering"] = config_to_dict(rig.steering)
    if rig.lidar is not None:
        m = rig.lidar
        data["lidar"] = {"mount": {"x_m": m.x_m, "y_m": m.y_m, "z_m": m.z_m,
                                   "yaw_deg": round(float(np.degrees(m.yaw_rad)), 6)}}
        if rig.lidar_device:
            data["lidar"]["device"] = dict(rig.lidar_device)
    if rig.camera_maps:
        data["camera_maps"] = [str(Path(m).relative_to(path.parent)) if Path(m).is_relative_to(path.parent) else m
                               for m in rig.camera_maps]
    return write_text_atomic(path, yaml.safe_dump(data, sort_keys=False, default_flow_style=None))

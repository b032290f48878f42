"""ROS bags in and out of the recording format, read and written with rosbags (no ROS installation needed).

Import (:func:`import_bag`, ROS 1 ``.bag`` or a ROS 2 bag folder):

* an image (``sensor_msgs/Image``: mono8, bgr8, rgb8, bgra8, rgba8) or compressed-image topic with its
  ``camera_info`` becomes a camera. Its name is the topic's last part that is not an image word
  (``/stereo/left/image_raw`` gives ``left``), its info topic the sibling ``camera_info``, and its pose on the
  kart the chain of ``/tf_static`` (or ``/tf``) transforms from ``base_link`` to the image's frame. Without
  them, a stereo pair's baseline comes from the right camera's projection matrix (ROS's stereo convention).
* Twist (``linear.x`` and ``angular.z``, steer through the wheelbase) or Ackermann commands become commands:
  the speed over the vehicle's top speed is the throttle. The raw values are kept as the ``ros_command``
  output.
* An odometry or pose topic becomes the ground truth (the pose of ``base_link``, or of a camera's frame,
  moved onto the reference camera through the mounts).
* A ``sensor_msgs/LaserScan`` topic becomes a LiDAR (named from its topic: ``/lidar/scan`` gives ``lidar``, a bare
  ``/scan`` too), its mount the transform chain from ``base_link`` to the scan's frame (its position and its turn
  about the vertical; without one, at the kart's origin 0.3 m up, with a note). A range that is not finite or lies
  outside the scan's own window is no return.
* Topics and types it cannot map are listed with the reason, never guessed. A topic map (:class:`BagImportConfig`,
  YAML) names what to take where the topics are not the usual ones.

Time: every frame's time is its header's stamp, to the nanosecond. The reference camera (the stereo pair's
left, else the first) sets the recording's sets; another camera's frame joins the set within
``sync_tolerance_ms`` of it and keeps its own stamp as the capture time.

Export (:func:`export_ros2_bag`): each camera's images as ``/<camera>/image_raw/compressed`` (the recording's own
PNG or JPEG bytes) with ``/<camera>/camera_info``, stamped with the set's time (the bag's log time is the
camera's own capture time), the mounts on ``/tf_static``, the ground truth as ``nav_msgs/Odometry`` of
``base_link`` in ``world``, the commands as ``ackermann_msgs/AckermannDriveStamped`` and each LiDAR's sweeps as
``/<lidar>/scan`` (``sensor_msgs/LaserScan``, no return as +inf, REP 117's "nothing within range"). CAN traffic and the
pipeline's outputs are not carried (the MCAP export has them). Both directions write whole or nothing.
"""

from __future__ import annotations

import math
import os
import re
import shutil
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Rosbag1Error
from rosbags.rosbag2 import ReaderError as Rosbag2Error
from rosbags.rosbag2 import Writer
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from kartpilot.core.camera import DISTORTION_COUNTS, PinholeCamera
from kartpilot.core.errors import CalibrationError, DataError, KartpilotError
from kartpilot.core.files import read_file_bytes
from kartpilot.core.geometry import Array, invert_pose, mount_pose, pose_from_quaternion, quaternion_xyzw_from_pose
from kartpilot.core.images import decode_image as decode_encoded
from kartpilot.core.trajectory import Trajectory
from kartpilot.core.types import ActuatorCommand, Image, LaserScan, LidarMount
from kartpilot.core.vehicle import VehicleParams
from kartpilot.record.recording import RecordingReader, RecordingWriter

__all__ = ["BagCamera", "BagImport", "BagImportConfig", "camera_name", "decode_image", "export_ros2_bag", "import_bag",
           "info_topic", "lidar_name", "match_sets", "scan_from_message"]

IMAGE, COMPRESSED, INFO = "sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo"
TWIST, TWIST_STAMPED = "geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"
ACKERMANN, ACKERMANN_STAMPED = "ackermann_msgs/msg/AckermannDrive", "ackermann_msgs/msg/AckermannDriveStamped"
ODOMETRY, POSE_STAMPED = "nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped"
POSE_COVARIANCE = "geometry_msgs/msg/PoseWithCovarianceStamped"
TF = "tf2_msgs/msg/TFMessage"
LASER_SCAN = "sensor_msgs/msg/LaserScan"
COMMAND_TYPES = (TWIST, TWIST_STAMPED, ACKERMANN, ACKERMANN_STAMPED)
POSE_TYPES = (ODOMETRY, POSE_STAMPED, POSE_COVARIANCE)
_IMAGE_WORDS = {"image", "image_raw", "image_rect", "image_rect_color", "image_color", "image_mono",
                "image_rect_raw", "compressed"}
_ENCODINGS = {"mono8": None, "8uc1": None, "bgr8": None, "8uc3": None, "rgb8": cv2.COLOR_RGB2BGR,
              "bgra8": cv2.COLOR_BGRA2BGR, "rgba8": cv2.COLOR_RGBA2BGR}
# ackermann_msgs is not in the core message sets; its two public definitions are registered from their text
_ACKERMANN_MSGS = {
    ACKERMANN: "float32 steering_angle\nfloat32 steering_angle_velocity\nfloat32 speed\nfloat32 acceleration\n"
               "float32 jerk\n",
    ACKERMANN_STAMPED: "std_msgs/Header header\nackermann_msgs/AckermannDrive drive\n",
}


@dataclass(frozen=True)
class BagCamera:
    """One camera to take from a bag: its name in the recording, its image (or compressed image) topic, and
    its camera-info topic ("": the image topic's sibling ``camera_info``)."""

    name: str = ""
    image: str = ""
    info: str = ""


@dataclass(frozen=True)
class BagImportConfig:
    """The topic map of :func:`import_bag` (YAML: ``kartpilot recordings import-bag --topics``).

    Attributes:
        cameras: the cameras to take; empty: every image topic with a camera info, named from its topic.
        stereo_pair: the left and right camera's names; empty: ``left`` and ``right`` when both are there.
        commands: the command topic (Twist or Ackermann); "": the only one, if there is one.
        groundtruth: the odometry or pose topic; "": the only one, if there is one.
        base_frame: the kart's frame, from which the cameras' transforms are chained.
        sync_tolerance_ms: how far another camera's frame may be from the reference camera's to join its set.
    """

    cameras: tuple[BagCamera, ...] = ()
    stereo_pair: tuple[str, ...] = ()
    commands: str = ""
    groundtruth: str = ""
    base_frame: str = "base_link"
    sync_tolerance_ms: float = 5.0

    def __post_init__(self) -> None:
        if len(self.stereo_pair) not in (0, 2):
            raise ValueError(f"stereo_pair names two cameras, not {len(self.stereo_pair)}")
        if not 0 <= self.sync_tolerance_ms <= 1000:
            raise ValueError(f"sync_tolerance_ms is out of range ({self.sync_tolerance_ms!r})")
        for camera in self.cameras:
            if not re.fullmatch(r"[a-z][a-z0-9_]*", camera.name) or not camera.image:
                raise ValueError(f"a camera needs a name (lower-case letters, digits, _) and an image topic: {camera}")


@dataclass(frozen=True)
class BagImport:
    """What an import made: frames per camera, the commands and ground-truth poses, frames that joined no set,
    and the bag's topics it did not map (topic, type, reason)."""

    frames: dict[str, int]
    commands: int
    groundtruth_poses: int
    unsynchronised: dict[str, int]
    unmapped: tuple[tuple[str, str, str], ...]
    notes: tuple[str, ...] = field(default=())
    scans: dict[str, int] = field(default_factory=dict)


def _typestore() -> Typestore:
    store = get_typestore(Stores.ROS2_HUMBLE)
    for name, text in _ACKERMANN_MSGS.items():
        store.register(get_types_from_msg(text, name))
    return store


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def camera_name(topic: str) -> str:
    """The camera a topic names: its last part that is not an image word, in lower case."""
    parts = [p for p in topic.split("/") if p]
    while parts and parts[-1].lower() in _IMAGE_WORDS:
        parts.pop()
    name = re.sub(r"[^a-z0-9_]", "_", (parts[-1] if parts else "camera").lower())
    return name if name[:1].isalpha() else f"camera_{name}"


def info_topic(image_topic: str) -> str:
    """The camera-info topic beside an image topic (``/ns/cam/image_raw[/compressed]`` gives
    ``/ns/cam/camera_info``)."""
    parts = [p for p in image_topic.split("/") if p]
    while parts and parts[-1].lower() in _IMAGE_WORDS:
        parts.pop()
    return "/" + "/".join([*parts, "camera_info"])


def decode_image(msg: Any, msgtype: str) -> Image:
    """The BGR (or grey) pixels of an image or compressed-image message; DataError when they cannot be read."""
    if msgtype == COMPRESSED:
        data = np.asarray(msg.data, dtype=np.uint8)
        image = decode_encoded(data, f"a compressed image ({msg.format!r})", cv2.IMREAD_UNCHANGED)
        if image.dtype != np.uint8:
            raise DataError(f"a compressed image of {image.dtype} pixels: only 8-bit images are cameras here")
        return image if image.ndim == 2 or image.shape[2] == 3 else cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    encoding = str(msg.encoding).lower()
    if encoding not in _ENCODINGS:
        raise DataError(f"image encoding {msg.encoding!r} (known: {', '.join(_ENCODINGS)})")
    channels = 1 if encoding in ("mono8", "8uc1") else 4 if encoding.endswith("a8") else 3
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if width <= 0 or height <= 0 or step < width * channels or data.size < height * step:
        raise DataError(f"a {width}x{height} {encoding} image with step {step} and {data.size} bytes")
    rows = data[:height * step].reshape(height, step)[:, :width * channels]
    image = rows.reshape(height, width, channels) if channels > 1 else rows.reshape(height, width)
    conversion = _ENCODINGS[encoding]
    return np.ascontiguousarray(image if conversion is None else cv2.cvtColor(image, conversion))


def _matrix(msg: Any, name: str) -> Any:
    """A CameraInfo's ``d``, ``k``, ``r`` or ``p``: ROS 1 spells them in capitals."""
    return getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper())


def camera_from_info(msg: Any, pose_body_cam: Array) -> PinholeCamera:
    """A camera from a ``CameraInfo``: K, and D when the model is plumb_bob or rational_polynomial."""
    model = str(msg.distortion_model)
    distortion = tuple(float(v) for v in _matrix(msg, "d"))
    if not any(distortion):
        distortion = ()
    elif model not in ("plumb_bob", "rational_polynomial") or len(distortion) not in DISTORTION_COUNTS:
        raise CalibrationError(f"distortion model {model!r} with {len(distortion)} values is not OpenCV's pinhole "
                               "model (plumb_bob, rational_polynomial)")
    k = np.asarray(_matrix(msg, "k"), dtype=np.float64).reshape(3, 3)
    return PinholeCamera.from_matrix(k, (int(msg.width), int(msg.height)), distortion).on_body(pose_body_cam)


def _pose(position: Any, orientation: Any) -> Array:
    return pose_from_quaternion(np.array([orientation.x, orientation.y, orientation.z, orientation.w]),
                                np.array([position.x, position.y, position.z]))


def _chain(transforms: dict[str, tuple[str, Array]], base: str, frame: str) -> Array | None:
    """The pose of ``frame`` in ``base`` through the child-to-parent transforms, or None when not connected."""
    pose, current, seen = np.eye(4), frame, set()
    while current != base:
        if current not in transforms or current in seen:
            return None
        seen.add(current)
        parent, relative = transforms[current]
        pose = relative @ pose
        current = parent
    return pose


@dataclass
class _Topic:
    topic: str
    msgtype: str
    count: int


def _pick(kind: str, wanted: str, topics: dict[str, _Topic], types: tuple[str, ...]) -> str:
    if wanted:
        if wanted not in topics:
            raise DataError(f"the bag has no {kind} topic {wanted!r}")
        if topics[wanted].msgtype not in types:
            raise DataError(f"{kind} topic {wanted} is {topics[wanted].msgtype}, not one of {', '.join(types)}")
        return wanted
    found = [t for t in topics.values() if t.msgtype in types]
    return found[0].topic if len(found) == 1 else ""


def _messages(reader: AnyReader, topics: list[str]) -> Iterator[tuple[str, str, int, Any]]:
    connections = [c for c in reader.connections if c.topic in topics]
    if not connections:  # rosbags reads every connection when given none
        return
    for connection, log_ns, raw in reader.messages(connections=connections):
        yield connection.topic, connection.msgtype, log_ns, reader.deserialize(raw, connection.msgtype)


def import_bag(bag: str | Path, out: str | Path, config: BagImportConfig = BagImportConfig(),
               vehicle: VehicleParams | None = None) -> BagImport:
    """Write the ROS bag at ``bag`` (a ROS 1 ``.bag`` file or a ROS 2 bag folder) as a recording at ``out``.
    ``vehicle``: the top speed and wheelbase that turn speeds and yaw rates into throttle and steer."""
    out, bag = Path(out), Path(bag)
    if not bag.exists():
        raise DataError(f"no bag at {bag}")
    if bag.is_dir() and not (bag / "metadata.yaml").is_file():
        raise DataError(f"{bag} is a folder without metadata.yaml: not a ROS 2 bag")
    partial = out.with_name(f".{out.name}.partial")
    shutil.rmtree(partial, ignore_errors=True)
    try:
        with AnyReader([bag], default_typestore=_typestore()) as reader:
            result = _import(reader, partial, config, vehicle, str(bag.resolve()))
        if out.is_dir():
            out.rmdir()  # an empty folder (checked by the caller) is replaced
        os.replace(partial, out)
    except (AnyReaderError, Rosbag1Error, Rosbag2Error, SerdeError, FileNotFoundError) as exc:
        shutil.rmtree(partial, ignore_errors=True)
        raise DataError(f"{bag} cannot be read as a ROS bag: {exc}") from None
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return result


def match_sets(stamps: dict[str, list[int]], reference: str, tolerance_ns: int
               ) -> tuple[dict[tuple[str, int], int], dict[str, int]]:
    """Group cameras' frames into sets: each of the ``reference`` camera's stamps is a set, and another camera's
    frame joins the set nearest its stamp within ``tolerance_ns`` (one frame per camera and set). Returns
    (camera, stamp) -> the set's stamp, and how many frames of each camera joined none."""
    reference_ns = np.array(sorted(set(stamps[reference])), dtype=np.int64)
    set_of: dict[tuple[str, int], int] = {}
    unsynchronised = dict.fromkeys(stamps, 0)
    for name, own in stamps.items():
        taken: set[int] = set()
        for stamp in own:
            k = int(np.searchsorted(reference_ns, stamp))
            near = [j for j in (k - 1, k) if 0 <= j < len(reference_ns)]
            best = min(near, key=lambda j: abs(int(reference_ns[j]) - stamp)) if near else None
            if best is None or abs(int(reference_ns[best]) - stamp) > tolerance_ns or best in taken:
                unsynchronised[name] += 1
                continue
            taken.add(best)
            set_of[(name, stamp)] = int(reference_ns[best])
    return set_of, unsynchronised


def _import(reader: AnyReader, out: Path, config: BagImportConfig, vehicle: VehicleParams | None,
            source: str) -> BagImport:
    topics: dict[str, _Topic] = {}
    for connection in reader.connections:
        entry = topics.setdefault(connection.topic, _Topic(connection.topic, connection.msgtype, 0))
        entry.count += connection.msgcount
    tf_topics = [t.topic for t in topics.values() if t.msgtype == TF]
    transforms = _transforms(reader, tf_topics)
    cameras, unmapped = _camera_topics(config, topics)
    infos: dict[str, Any] = {}
    for topic, _, _, msg in _messages(reader, [c.info for c in cameras]):
        infos.setdefault(topic, msg)
    silent = [c.info for c in cameras if c.info not in infos]
    if silent:
        raise DataError(f"camera info topic {silent[0]} holds no message")
    pair = config.stereo_pair or (("left", "right") if {"left", "right"} <= {c.name for c in cameras} else ())
    if pair and not set(pair) <= {c.name for c in cameras}:
        raise DataError(f"stereo pair {pair[0]}, {pair[1]}: the cameras are {', '.join(c.name for c in cameras)}")
    reference = pair[0] if pair else cameras[0].name
    by_topic = {c.image: c.name for c in sorted(cameras, key=lambda c: c.name != reference)}
    stamps: dict[str, list[int]] = {name: [] for name in by_topic.values()}
    frame_ids: dict[str, str] = {}
    for topic, _, log_ns, msg in _messages(reader, list(by_topic)):
        stamps[by_topic[topic]].append(_stamp_ns(msg.header) or log_ns)
        frame_ids.setdefault(by_topic[topic], str(msg.header.frame_id).lstrip("/"))
    for name, own in stamps.items():
        # a bag stores messages as they arrived, so its images are put in the order of their header stamps; but
        # two images of one camera with one stamp cannot both be that moment (a driver's clock that stood still)
        ordered = np.sort(np.asarray(own, np.int64))
        repeated = np.flatnonzero(np.diff(ordered) == 0)
        if len(repeated):
            topic = next(t for t, n in by_topic.items() if n == name)
            raise DataError(f"{topic}: {len(repeated)} image(s) repeat another's header stamp (first "
                            f"{int(ordered[repeated[0]])} ns): one camera's frames must each have their own time")
    base = config.base_frame.lstrip("/")
    mounts, notes = _mounts(cameras, frame_ids, transforms, base, pair, infos)
    rig = {c.name: camera_from_info(infos[c.info], mounts[c.name]) for c in cameras}
    set_of, unsynchronised = match_sets(stamps, reference, round(config.sync_tolerance_ms * 1e6))
    command_topic = _pick("command", config.commands, topics, COMMAND_TYPES)
    truth_topic = _pick("ground-truth", config.groundtruth, topics, POSE_TYPES)
    lidars = _lidar_topics(reader, topics, transforms, base, notes)
    metadata: dict[str, Any] = {"source": "ros bag", "imported_from": source, "groundtruth_camera": reference,
                                "topics": {c.name: c.image for c in cameras}, "notes": notes}
    with RecordingWriter(out, rig, stereo_pair=(pair[0], pair[1]) if pair else None, metadata=metadata,
                         lidars={name: mount for name, (_, mount) in lidars.items()}) as writer:
        written = _write_frames(reader, writer, by_topic, set_of)
        scans = _write_scans(reader, writer, {topic: name for name, (topic, _) in lidars.items()})
        commands = _write_commands(reader, writer, command_topic, vehicle)
        # the truth as the reference camera's poses: a camera's own pose goes back to the kart's through its mount
        frame_mounts = {frame_ids[n]: mounts[n] for n in frame_ids}

        def mount_of(frame: str) -> Array | None:
            if frame in frame_mounts:
                return frame_mounts[frame]
            return _chain(transforms, base, frame) if frame not in ("", base) else None

        poses = _write_truth(reader, writer, truth_topic, mount_of, mounts[reference])
    mapped = {*(c.image for c in cameras), *(c.info for c in cameras), *tf_topics, command_topic, truth_topic,
              *(topic for topic, _ in lidars.values())}
    for entry in topics.values():
        if entry.topic not in mapped and entry.topic not in unmapped:
            several = entry.msgtype in COMMAND_TYPES or entry.msgtype in POSE_TYPES
            unmapped[entry.topic] = "one of several; name it in a topic map" if several else "no mapping for this type"
    return BagImport({c.name: written[c.name] for c in cameras}, commands, poses,
                     {n: c for n, c in unsynchronised.items() if c},
                     tuple((t, topics[t].msgtype, r) for t, r in sorted(unmapped.items())), tuple(notes), scans)


def _transforms(reader: AnyReader, tf_topics: list[str]) -> dict[str, tuple[str, Array]]:
    """Child frame -> (parent frame, the child's pose in it), the first of each: a mount does not move."""
    transforms: dict[str, tuple[str, Array]] = {}
    for _, _, _, msg in _messages(reader, tf_topics):
        for transform in msg.transforms:
            child = str(transform.child_frame_id).lstrip("/")
            if child not in transforms:
                transforms[child] = (str(transform.header.frame_id).lstrip("/"),
                                     _pose(transform.transform.translation, transform.transform.rotation))
    return transforms


def lidar_name(topic: str) -> str:
    """A LiDAR's name from its topic: the last part that is not ``scan`` (``/front_lidar/scan`` gives
    ``front_lidar``), ``lidar`` for a bare ``/scan``; made a recording's name (lower case, _ for the rest)."""
    parts = [p for p in topic.strip("/").split("/") if p and p.lower() not in ("scan", "scans", "laser_scan")]
    name = re.sub(r"[^a-z0-9_]", "_", parts[-1].lower()) if parts else "lidar"
    return name if re.match(r"[a-z]", name) else f"lidar_{name}"


def _lidar_topics(reader: AnyReader, topics: dict[str, _Topic], transforms: dict[str, tuple[str, Array]], base: str,
                  notes: list[str]) -> dict[str, tuple[str, LidarMount]]:
    """Each LaserScan topic as a LiDAR: name -> (topic, mount on the kart through the transforms to its frame)."""
    lidars: dict[str, tuple[str, LidarMount]] = {}
    for entry in (t for t in topics.values() if t.msgtype == LASER_SCAN):
        name = lidar_name(entry.topic)
        if name in lidars:
            raise DataError(f"two LaserScan topics name the same LiDAR {name!r} ({lidars[name][0]}, {entry.topic})")
        frame = next((str(msg.header.frame_id).lstrip("/") for _, _, _, msg in _messages(reader, [entry.topic])), "")
        pose = _chain(transforms, base, frame) if frame and frame != base else None
        if pose is None:
            notes.append(f"{name}: no transform from {base} to {frame or 'its frame'}; mounted at the kart's origin, "
                         "0.3 m up, looking ahead")
            mount = LidarMount(0.0, 0.0, 0.3)
        else:
            height = float(pose[2, 3]) if pose[2, 3] > 0 else 0.3
            mount = LidarMount(float(pose[0, 3]), float(pose[1, 3]), height, math.atan2(pose[1, 0], pose[0, 0]))
        lidars[name] = (entry.topic, mount)
    return lidars


def scan_from_message(msg: Any, log_ns: int) -> LaserScan:
    """A ``sensor_msgs/LaserScan`` as a sweep: its header's stamp (the log time where it has none), each range that
    is finite and within the scan's own window kept, any other no return (NaN)."""
    ranges = np.asarray(msg.ranges, np.float32)
    valid = np.isfinite(ranges) & (ranges >= msg.range_min) & (ranges <= msg.range_max)
    strengths = np.asarray(msg.intensities, np.float32)
    if strengths.shape != ranges.shape:  # a driver that sends no intensities
        strengths = np.zeros_like(ranges)
    return LaserScan(_stamp_ns(msg.header) or log_ns, float(msg.angle_min), float(msg.angle_increment),
                     float(msg.time_increment), float(msg.scan_time), float(msg.range_min), float(msg.range_max),
                     np.where(valid, ranges, np.nan).astype(np.float32),
                     np.where(valid, np.nan_to_num(strengths), 0.0).astype(np.float32))


def _write_scans(reader: AnyReader, writer: RecordingWriter, by_topic: dict[str, str]) -> dict[str, int]:
    """Every sweep of each LiDAR topic, in the order of their stamps (a sweep whose stamp repeats or goes back is
    left out: the recording's sweeps are in time); returns the count per LiDAR."""
    counts = dict.fromkeys(by_topic.values(), 0)
    last: dict[str, int] = {}
    for topic, _, log_ns, msg in _messages(reader, list(by_topic)):
        name = by_topic[topic]
        try:
            scan = scan_from_message(msg, log_ns)
        except KartpilotError as exc:
            raise DataError(f"{topic}: a LaserScan that is not one: {exc}") from None
        if scan.stamp_ns <= last.get(name, -1):
            continue
        writer.write_scan(name, scan)
        last[name] = scan.stamp_ns
        counts[name] += 1
    return counts


def _camera_topics(config: BagImportConfig, topics: dict[str, _Topic]) -> tuple[list[BagCamera], dict[str, str]]:
    """The cameras to import (named in the map, or every image topic with a camera info), and the image topics
    left out with the reason."""
    wanted = list(config.cameras) or [BagCamera(camera_name(t.topic), t.topic, "") for t in topics.values()
                                     if t.msgtype in (IMAGE, COMPRESSED)]
    names = [c.name for c in wanted]
    if len(set(names)) < len(names):
        raise DataError(f"two image topics name the same camera ({', '.join(names)}): name them in a topic map")
    cameras: list[BagCamera] = []
    unmapped: dict[str, str] = {}
    for camera in wanted:
        if camera.image not in topics or topics[camera.image].msgtype not in (IMAGE, COMPRESSED):
            raise DataError(f"camera {camera.name}: the bag has no image topic {camera.image!r}")
        info = camera.info or info_topic(camera.image)
        if info not in topics or topics[info].msgtype != INFO:
            if config.cameras:
                raise DataError(f"camera {camera.name}: the bag has no camera info {info!r}")
            unmapped[camera.image] = f"no camera info (looked for {info})"
            continue
        cameras.append(BagCamera(camera.name, camera.image, info))
    if not cameras:
        raise DataError("the bag has no image topic with a camera info: " +
                        ("; ".join(f"{t}: {r}" for t, r in unmapped.items()) or "no image topic at all"))
    return cameras, unmapped


def _mounts(cameras: list[BagCamera], frame_ids: dict[str, str], transforms: dict[str, tuple[str, Array]],
            base: str, pair: tuple[str, ...], infos: dict[str, Any]) -> tuple[dict[str, Array], list[str]]:
    """Each camera's pose on the kart through the transforms from ``base``; without them, at the kart's origin,
    and a stereo pair's right camera at the baseline its projection matrix gives. Returns the mounts and notes."""
    notes: list[str] = []
    mounts: dict[str, Array] = {}
    for camera in cameras:
        frame = frame_ids.get(camera.name, "")
        mount = _chain(transforms, base, frame) if frame else None
        if mount is None:
            notes.append(f"{camera.name}: no transform from {base} to {frame or 'its frame'}; mounted at the kart's "
                         "origin, looking ahead")
            mount = mount_pose()
        mounts[camera.name] = mount
    if pair and any(_chain(transforms, base, frame_ids.get(n, "")) is None for n in pair):
        # ROS's stereo convention: the right camera's P[0, 3] = -fx * baseline
        p = _matrix(infos[next(c.info for c in cameras if c.name == pair[1])], "p")
        baseline_m = -float(p[3]) / float(p[0]) if p[0] else 0.0
        if baseline_m <= 0:
            raise CalibrationError(f"stereo pair {pair[0]}, {pair[1]}: neither transforms nor the right camera's "
                                   "projection matrix give the baseline")
        right_on_left = np.eye(4)
        right_on_left[0, 3] = baseline_m
        mounts[pair[1]] = mounts[pair[0]] @ right_on_left
        notes.append(f"the stereo baseline, {baseline_m:.4f} m, is the right camera's projection matrix's")
    return mounts, notes


def _write_frames(reader: AnyReader, writer: RecordingWriter, by_topic: dict[str, str],
                  set_of: dict[tuple[str, int], int]) -> Counter[str]:
    """Each image that joined a set, decoded and checked against its camera; returns the count per camera."""
    written: Counter[str] = Counter()
    for topic, msgtype, log_ns, msg in _messages(reader, list(by_topic)):
        name = by_topic[topic]
        stamp = _stamp_ns(msg.header) or log_ns
        set_ns = set_of.pop((name, stamp), None)  # popped: a second frame with the same stamp joins nothing
        if set_ns is None:
            continue
        try:
            image = decode_image(msg, msgtype)
        except DataError as exc:
            raise DataError(f"{topic} at {stamp} ns: {exc}") from None
        camera = writer.cameras[name]
        if image.shape[:2] != (camera.height_px, camera.width_px):
            raise DataError(f"{topic} at {stamp} ns is {image.shape[1]}x{image.shape[0]}, its camera info "
                            f"{camera.width_px}x{camera.height_px}")
        writer.write_frame(name, set_ns, image, stamp)
        written[name] += 1
    return written


def _write_commands(reader: AnyReader, writer: RecordingWriter, topic: str, vehicle: VehicleParams | None) -> int:
    """The command topic's messages as commands (the speed over the top speed: the throttle; a negative speed:
    the brake), with their raw values as the ``ros_command`` output; returns how many."""
    count = 0
    top = vehicle.top_speed_mps if vehicle else 1.0
    for _, msgtype, log_ns, msg in _messages(reader, [topic] if topic else []):
        stamp, values = _command(msgtype, msg, log_ns, vehicle)
        speed = float(values["speed_mps"])
        writer.write_command(ActuatorCommand(stamp, float(values["steer_rad"]), float(np.clip(speed / top, 0.0, 1.0)),
                                             float(np.clip(-speed / top, 0.0, 1.0))))
        writer.write_output("ros_command", stamp, values)
        count += 1
    return count


def _write_truth(reader: AnyReader, writer: RecordingWriter, topic: str, mount_of: Callable[[str], Array | None],
                 reference_mount: Array) -> int:
    """The pose topic as the reference camera's ground truth; ``mount_of`` gives the mount of a frame a pose is
    of (None: the kart's own). Returns how many poses."""
    stamps: list[float] = []
    poses: list[Array] = []
    for _, msgtype, log_ns, msg in _messages(reader, [topic] if topic else []):
        stamp, pose_world_frame, frame = _truth(msgtype, msg, log_ns)
        mount = mount_of(frame)
        body = pose_world_frame if mount is None else pose_world_frame @ invert_pose(mount)
        stamps.append(stamp * 1e-9)
        poses.append(body @ reference_mount)
    if poses:
        writer.write_groundtruth(Trajectory(np.array(stamps), np.array(poses)))
    return len(poses)


def _command(msgtype: str, msg: Any, log_ns: int, vehicle: VehicleParams | None) -> tuple[int, dict[str, float]]:
    """(stamp_ns, {steer_rad, speed_mps, yaw_rate_radps}) of a Twist or Ackermann message."""
    stamp = _stamp_ns(msg.header) or log_ns if hasattr(msg, "header") else log_ns
    if msgtype in (ACKERMANN, ACKERMANN_STAMPED):
        drive = msg.drive if msgtype == ACKERMANN_STAMPED else msg
        return stamp, {"steer_rad": float(drive.steering_angle), "speed_mps": float(drive.speed),
                       "yaw_rate_radps": math.nan}
    twist = msg.twist if msgtype == TWIST_STAMPED else msg
    speed, yaw_rate = float(twist.linear.x), float(twist.angular.z)
    steer = 0.0
    if vehicle is not None and abs(speed) > 0.1:  # the bicycle model: tan(steer) = wheelbase * yaw rate / speed
        steer = float(np.clip(math.atan(vehicle.wheelbase_m * yaw_rate / speed), -vehicle.max_steer_rad,
                              vehicle.max_steer_rad))
    return stamp, {"steer_rad": steer, "speed_mps": speed, "yaw_rate_radps": yaw_rate}


def _truth(msgtype: str, msg: Any, log_ns: int) -> tuple[int, Array, str]:
    """(stamp_ns, the pose in its world frame, the frame it is the pose of: "" for the kart's)."""
    stamp = _stamp_ns(msg.header) or log_ns
    if msgtype == ODOMETRY:
        return stamp, _pose(msg.pose.pose.position, msg.pose.pose.orientation), str(msg.child_frame_id).lstrip("/")
    pose = msg.pose.pose if msgtype == POSE_COVARIANCE else msg.pose
    return stamp, _pose(pose.position, pose.orientation), ""


# --- export -------------------------------------------------------------------------------------------


def export_ros2_bag(folder: str | Path, out: str | Path, vehicle: VehicleParams | None = None) -> dict[str, int]:
    """Write the recording at ``folder`` as a ROS 2 bag (a folder) at ``out``; returns the message count per
    topic. ``vehicle``: the top speed that turns a throttle into the Ackermann command's speed (without one,
    the speed is the throttle)."""
    reader = RecordingReader(folder)
    out = Path(out)
    partial = out.with_name(f".{out.name}.partial")
    shutil.rmtree(partial, ignore_errors=True)
    try:
        counts = _export(reader, partial, vehicle)
        if out.is_dir():
            out.rmdir()
        os.replace(partial, out)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return counts


def _export(reader: RecordingReader, out: Path, vehicle: VehicleParams | None) -> dict[str, int]:
    store = _typestore()
    t = store.types
    header = t["std_msgs/msg/Header"]

    def stamped(stamp_ns: int, frame: str) -> Any:
        return header(stamp=t["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000,
                                                             nanosec=stamp_ns % 1_000_000_000), frame_id=frame)

    def transform(stamp_ns: int, parent: str, child: str, pose: Array) -> Any:
        q = quaternion_xyzw_from_pose(pose)
        return t["geometry_msgs/msg/TransformStamped"](
            header=stamped(stamp_ns, parent), child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](*(float(v) for v in pose[:3, 3])),
                rotation=t["geometry_msgs/msg/Quaternion"](*(float(v) for v in q))))

    messages: list[tuple[int, str, str, Any]] = []  # (log time, topic, type, message)
    first_ns = min([s for n in reader.cameras for s, _ in reader.frames(n)[:1]] or [0])
    lidars = reader.lidars
    messages.append((first_ns, "/tf_static", TF, t[TF](transforms=[
        *(transform(first_ns, "base_link", name, cam.pose_body_cam_array) for name, cam in reader.cameras.items()),
        *(transform(first_ns, "base_link", name, m.pose_body_lidar()) for name, m in lidars.items())])))
    for name in lidars:
        for scan in reader.scans(name):
            ranges = np.where(np.isfinite(scan.ranges_m), scan.ranges_m, np.inf).astype(np.float32)
            messages.append((scan.stamp_ns, f"/{name}/scan", LASER_SCAN, t[LASER_SCAN](
                header=stamped(scan.stamp_ns, name), angle_min=scan.angle_min_rad,
                angle_max=scan.angle_min_rad + scan.angle_increment_rad * (len(ranges) - 1),
                angle_increment=scan.angle_increment_rad, time_increment=scan.time_increment_s,
                scan_time=scan.scan_time_s, range_min=scan.range_min_m, range_max=scan.range_max_m, ranges=ranges,
                intensities=np.asarray(scan.intensities, np.float32))))
    for name, camera in reader.cameras.items():
        baseline = 0.0
        if reader.stereo_pair and name == reader.stereo_pair[1]:
            left = reader.cameras[reader.stereo_pair[0]].pose_body_cam_array
            baseline = float((invert_pose(left) @ camera.pose_body_cam_array)[0, 3])
        calibration = camera.ros_calibration(baseline)
        for (stamp, path), capture in zip(reader.frames(name), reader.capture_stamps(name), strict=True):
            data = np.frombuffer(read_file_bytes(path), dtype=np.uint8)
            image_format = "jpeg" if path.suffix.lower() in (".jpg", ".jpeg") else "png"
            messages.append((capture, f"/{name}/image_raw/compressed", COMPRESSED,
                             t[COMPRESSED](header=stamped(stamp, name), format=image_format, data=data)))
            messages.append((capture, f"/{name}/camera_info", INFO, t[INFO](
                header=stamped(stamp, name), height=camera.height_px, width=camera.width_px,
                distortion_model=calibration["distortion_model"],
                **{key.lower(): np.array(calibration[key]) for key in ("D", "K", "R", "P")},
                binning_x=0, binning_y=0, roi=t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False))))
    bodies = reader.body_poses()
    if bodies is not None:
        zero6 = np.zeros(36)
        for stamp_s, pose in zip(bodies.stamps_s, bodies.poses, strict=True):
            stamp = round(float(stamp_s) * 1e9)
            q = quaternion_xyzw_from_pose(pose)
            messages.append((stamp, "/groundtruth", ODOMETRY, t[ODOMETRY](
                header=stamped(stamp, "world"), child_frame_id="base_link",
                pose=t["geometry_msgs/msg/PoseWithCovariance"](t["geometry_msgs/msg/Pose"](
                    t["geometry_msgs/msg/Point"](*(float(v) for v in pose[:3, 3])),
                    t["geometry_msgs/msg/Quaternion"](*(float(v) for v in q))), zero6),
                twist=t["geometry_msgs/msg/TwistWithCovariance"](t["geometry_msgs/msg/Twist"](
                    t["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0), t["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0)),
                    zero6))))
    top = vehicle.top_speed_mps if vehicle else 1.0
    for command in reader.commands():
        speed = (command.throttle if command.brake <= 0 else -command.brake) * top
        messages.append((command.stamp_ns, "/commands", ACKERMANN_STAMPED, t[ACKERMANN_STAMPED](
            header=stamped(command.stamp_ns, "base_link"), drive=t[ACKERMANN](
                steering_angle=command.steer_rad, steering_angle_velocity=0.0, speed=speed, acceleration=0.0,
                jerk=0.0))))
    messages.sort(key=lambda m: m[0])
    counts: dict[str, int] = {}
    with Writer(out, version=9) as writer:
        connections = {}
        for log_ns, topic, msgtype, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], log_ns, store.serialize_cdr(message, msgtype))
            counts[topic] = counts.get(topic, 0) + 1
    return counts

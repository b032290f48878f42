"""ROS bags in and out, with rosbags itself: a foreign ROS 2 bag (raw images, transforms, odometry, Twist) of a
simulated drive imports, and stereo VO on it matches VO on the drive's own recording; a recording exported
to a bag and imported again keeps its images and time stamps."""

import math
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from kartpilot.cli.main import main
from kartpilot.core.config import merge_config
from kartpilot.core.errors import ConfigError, DataError
from kartpilot.core.geometry import invert_pose, quaternion_xyzw_from_pose
from kartpilot.core.vehicle import get_vehicle
from kartpilot.odometry.run import run_vo
from kartpilot.odometry.stereo_vo import StereoVO
from kartpilot.record.recording import RecordingReader, RecordingStereoSource
from kartpilot.record.rosbag import BagImportConfig, camera_name, decode_image, import_bag, info_topic, match_sets
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.simulator import SimConfig

RIGHT_LAG_NS = 1_000_000  # the right camera's frames are stamped 1 ms after the left's, as unsynchronised cameras


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bag") / "drive"
    config = SimConfig(track="straight20", vehicle="rc-kart", cameras=("left", "right"), camera_rate_hz=10.0,
                       seed=1, max_time_s=2.0)
    run_simulation(config, driver_config=CenterlineDriverConfig(speed_mps=1.0),
                   outputs=SessionOutputs(record_dir=folder))
    return folder


def stereo_vo(folder):
    source = RecordingStereoSource(folder)
    return run_vo(source.frame_sets(), StereoVO(source.rig), source.name).trajectory


def write_foreign_bag(recording, out, vehicle, header_ns=lambda name, stamp: stamp):
    """The drive as a team's ROS 2 bag would hold it: raw rgb8 images under /stereo, camera info with the right
    camera's baseline in P, the mounts as a chain of static transforms, odometry of base_link, Twist commands,
    and a topic kartpilot has no use for. ``header_ns`` gives each image's header stamp (a driver's clock)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types
    reader = RecordingReader(recording)

    def header(stamp_ns, frame):
        return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](
            sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000), frame_id=frame)

    def transform(parent, child, pose):
        return t["geometry_msgs/msg/TransformStamped"](
            header=header(0, parent), child_frame_id=child, transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](*pose[:3, 3]),
                rotation=t["geometry_msgs/msg/Quaternion"](*quaternion_xyzw_from_pose(pose))))

    left, right = reader.cameras["left"], reader.cameras["right"]
    rig_link = np.eye(4)
    rig_link[:3, 3] = left.pose_body_cam_array[:3, 3]  # base_link -> stereo_link -> each optical frame
    messages = [(0, "/tf_static", "tf2_msgs/msg/TFMessage", t["tf2_msgs/msg/TFMessage"](transforms=[
        transform("base_link", "stereo_link", rig_link),
        transform("stereo_link", "left_optical", invert_pose(rig_link) @ left.pose_body_cam_array),
        transform("stereo_link", "right_optical", invert_pose(rig_link) @ right.pose_body_cam_array)]))]
    baseline = float((invert_pose(left.pose_body_cam_array) @ right.pose_body_cam_array)[0, 3])
    for name, lag, tx in (("left", 0, 0.0), ("right", RIGHT_LAG_NS, -right.fx_px * baseline)):
        k = reader.cameras[name].matrix
        for stamp, path in reader.frames(name):
            rgb = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
            h, w = rgb.shape[:2]
            messages.append((stamp + lag, f"/stereo/{name}/image_raw", "sensor_msgs/msg/Image", t[
                "sensor_msgs/msg/Image"](header=header(header_ns(name, stamp + lag), f"{name}_optical"), height=h,
                                         width=w, encoding="rgb8", is_bigendian=0, step=w * 3, data=rgb.ravel())))
            messages.append((stamp + lag, f"/stereo/{name}/camera_info", "sensor_msgs/msg/CameraInfo", t[
                "sensor_msgs/msg/CameraInfo"](
                    header=header(stamp + lag, f"{name}_optical"), height=h, width=w, distortion_model="plumb_bob",
                    d=np.zeros(5), k=k.ravel(), r=np.eye(3).ravel(),
                    p=np.array([k[0, 0], 0, k[0, 2], tx, 0, k[1, 1], k[1, 2], 0, 0, 0, 1, 0.0]), binning_x=0,
                    binning_y=0, roi=t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False))))
    bodies = reader.body_poses()
    for stamp_s, pose in zip(bodies.stamps_s, bodies.poses, strict=True):
        stamp = round(stamp_s * 1e9)
        vector = t["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0)
        messages.append((stamp, "/odom", "nav_msgs/msg/Odometry", t["nav_msgs/msg/Odometry"](
            header=header(stamp, "odom"), child_frame_id="base_link",
            pose=t["geometry_msgs/msg/PoseWithCovariance"](t["geometry_msgs/msg/Pose"](
                t["geometry_msgs/msg/Point"](*pose[:3, 3]),
                t["geometry_msgs/msg/Quaternion"](*quaternion_xyzw_from_pose(pose))), np.zeros(36)),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](t["geometry_msgs/msg/Twist"](vector, vector),
                                                             np.zeros(36)))))
    for command in reader.commands():
        speed = command.throttle * vehicle.top_speed_mps
        yaw_rate = speed * math.tan(command.steer_rad) / vehicle.wheelbase_m
        messages.append((command.stamp_ns, "/cmd_vel", "geometry_msgs/msg/Twist", t["geometry_msgs/msg/Twist"](
            t["geometry_msgs/msg/Vector3"](speed, 0.0, 0.0), t["geometry_msgs/msg/Vector3"](0.0, 0.0, yaw_rate))))
    messages.append((1, "/chatter", "std_msgs/msg/String", t["std_msgs/msg/String"]("hello")))
    messages.sort(key=lambda m: m[0])
    with Writer(out, version=9) as writer:
        connections = {}
        for stamp, topic, msgtype, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], stamp, store.serialize_cdr(message, msgtype))


def test_a_foreign_ros2_bag_imports_and_stereo_vo_on_it_matches_vo_on_the_original(drive, tmp_path):
    vehicle = get_vehicle("rc-kart")
    write_foreign_bag(drive, tmp_path / "team_bag", vehicle)
    result = import_bag(tmp_path / "team_bag", tmp_path / "imported", vehicle=vehicle)
    original, imported = RecordingReader(drive), RecordingReader(tmp_path / "imported")
    assert result.frames == {"left": len(original.frames("left")), "right": len(original.frames("right"))}
    assert result.unmapped == (("/chatter", "std_msgs/msg/String", "no mapping for this type"),)
    assert result.unsynchronised == {} and result.notes == ()
    # the sets are the left camera's stamps; the right camera's own stamps are kept as its capture time
    assert [s for s, _ in imported.frames("right")] == [s for s, _ in original.frames("left")]
    assert imported.capture_stamps("right") == [s + RIGHT_LAG_NS for s, _ in original.frames("right")]
    for name in ("left", "right"):  # the mounts through the chain of transforms, the intrinsics from K
        assert np.allclose(imported.cameras[name].pose_body_cam_array, original.cameras[name].pose_body_cam_array,
                           atol=1e-12)
        assert np.allclose(imported.cameras[name].matrix, original.cameras[name].matrix)
    assert np.allclose(imported.groundtruth().poses, original.groundtruth().poses, atol=1e-9)
    # Twist: the steer back through the wheelbase where the kart moves (a yaw rate at standstill says nothing)
    moving = [c.throttle * vehicle.top_speed_mps > 0.1 for c in original.commands()]
    assert [c.stamp_ns for c in imported.commands()] == [c.stamp_ns for c in original.commands()]
    assert [c.steer_rad for c in imported.commands()] == pytest.approx(
        [c.steer_rad if m else 0.0 for c, m in zip(original.commands(), moving, strict=True)], abs=1e-9)
    assert [c.throttle for c in imported.commands()] == pytest.approx([c.throttle for c in original.commands()])
    ours, theirs = stereo_vo(drive), stereo_vo(tmp_path / "imported")
    offset_m = np.linalg.norm(ours.poses[:, :3, 3] - theirs.poses[:, :3, 3], axis=1).max()
    print(f"stereo VO, the imported bag against the original recording: largest offset {offset_m * 1e3:.4f} mm "
          f"over {len(ours.poses)} frames")
    assert len(theirs.poses) == len(ours.poses) and offset_m < 1e-3


def test_a_recording_to_a_ros2_bag_and_back_keeps_images_and_stamps(drive, tmp_path, capsys):
    assert main(["recordings", "export", str(drive), "--format", "ros2", "--out", str(tmp_path / "bag"),
                 "--vehicle", "rc-kart"]) == 0
    assert main(["recordings", "import-bag", str(tmp_path / "bag"), "--out", str(tmp_path / "back"),
                 "--vehicle", "rc-kart"]) == 0
    assert "not imported" not in capsys.readouterr().out
    original, back = RecordingReader(drive), RecordingReader(tmp_path / "back")
    assert back.stereo_pair == original.stereo_pair
    for name in original.cameras:
        assert back.frames(name) and [s for s, _ in back.frames(name)] == [s for s, _ in original.frames(name)]
        assert back.capture_stamps(name) == original.capture_stamps(name)
        for (_, a), (_, b) in zip(original.frames(name), back.frames(name), strict=True):
            assert np.array_equal(cv2.imread(str(a), cv2.IMREAD_UNCHANGED), cv2.imread(str(b), cv2.IMREAD_UNCHANGED))
        assert back.cameras[name] == original.cameras[name]
    assert np.allclose(back.groundtruth().poses, original.groundtruth().poses, atol=1e-9)
    assert [c.stamp_ns for c in back.commands()] == [c.stamp_ns for c in original.commands()]
    assert [c.steer_rad for c in back.commands()] == pytest.approx([c.steer_rad for c in original.commands()],
                                                                   abs=1e-6)  # Ackermann's float32


def test_topic_names_give_cameras_and_their_info():
    assert camera_name("/stereo/left/image_raw") == "left"
    assert camera_name("/cam_front/image_rect_color/compressed") == "cam_front"
    assert camera_name("/image_raw") == "camera"
    assert info_topic("/stereo/left/image_raw/compressed") == "/stereo/left/camera_info"


def test_bad_bags_and_topic_maps_are_refused_and_leave_nothing(drive, tmp_path, capsys):
    (tmp_path / "junk.bag").write_bytes(b"not a bag at all")
    (tmp_path / "empty").mkdir()
    for bag, message in ((tmp_path / "junk.bag", "cannot be read as a ROS bag"),
                         (tmp_path / "empty", "not a ROS 2 bag"), (tmp_path / "none", "no bag at")):
        assert main(["recordings", "import-bag", str(bag), "--out", str(tmp_path / "out")]) == 1
        error = capsys.readouterr().err
        assert error.startswith("kartpilot: ") and message in error and len(error.strip().splitlines()) == 1
        assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out*"))
    (tmp_path / "map.yaml").write_text("cameras:\n  - {name: left, image: /left/image_raw, infos: x}\n")
    assert main(["recordings", "import-bag", str(tmp_path / "junk.bag"), "--out", str(tmp_path / "out"),
                 "--topics", str(tmp_path / "map.yaml")]) == 1
    assert "unknown config key 'topics.cameras[0].infos'" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="sync_tolerance_ms"):
        merge_config(BagImportConfig(), {"sync_tolerance_ms": -1.0}, "topics")
    assert main(["recordings", "export", str(drive), "--format", "ros2", "--out", str(tmp_path / "bag")]) == 0
    (tmp_path / "map.yaml").write_text("cameras:\n  - {name: left, image: /nowhere/image_raw}\n")
    assert main(["recordings", "import-bag", str(tmp_path / "bag"), "--out", str(tmp_path / "out"),
                 "--topics", str(tmp_path / "map.yaml")]) == 1
    assert "camera left: the bag has no image topic '/nowhere/image_raw'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out*"))
    with pytest.raises(DataError, match="the bag has no command topic"):
        import_bag(tmp_path / "bag", tmp_path / "out", BagImportConfig(commands="/cmd_vel"))


def test_a_camera_whose_images_repeat_a_header_stamp_is_refused_naming_its_topic(drive, tmp_path):
    """A driver's clock that stood still stamps two images alike: sorting by header stamp cannot order them, and
    matching them to the other camera would pair the wrong images."""
    first = RecordingReader(drive).frames("left")[3][0]
    write_foreign_bag(drive, tmp_path / "bag", get_vehicle("rc-kart"),
                      header_ns=lambda name, stamp: min(stamp, first) if name == "left" else stamp)
    with pytest.raises(DataError, match=r"/stereo/left/image_raw: \d+ image\(s\) repeat another's header stamp"):
        import_bag(tmp_path / "bag", tmp_path / "out", BagImportConfig())
    assert not (tmp_path / "out").exists()


def test_a_ros1_bag_of_compressed_images_without_transforms_imports(drive, tmp_path):
    """ROS 1: JPEG-compressed images, camera info in ROS 1's spelling (K, P), no transforms: the pair's baseline
    comes from the right camera's projection matrix, and the import says the mounts are guessed."""
    store = get_typestore(Stores.ROS1_NOETIC)
    t = store.types
    reader = RecordingReader(drive)
    left, right = reader.cameras["left"], reader.cameras["right"]
    baseline = float((invert_pose(left.pose_body_cam_array) @ right.pose_body_cam_array)[0, 3])
    with Writer1(tmp_path / "team.bag") as writer:
        connections = {}
        for name, tx in (("left", 0.0), ("right", -right.fx_px * baseline)):
            k = reader.cameras[name].matrix
            image = f"/{name}/image_raw/compressed"
            info = f"/{name}/camera_info"
            connections[image] = writer.add_connection(image, "sensor_msgs/msg/CompressedImage", typestore=store)
            connections[info] = writer.add_connection(info, "sensor_msgs/msg/CameraInfo", typestore=store)
            for index, (stamp, path) in enumerate(reader.frames(name)[:5]):
                header = t["std_msgs/msg/Header"](index, t["builtin_interfaces/msg/Time"](
                    stamp // 1_000_000_000, stamp % 1_000_000_000), f"{name}_optical")
                jpeg = np.frombuffer(cv2.imencode(".jpg", cv2.imread(str(path)))[1].tobytes(), np.uint8)
                writer.write(connections[image], stamp, store.serialize_ros1(
                    t["sensor_msgs/msg/CompressedImage"](header, "jpeg", jpeg), "sensor_msgs/msg/CompressedImage"))
                writer.write(connections[info], stamp, store.serialize_ros1(t["sensor_msgs/msg/CameraInfo"](
                    header, left.height_px, left.width_px, "plumb_bob", np.zeros(5), k.ravel(), np.eye(3).ravel(),
                    np.array([k[0, 0], 0, k[0, 2], tx, 0, k[1, 1], k[1, 2], 0, 0, 0, 1, 0.0]), 0, 0,
                    t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False)), "sensor_msgs/msg/CameraInfo"))
    result = import_bag(tmp_path / "team.bag", tmp_path / "imported")
    imported = RecordingReader(tmp_path / "imported")
    assert result.frames == {"left": 5, "right": 5} and imported.stereo_pair == ("left", "right")
    assert any("baseline" in note for note in result.notes) and any("no transform" in note for note in result.notes)
    mounts = [imported.cameras[n].pose_body_cam_array for n in ("left", "right")]
    assert (invert_pose(mounts[0]) @ mounts[1])[0, 3] == pytest.approx(baseline)
    assert [s for s, _ in imported.frames("left")] == [s for s, _ in reader.frames("left")[:5]]


@settings(max_examples=200, deadline=None)
@given(encoding=st.sampled_from(["mono8", "bgr8", "rgb8", "rgba8", "16UC1", "32FC1", "yuv422", ""]),
       width=st.integers(0, 9), height=st.integers(0, 9), step=st.integers(-2, 40), size=st.integers(0, 400))
def test_a_raw_image_message_decodes_or_is_refused_by_name(encoding, width, height, step, size):
    msg = SimpleNamespace(encoding=encoding, width=width, height=height, step=step, data=np.zeros(size, np.uint8))
    try:
        image = decode_image(msg, "sensor_msgs/msg/Image")
    except DataError:
        return
    assert image.shape[:2] == (height, width) and image.dtype == np.uint8


@settings(max_examples=100, deadline=None)
@given(data=st.binary(max_size=300))
def test_a_compressed_image_message_of_any_bytes_decodes_or_is_refused_by_name(data):
    msg = SimpleNamespace(format="jpeg", data=np.frombuffer(data, np.uint8))
    try:
        image = decode_image(msg, "sensor_msgs/msg/CompressedImage")
    except DataError:
        return
    assert image.dtype == np.uint8


def test_frames_join_the_reference_cameras_nearest_set_within_the_tolerance_once():
    stamps = {"left": [100, 200, 300], "right": [104, 196, 197, 260, 301]}
    set_of, unsynchronised = match_sets(stamps, "left", tolerance_ns=5)
    assert set_of == {("left", 100): 100, ("left", 200): 200, ("left", 300): 300, ("right", 104): 100,
                      ("right", 196): 200, ("right", 301): 300}
    assert unsynchronised == {"left": 0, "right": 2}  # 197: its set is taken; 260: nowhere near one

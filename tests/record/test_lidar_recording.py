"""The LiDAR in a recording (issue 58): a simulated drive of the 2026 kart records its sweeps beside the frames,
they read back sweep for sweep, a replay hands them to the frame sets as the drive did, and a line cut off by a
crash or a damaged line is left out or named."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from kartpilot.core.errors import RecordingError
from kartpilot.core.types import LidarMount
from kartpilot.record.recording import RecordingReader
from kartpilot.record.replay import RecordingFrameSource
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.simulator import SimConfig, Simulator
from kartpilot.sim.track import Prop

CONFIG = SimConfig(track="straight20", vehicle="sdc-kart-2026", cameras=("center",), camera_rate_hz=15.0,
                   max_time_s=2.0, props=(Prop(kind="car", s_m=12.0, offset_m=0.0),))


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lidar") / "drive"
    run_simulation(CONFIG, "centerline", driver_config=CenterlineDriverConfig(speed_mps=2.0),
                   outputs=SessionOutputs(record_dir=folder))
    return folder


def test_the_sweeps_are_recorded_with_the_mount_and_read_back_sweep_for_sweep(drive) -> None:
    """The first sweep as the same simulation (same seed) makes it again, each range to the format's 0.1 mm, a
    return and no return where they were; 10 Hz beside 15 Hz frames: 20 sweeps in 2 s, each at its own time."""
    reader = RecordingReader(drive)
    assert reader.lidars == {"lidar": LidarMount(1.45, 0.0, 0.30)}
    recorded = reader.scans("lidar")
    assert reader.manifest["scan_counts"] == {"lidar": len(recorded)} and len(recorded) == 20
    with Simulator(CONFIG) as sim:  # the first sweep, taken standing still before any command, made again
        frames = sim.read()
        assert frames is not None
        same = frames.scans["lidar"]
    first = recorded[0]
    assert first.stamp_ns == same.stamp_ns and first.angle_increment_rad == pytest.approx(same.angle_increment_rad)
    assert np.array_equal(np.isnan(first.ranges_m), np.isnan(same.ranges_m))
    assert np.nanmax(np.abs(first.ranges_m - same.ranges_m)) <= 5e-5
    assert [s.stamp_ns for s in recorded] == [round(k * 0.1e9) for k in range(20)]


def test_a_replay_hands_each_sweep_to_the_set_it_came_with(drive) -> None:
    source = RecordingFrameSource(drive)
    handed = []
    while (frames := source.read()) is not None:
        if "lidar" in frames.scans:
            assert frames.scans["lidar"].stamp_ns <= frames.stamp_ns
            handed.append(frames.scans["lidar"].stamp_ns)
    assert handed == [s.stamp_ns for s in RecordingReader(drive).scans("lidar")]


def test_a_torn_last_sweep_is_left_out_and_a_damaged_one_named(drive, tmp_path) -> None:
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(drive, copy)
    path = copy / "lidar" / "lidar" / "scans.csv"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:-1]) + lines[-1][: len(lines[-1]) // 2])  # cut off mid-line, as a crash leaves
    assert len(RecordingReader(copy).scans("lidar")) == 19
    lines[3] = lines[3].replace(",", ",x", 1)
    path.write_text("".join(lines))
    with pytest.raises(RecordingError, match=r"scans\.csv:4: not a sweep"):
        RecordingReader(copy).scans("lidar")
    values = lines[5].split(",")
    values[-1] = " ".join(values[-1].split()[:-3]) + "\n"  # fewer intensities than ranges
    lines[3] = lines[4]
    lines[5] = ",".join(values)
    path.write_text("".join(lines[:4] + lines[5:]))
    with pytest.raises(RecordingError, match="ranges but"):
        RecordingReader(copy).scans("lidar")
    with pytest.raises(RecordingError, match="no LiDAR 'front'"):
        RecordingReader(copy).scans("front")


def test_a_recording_without_a_lidar_reads_as_one_with_none(tmp_path) -> None:
    folder = tmp_path / "plain"
    run_simulation(SimConfig(track="straight20", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=10.0,
                             max_time_s=0.5), "centerline", outputs=SessionOutputs(record_dir=folder))
    reader = RecordingReader(folder)
    assert reader.lidars == {} and not (folder / "lidar").exists()
    frames = RecordingFrameSource(folder).read()
    assert frames is not None and frames.scans == {}
    assert math.isfinite(reader.manifest["frame_counts"]["center"])


def _same_sweeps(a: list, b: list) -> None:
    assert [s.stamp_ns for s in a] == [s.stamp_ns for s in b] and len(a) > 0
    for x, y in zip(a, b, strict=True):
        assert x.angle_min_rad == pytest.approx(y.angle_min_rad) and len(x.ranges_m) == len(y.ranges_m)
        assert np.array_equal(np.isnan(x.ranges_m), np.isnan(y.ranges_m))
        assert np.nanmax(np.abs(x.ranges_m - y.ranges_m)) <= 1e-6


def test_a_drive_with_its_lidar_goes_to_a_ros2_bag_and_back_sweep_for_sweep(drive, tmp_path) -> None:
    """Exported as sensor_msgs/LaserScan on /lidar/scan with the mount on /tf_static, imported again: the same
    LiDAR, mount and sweeps (no return stays no return: +inf in the bag, as REP 117 has it)."""
    from kartpilot.record.rosbag import export_ros2_bag, import_bag

    counts = export_ros2_bag(drive, tmp_path / "bag")
    assert counts["/lidar/scan"] == 20
    imported = import_bag(tmp_path / "bag", tmp_path / "back")
    assert imported.scans == {"lidar": 20}
    back = RecordingReader(tmp_path / "back")
    mount = back.lidars["lidar"]
    assert (mount.x_m, mount.y_m, mount.z_m, mount.yaw_rad) == pytest.approx((1.45, 0.0, 0.30, 0.0))
    _same_sweeps(RecordingReader(drive).scans("lidar"), back.scans("lidar"))


def test_the_mcap_export_carries_each_sweep_as_a_foxglove_laser_scan(drive, tmp_path) -> None:
    import json

    from mcap.reader import make_reader

    from kartpilot.record.mcap_export import export_mcap

    export_mcap(drive, tmp_path / "drive.mcap")
    recorded = RecordingReader(drive).scans("lidar")
    with (tmp_path / "drive.mcap").open("rb") as handle:
        read = [(schema.name, json.loads(message.data)) for schema, channel, message in
                make_reader(handle).iter_messages(topics=["/lidar/scan"])]
    assert len(read) == len(recorded) and {name for name, _ in read} == {"foxglove.LaserScan"}
    for (_, message), scan in zip(read, recorded, strict=True):
        ranges = np.array([np.nan if r is None else r for r in message["ranges"]], np.float32)
        assert message["timestamp"]["sec"] * 10**9 + message["timestamp"]["nsec"] == scan.stamp_ns
        assert np.array_equal(ranges, scan.ranges_m, equal_nan=True)
        assert message["start_angle"] == pytest.approx(scan.angle_min_rad) and message["frame_id"] == "lidar"


def test_a_bag_with_a_laser_scan_from_another_tool_imports_and_replays(tmp_path) -> None:
    """A team's ROS 2 bag: one camera, and an RPLIDAR's /scan in frame laser, mounted 1.2 m ahead of base_link, 0.25
    m up, turned round (the sensor's cable to the back), ranges of inf and 0 where it saw nothing, no intensities:
    the LiDAR is named lidar, its mount is the transform's, and a replay hands its sweeps to the frame sets."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    from kartpilot.record.rosbag import import_bag

    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types

    def header(stamp_ns: int, frame: str):
        return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](
            sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id=frame)

    laser = t["geometry_msgs/msg/TransformStamped"](
        header=header(0, "base_link"), child_frame_id="laser", transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](1.2, 0.0, 0.25),
            rotation=t["geometry_msgs/msg/Quaternion"](0.0, 0.0, 1.0, 0.0)))
    messages = [(0, "/tf_static", "tf2_msgs/msg/TFMessage", t["tf2_msgs/msg/TFMessage"](transforms=[laser]))]
    image = np.full((48, 64, 3), 90, np.uint8)
    for k in range(6):
        stamp = 10**9 + k * 100_000_000
        messages.append((stamp, "/camera/image_raw", "sensor_msgs/msg/Image", t["sensor_msgs/msg/Image"](
            header=header(stamp, "camera"), height=48, width=64, encoding="bgr8", is_bigendian=0, step=192,
            data=image.ravel())))
        messages.append((stamp, "/camera/camera_info", "sensor_msgs/msg/CameraInfo", t["sensor_msgs/msg/CameraInfo"](
            header=header(stamp, "camera"), height=48, width=64, distortion_model="plumb_bob", d=np.zeros(5),
            k=np.array([50.0, 0, 31.5, 0, 50.0, 23.5, 0, 0, 1]), r=np.eye(3).ravel(),
            p=np.array([50.0, 0, 31.5, 0, 0, 50.0, 23.5, 0, 0, 0, 1, 0]), binning_x=0, binning_y=0,
            roi=t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False))))
        ranges = np.full(360, np.inf, np.float32)
        ranges[170:190] = 2.0 + 0.01 * k
        ranges[0] = 0.0  # an RPLIDAR driver's "nothing"
        messages.append((stamp + 5_000_000, "/scan", "sensor_msgs/msg/LaserScan", t["sensor_msgs/msg/LaserScan"](
            header=header(stamp + 5_000_000, "laser"), angle_min=-math.pi, angle_max=math.pi - math.radians(1.0),
            angle_increment=math.radians(1.0), time_increment=1e-4, scan_time=0.1, range_min=0.15, range_max=12.0,
            ranges=ranges, intensities=np.zeros(0, np.float32))))
    with Writer(tmp_path / "team", version=9) as writer:
        connections = {}
        for stamp, topic, msgtype, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], stamp, store.serialize_cdr(message, msgtype))
    result = import_bag(tmp_path / "team", tmp_path / "imported")
    assert result.scans == {"lidar": 6} and "/scan" not in {topic for topic, _, _ in result.unmapped}
    reader = RecordingReader(tmp_path / "imported")
    mount = reader.lidars["lidar"]
    assert (mount.x_m, mount.z_m) == pytest.approx((1.2, 0.25)) and abs(mount.yaw_rad) == pytest.approx(math.pi)
    sweep = reader.scans("lidar")[0]
    assert np.count_nonzero(np.isfinite(sweep.ranges_m)) == 20 and not sweep.intensities.any()
    handed = []
    source = RecordingFrameSource(tmp_path / "imported")
    while (frames := source.read()) is not None:
        handed += [scan.stamp_ns for scan in frames.scans.values()]
    assert handed == [s.stamp_ns for s in reader.scans("lidar")][:5]  # the last sweep came after the last frame


def test_the_recording_s_info_and_the_monitor_show_the_lidar_s_rate(drive, capsys) -> None:
    from kartpilot.cli.main import main
    from kartpilot.record.info import recording_info

    info = recording_info(RecordingReader(drive))["lidars"]["lidar"]
    assert info["sweeps"] == 20 and info["rate_hz"] == pytest.approx(10.0) and info["frozen"] == 0
    assert info["mount"]["x_m"] == pytest.approx(1.45)
    assert main(["lidar", "monitor", "--recording", str(drive)]) == 0
    assert "lidar: 20 sweeps, 10.00 Hz" in capsys.readouterr().out


def test_the_rerun_view_of_a_recording_shows_every_sweep(drive, tmp_path) -> None:
    from rerun.chunk import RrdReader

    from kartpilot.record.rerun_view import view_recording

    view_recording(drive, tmp_path / "drive.rrd")
    rows = sum(chunk.num_rows for chunk in RrdReader(str(tmp_path / "drive.rrd")).store().stream()
               if str(chunk.entity_path) == "/lidar/lidar" and not chunk.is_static)
    assert rows == len(RecordingReader(drive).scans("lidar")) == 20


def test_the_rerun_view_lays_the_sweeps_on_the_bird_s_eye_view(drive, tmp_path) -> None:
    """Issue 58: the scan over what the camera sees. Each frame's centre image on the ground, and each sweep's
    returns on it through the LiDAR's mount: a return 10 m ahead of the sensor and 1 m to its left is drawn 11.45 m
    ahead of the rear axle (the mount 1.45 m ahead), 1 m left of the view's middle column."""
    from rerun.chunk import RrdReader

    from kartpilot.record.rerun_view import ViewConfig, birdseye_view_grid, scan_on_birdseye, view_recording

    reader = RecordingReader(drive)
    config = ViewConfig()
    grid = birdseye_view_grid(reader.cameras["center"], config)
    assert grid is not None
    pixel = scan_on_birdseye(np.array([[10.0, 1.0]]), reader.lidars["lidar"], grid)[0]
    resolution = config.birdseye_resolution_m
    assert pixel == pytest.approx([(config.birdseye_side_m - 1.0) / resolution,
                                   (config.birdseye_ahead_m - 11.45) / resolution])
    unmounted = replace(reader.cameras["center"], pose_body_cam=tuple(map(tuple, np.eye(4))))
    assert birdseye_view_grid(unmounted, config) is None  # a camera with no mount lays nothing on the ground

    view_recording(drive, tmp_path / "drive.rrd")
    rows: dict[str, int] = {}
    for chunk in RrdReader(str(tmp_path / "drive.rrd")).store().stream():
        if not chunk.is_static:
            rows[str(chunk.entity_path)] = rows.get(str(chunk.entity_path), 0) + chunk.num_rows
    assert rows["/birdseye/lidar"] == len(reader.scans("lidar")) == 20
    assert rows["/birdseye"] == len(reader.frames("center"))

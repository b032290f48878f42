"""Objects and free space from the LiDAR's sweep (issue 58), on the simulator's scans of the 2026 kart (its LiDAR
on the nose, 0.30 m up) where the truth is known: a car's place and width, a walking person's speed while the kart
drives, the lane's free length ahead, the side strip clear or not, and the camera's detection located by the scan."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand, LaserScan, LidarMount
from kartpilot.core.vehicle import get_vehicle
from kartpilot.perception.objects import Detection
from kartpilot.perception.scan import (
    ScanConfig,
    ScanTracker,
    cluster_scan,
    corridor_free_m,
    locate_detections,
    scan_points_body,
    side_clear,
)
from kartpilot.sim.lidar import LidarConfig
from kartpilot.sim.simulator import SimConfig, Simulator
from kartpilot.sim.track import Prop

MOUNT = get_vehicle("sdc-kart-2026").lidar
assert MOUNT is not None


def _sim(props: tuple[Prop, ...], **lidar) -> Simulator:
    return Simulator(SimConfig(track="straight20", vehicle="sdc-kart-2026", render_images=False, camera_rate_hz=10.0,
                               max_time_s=10.0, props=props, lidar=LidarConfig(**lidar)))


def _cluster_near(clusters, x: float, y: float):
    return min(clusters, key=lambda k: math.hypot(k.centre_xy_m[0] - x, k.centre_xy_m[1] - y))


def test_a_car_ahead_is_one_cluster_as_wide_as_the_car_where_the_track_put_it() -> None:
    """The car's rear 8.65 m ahead of the sensor (its centre at 14 m along straight20, the kart's rear axle at
    2 m, the sensor 1.45 m ahead of it), without and with the sensor's noise: one cluster, its nearest point on the
    rear face (nearer by the noise at most), its rectangle the car's width (1.7 m, less up to a beam's spacing at
    each side), its centre on the lane's centre line."""
    for noise_m, noise_share in ((0.0, 0.0), (0.005, 0.005)):
        sim = _sim((Prop(kind="car", s_m=14.0, offset_m=0.0),), dropout={}, noise_m=noise_m, noise_share=noise_share)
        frames = sim.read()
        assert frames is not None and set(frames.scans) == {"lidar"}
        clusters = cluster_scan(frames.scans["lidar"], MOUNT)
        car = _cluster_near(clusters, 10.1, 0.0)
        rear_x = 14.0 - 2.0 - 3.8 / 2
        spacing = math.radians(0.45) * (rear_x - MOUNT.x_m)  # between two beams on the car's rear
        sigma = noise_m + noise_share * rear_x
        print(f"noise {sigma:.3f} m: {len(clusters)} clusters; the car's nearest {car.nearest_xy_m}, centre "
              f"{car.centre_xy_m}, {car.length_m:.2f} x {car.width_m:.2f} m from {car.points} returns (its rear at "
              f"x {rear_x:.2f} m, 1.7 m wide)")
        assert len(clusters) == 1 and car.points >= 15
        # the nearest of its returns: the rear face, less the sensor's noise at most (a nearer-than-true stop)
        assert rear_x - 3 * sigma - 0.01 <= car.nearest_xy_m[0] <= rear_x + 0.01
        assert abs(car.centre_xy_m[1]) < 0.05 + sigma
        assert 1.7 - 2 * spacing - 0.01 <= max(car.length_m, car.width_m) <= 1.7 + 0.01
        assert min(car.length_m, car.width_m) <= 0.02 + 6 * sigma  # the rear face alone: a line


def test_the_ring_s_seam_does_not_split_an_object_behind_the_sensor() -> None:
    """A wall straight behind the sensor lies across the sweep's first and last beams (-180 and +179.55 deg): one
    cluster, not two."""
    step = math.radians(0.45)
    angles = -math.pi + step * np.arange(800)
    ranges = np.full(800, np.nan, np.float32)
    behind = np.abs(np.abs(angles) - math.pi) < math.radians(20)
    ranges[behind] = (2.0 / np.abs(np.cos(angles[behind]))).astype(np.float32)
    scan = LaserScan(0, float(angles[0]), step, 1e-4, 0.1, 0.15, 12.0, ranges, np.ones(800, np.float32))
    clusters = cluster_scan(scan, LidarMount(0.0, 0.0, 0.3))
    assert len(clusters) == 1 and clusters[0].points == int(behind.sum())
    assert clusters[0].centre_xy_m[0] == pytest.approx(-2.0, abs=0.01)


def test_a_walking_person_s_speed_comes_out_while_the_kart_drives() -> None:
    """A person crossing the road 11 m along at 1.2 m/s while the kart drives at up to 2 m/s, and a car standing
    beside the lane: the tracker, given the kart's true pose, gives the person about 1.2 m/s across the road and
    the car less than 0.3 m/s, once each is tracked for half a second."""
    person = Prop(kind="person", s_m=11.0, offset_m=-4.0, walk_to_offset_m=4.0, walk_start_s=0.0,
                  walk_speed_mps=1.2)
    sim = _sim((person, Prop(kind="car", s_m=9.0, offset_m=3.5)), dropout={})
    tracker = ScanTracker()
    walking, standing = [], []
    while not sim.done and sim.time_s < 5.0:
        frames = sim.read()
        assert frames is not None
        if "lidar" in frames.scans:
            scan = frames.scans["lidar"]
            objects = tracker.update(scan.stamp_ns, cluster_scan(scan, MOUNT),
                                     (sim.state.x_m, sim.state.y_m, sim.state.yaw_rad))
            for obj in (o for o in objects if o.age >= 5):
                at_person = abs(obj.cluster.centre_xy_m[0] - (11.0 - sim.state.x_m)) < 0.6
                (walking if at_person else standing).append(obj.velocity_mps)
        sim.send(ActuatorCommand(frames.stamp_ns, 0.0, 0.5 if sim.state.vx_mps < 2.0 else 0.0, 0.0))
    across = np.array(walking)[:, 1]
    still = np.hypot(*np.array(standing).T)
    print(f"the person across the road: median {np.median(across):.2f} m/s over {len(across)} sweeps; the car "
          f"standing: median {np.median(still):.2f}, max {still.max():.2f} m/s over {len(still)}; the kart "
          f"reached {sim.state.vx_mps:.1f} m/s")
    assert len(across) >= 20 and np.median(across) == pytest.approx(1.2, abs=0.2)
    assert len(still) >= 20 and np.median(still) < 0.3


def test_the_lane_ahead_is_free_up_to_the_car_and_the_strip_beside_is_clear_or_not() -> None:
    sim = _sim((Prop(kind="car", s_m=14.0, offset_m=0.0),), dropout={}, noise_m=0.0, noise_share=0.0)
    frames = sim.read()
    assert frames is not None
    points, _ = scan_points_body(frames.scans["lidar"], MOUNT)
    free = corridor_free_m(points, -0.8, 0.8, x_from_m=1.5)
    assert free == pytest.approx(14.0 - 2.0 - 1.9 - 1.5, abs=0.01)  # the car's rear, from the kart's front
    assert corridor_free_m(points, 2.0, 4.0, x_from_m=1.5) == math.inf  # the next lane: nothing in it
    assert side_clear(points, 0.0, 3.0, 1.0, 4.0)  # beside the kart on the left: clear
    assert not side_clear(points, 9.0, 12.0, -1.0, 1.0)  # where the car stands: not


def test_a_camera_detection_takes_the_lidar_s_distance_along_its_bearing() -> None:
    """The camera put the car 1.5 m too far (a flat-road guess under a tilted kart): the cluster along the same
    bearing corrects it to the scan's distance; a detection with no cluster along its bearing is left as it was."""
    sim = _sim((Prop(kind="car", s_m=14.0, offset_m=0.0),), dropout={}, noise_m=0.0, noise_share=0.0)
    frames = sim.read()
    assert frames is not None
    clusters = cluster_scan(frames.scans["lidar"], MOUNT)
    seen = Detection("car", (300, 200, 400, 260), 0.9, distance_m=11.6, lateral_m=0.1)
    alone = Detection("person", (10, 200, 30, 260), 0.9, distance_m=6.0, lateral_m=5.5)
    located = locate_detections([seen, alone], clusters, MOUNT)
    print(f"camera {seen.distance_m} m -> lidar {located[0].distance_m:.2f} m ({located[0].source})")
    assert located[0].distance_m == pytest.approx(10.1, abs=0.05) and located[0].source == "classical+lidar"
    assert located[1] == alone


def test_nothing_in_range_and_too_few_returns_give_no_objects() -> None:
    scan = LaserScan(0, -math.pi, math.radians(0.45), 1e-4, 0.1, 0.15, 12.0, np.full(800, np.nan, np.float32),
                     np.zeros(800, np.float32))
    assert cluster_scan(scan, MOUNT) == []
    two = scan.ranges_m.copy()
    two[400:402] = 3.0
    assert cluster_scan(replace(scan, ranges_m=two), MOUNT, ScanConfig(min_points=3)) == []


def test_a_lidar_that_does_not_see_what_the_camera_sees_is_said_to_disagree_until_it_does_again() -> None:
    """A mount knocked so that the plane passes over the car: the camera's car within reach has no return along its
    bearing frame after frame; after ten such objects, under a fifth placed, the LiDAR disagrees (and the rules
    go camera-only); once half again are placed, it agrees. Paint, far things and things a plane misses (a sign)
    do not count."""
    from kartpilot.perception.scan import LidarAgreement

    agreement = LidarAgreement(reach_m=10.0)
    unplaced = Detection("car", (0, 0, 1, 1), 0.9, distance_m=8.0, lateral_m=0.0)
    placed = Detection("car", (0, 0, 1, 1), 0.9, distance_m=8.0, lateral_m=0.0, source="classical+lidar")
    ignored = [Detection("stop_line", (0, 0, 1, 1), 0.9, distance_m=5.0, lateral_m=0.0),
               Detection("car", (0, 0, 1, 1), 0.9, distance_m=15.0, lateral_m=0.0),
               Detection("speed_sign", (0, 0, 1, 1), 0.9, "10", distance_m=6.0, lateral_m=2.0)]
    for _ in range(20):
        assert agreement.update(ignored) == ""
    for k in range(9):
        assert agreement.update([unplaced]) == "", k  # not yet ten counted
    problem = agreement.update([unplaced])
    assert problem.startswith("disagrees with the camera: 10 of the last 10 objects")
    for _ in range(5):
        assert agreement.update([placed]) != ""  # 5 of 15: still under a half
    for _ in range(5):
        agreement.update([placed])
    assert agreement.update([placed]) == ""  # 11 of the last 20 placed
    with pytest.raises(ConfigError):
        LidarAgreement(reach_m=10.0, min_share=0.6, recover_share=0.5)

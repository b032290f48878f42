"""Monocular VO with ground-plane scale: the pure pieces on synthetic geometry, the whole on a simulated
drive with ground truth (a kart's camera, 0.6 m high and pitched down), and on KITTI 06 (real data)."""

import itertools
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from tests.conftest import KART, GreyFrames, road_texture, road_view

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import mount_pose, transform_points
from kartpilot.core.types import FrameSet
from kartpilot.core.vehicle import get_vehicle
from kartpilot.odometry.mono_vo import (
    GroundConfig,
    MonoVO,
    MonoVOConfig,
    arc_step,
    beyond_ground_mask,
    fit_ground_homography,
    ground_normal_prior,
    ground_region,
    relative_pose,
    rotation_only,
)

CAMERA = PinholeCamera(700.0, 700.0, 480.0, 270.0, 960, 540)
LEVEL = PinholeCamera(300.0, 300.0, 159.5, 119.5, 320, 240)  # no mount: level, the ground starts below row 120


def _motion(yaw_deg: float, forward_m: float) -> tuple[np.ndarray, np.ndarray]:
    """R, t taking points of camera 0 into camera 1 for a camera turning and moving forward (z)."""
    yaw = math.radians(yaw_deg)
    rotation = np.array([[math.cos(yaw), 0, math.sin(yaw)], [0, 1, 0], [-math.sin(yaw), 0, math.cos(yaw)]])
    return rotation, -rotation @ np.array([0.0, 0.0, forward_m])


def _project(points: np.ndarray) -> np.ndarray:
    return CAMERA.project(points).astype(np.float32)


def test_the_plane_s_homography_gives_the_metric_scale_despite_noise_and_points_off_the_road():
    rng = np.random.default_rng(3)
    height, tilt = 1.2, math.radians(3.0)
    normal = np.array([0.0, math.cos(tilt), math.sin(tilt)])  # the camera pitched a little
    # road points 4 to 25 m ahead, on the plane normal . X = height
    ahead, lateral = rng.uniform(4, 25, 300), rng.uniform(-4, 4, 300)
    road = np.stack([lateral, (height - normal[2] * ahead) / normal[1], ahead], axis=1)
    clutter = np.stack([rng.uniform(-4, 4, 120), rng.uniform(-0.5, 0.8, 120), rng.uniform(5, 25, 120)], axis=1)
    points = np.vstack([road, clutter])  # 29 % of the points are parked cars and kerbs, not road
    rotation, t = _motion(1.5, 1.3)
    p0 = _project(points) + rng.normal(0, 0.3, (len(points), 2)).astype(np.float32)
    p1 = _project(points @ rotation.T + t) + rng.normal(0, 0.3, (len(points), 2)).astype(np.float32)
    unit = t / np.linalg.norm(t)
    fit = fit_ground_homography(p0, p1, rotation, unit, CAMERA.matrix, GroundConfig(camera_height_m=height),
                                np.random.default_rng(0), np.array([0.0, 1.0, 0.0]))
    assert fit is not None
    m, inliers = fit
    scale = height * np.linalg.norm(m)
    print(f"scale {scale:.4f} m per unit (true {np.linalg.norm(t):.4f}), {inliers} road inliers")
    assert scale == pytest.approx(np.linalg.norm(t), rel=0.01)
    assert math.degrees(math.acos(abs(m @ normal) / np.linalg.norm(m))) < 1.0
    assert inliers <= 300 + 5


def test_relative_pose_recovers_the_rotation_and_the_direction_of_travel():
    rng = np.random.default_rng(1)
    points = np.stack([rng.uniform(-10, 10, 400), rng.uniform(-3, 2, 400), rng.uniform(5, 40, 400)], axis=1)
    rotation, t = _motion(2.0, 1.0)
    result = relative_pose(_project(points), _project(points @ rotation.T + t), CAMERA.matrix, 1.0, 0.999)
    assert result is not None
    r_est, t_est, inliers = result
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(r_est @ rotation.T)[0])) < 0.05
    assert float(t_est @ (t / np.linalg.norm(t))) > 0.9999 and inliers.sum() > 380


def test_an_arc_step_moves_the_camera_along_the_kart_s_heading_and_turns_it_about_the_vertical():
    mount = mount_pose(1.2, 0.0, 0.6, pitch_down_deg=12.0)
    straight = arc_step(0.0, 0.5, mount)
    assert straight[:3, :3] == pytest.approx(np.eye(3))
    # forward on the body, seen from a camera pitched down: along its optical axis, and up in its image
    pitch = math.radians(12)
    assert straight[:3, 3] == pytest.approx(0.5 * np.array([0.0, -math.sin(pitch), math.cos(pitch)]))
    left = arc_step(math.radians(10), 0.5, mount)
    body = mount @ left @ np.linalg.inv(mount)  # the rear axle's motion, back in body axes
    assert math.degrees(math.atan2(body[1, 0], body[0, 0])) == pytest.approx(10.0)
    assert math.degrees(math.atan2(body[1, 3], body[0, 3])) == pytest.approx(5.0)  # a chord: half the turn
    assert math.hypot(body[0, 3], body[1, 3]) == pytest.approx(0.5) and body[2, 3] == pytest.approx(0.0)
    slipping = mount @ arc_step(math.radians(10), 0.5, mount, math.radians(-2.0)) @ np.linalg.inv(mount)
    assert math.degrees(math.atan2(slipping[1, 0], slipping[0, 0])) == pytest.approx(10.0)  # the same turn
    assert math.degrees(math.atan2(slipping[1, 3], slipping[0, 3])) == pytest.approx(3.0)  # the rear slid outward


@pytest.mark.parametrize(("yaw_deg", "length_m"), [(0.0, 0.5), (-1.1, 0.5), (2.5, 0.3), (0.4, 1.2), (0.0, 0.0)])
def test_the_arc_step_is_found_by_aligning_the_road(yaw_deg, length_m):
    texture = road_texture(4)
    step = arc_step(math.radians(yaw_deg), length_m, np.eye(4))  # the rear axle's own motion
    before, after = (road_view(texture, pose, 0.01) for pose in (np.eye(4), step))
    vo = MonoVO(KART, MonoVOConfig(ground=GroundConfig(camera_height_m=0.6)))
    assert vo.process(FrameSet(0, 0, {"left": before})).status == "init"
    estimate = vo.process(FrameSet(1, 10**8, {"left": after}))
    assert estimate.status == "ok"
    body = KART.pose_body_cam_array @ estimate.pose_world_cam @ np.linalg.inv(KART.pose_body_cam_array)
    print(f"true {yaw_deg:+.2f} deg {length_m:.3f} m; found {math.degrees(math.atan2(body[1, 0], body[0, 0])):+.3f} "
          f"deg {math.hypot(body[0, 3], body[1, 3]):.4f} m")
    assert math.degrees(math.atan2(body[1, 0], body[0, 0])) == pytest.approx(yaw_deg, abs=0.05)
    assert math.hypot(body[0, 3], body[1, 3]) == pytest.approx(length_m, abs=0.01 + 0.01 * length_m)


def _straight_drive(frames: int, step_m: float, frozen: int | None = None) -> list[FrameSet]:
    """A kart's centre camera driving straight over a textured road at 10 Hz; frame ``frozen`` repeats the
    frame before it (a camera that delivered the same image twice)."""
    texture = road_texture(5)
    views = []
    for k in range(frames):
        body = np.eye(4)
        body[0, 3] = step_m * (k - 1 if k == frozen else k)
        views.append(FrameSet(k, k * 10**8, {"left": road_view(texture, body, 0.01)}))
    return views


def _body_distance(camera: PinholeCamera, pose_world_cam: np.ndarray) -> float:
    body = camera.pose_body_cam_array @ pose_world_cam @ np.linalg.inv(camera.pose_body_cam_array)
    return float(np.hypot(body[0, 3], body[1, 3]))


def test_a_frozen_frame_at_speed_is_bridged_not_taken_for_a_stop():
    """At 5 m/s the road standing still for a frame is no motion the kart can make (it would brake at 50 m/s^2),
    nor is the double step after it: both frames are bridged with the last step and counted, and the drive's
    length stays right."""
    vo = MonoVO(KART, MonoVOConfig(ground=GroundConfig(camera_height_m=0.6)))
    estimates = [vo.process(frames) for frames in _straight_drive(8, 0.5, frozen=5)]
    assert [e.status for e in estimates[1:]] == ["ok"] * 4 + ["bridged"] * 2 + ["ok"]
    assert all("implausible" in e.reason for e in estimates[5:7])
    assert vo.bridged == 2
    assert _body_distance(KART, estimates[-1].pose_world_cam) == pytest.approx(3.5, abs=0.05)


def test_the_pitch_measured_on_the_road_corrects_a_mis_stated_mount():
    """The mount says the camera is pitched down 11 degrees; it is 12. Trusting the mount, every step is 9 %
    long; measuring the pitch on the road (``arc_pitch_every``) brings the steps back to the truth."""
    told = PinholeCamera(480.0, 480.0, 319.5, 239.5, 640, 480,
                         pose_body_cam=mount_pose(1.2, 0.0, 0.6, pitch_down_deg=11.0))
    drive = _straight_drive(16, 0.5)

    def last_steps_m(config: MonoVOConfig) -> np.ndarray:
        vo = MonoVO(told, config)
        poses = [vo.process(frames).pose_world_cam for frames in drive]
        return np.array([_body_distance(told, np.linalg.inv(a) @ b) for a, b in itertools.pairwise(poses[-5:])])

    trusted = last_steps_m(MonoVOConfig(ground=GroundConfig(camera_height_m=0.6)))
    measured = last_steps_m(MonoVOConfig(ground=GroundConfig(camera_height_m=0.6), arc_pitch_every=1))
    print(f"\nsteps of 0.5 m: mount trusted {np.round(trusted, 3)}, plane measured {np.round(measured, 3)}")
    assert np.all(np.abs(trusted - 0.5) > 0.03)
    assert np.all(np.abs(measured - 0.5) < 0.01)


def test_a_blank_road_gives_no_arc_step():
    vo = MonoVO(KART, MonoVOConfig(ground=GroundConfig(camera_height_m=0.6)))
    grey = np.full((480, 640), 90, np.uint8)
    vo.process(FrameSet(0, 0, {"left": grey}))
    estimate = vo.process(FrameSet(1, 10**8, {"left": grey}))
    assert estimate.status == "bridged" and "no texture" in estimate.reason


def test_vo_uses_the_arc_for_a_mounted_camera_and_the_general_motion_without_a_mount():
    assert MonoVO(KART, MonoVOConfig(ground=GroundConfig(camera_height_m=0.6))).arc
    assert not MonoVO(CAMERA, MonoVOConfig()).arc
    assert not MonoVO(KART, MonoVOConfig(motion="general", ground=GroundConfig(camera_height_m=0.6))).arc
    with pytest.raises(ConfigError, match=r"mono_vo\.motion"):
        MonoVOConfig(motion="holonomic")  # type: ignore[arg-type]
    for bad in ({"iterations": 0}, {"inlier_px": 0.0}):
        with pytest.raises(ConfigError, match=r"mono_vo\.ground\." + next(iter(bad))):
            GroundConfig(camera_height_m=0.6, **bad)  # type: ignore[arg-type]


def test_the_ground_mask_leaves_out_the_near_ground_only():
    mask = beyond_ground_mask(LEVEL, 8.0)
    # level camera, 8 heights: straight ahead, the ground nearer than that is below 300 / 8 = 37.5 px under
    # the horizon; to the sides the same distance comes sooner
    assert mask[:157].all() and not mask[158:, 159].any() and not mask[170:].any()
    assert beyond_ground_mask(LEVEL, 0.0).all()


def test_the_road_region_follows_the_camera_s_height_and_mount():
    config = GroundConfig(camera_height_m=0.6)
    level = ground_region(CAMERA, ground_normal_prior(CAMERA), config)
    rows = np.flatnonzero(level.any(axis=1))
    # level camera: the ground 15 heights ahead is f / 15 below the principal point
    assert rows[0] == pytest.approx(270 + 700 / 15, abs=1.5) and rows[-1] == 539
    pitched = PinholeCamera(700.0, 700.0, 480.0, 270.0, 960, 540,
                            pose_body_cam=tuple(map(tuple, mount_pose(0.5, 0, 0.6, pitch_down_deg=12.0))))
    prior = ground_normal_prior(pitched)
    assert prior == pytest.approx([0.0, math.cos(math.radians(12)), math.sin(math.radians(12))], abs=1e-9)
    far_point = transform_points(np.linalg.inv(pitched.pose_body_cam_array), np.array([0.5 + 9.0, 0.0, 0.0]))
    far_row = pitched.project(far_point)[0, 1]
    assert np.flatnonzero(ground_region(pitched, prior, config).any(axis=1))[0] == pytest.approx(far_row, abs=1.5)


@pytest.mark.slow
def test_on_a_simulated_kart_drive_the_ground_plane_gives_metres():
    """The SDC kart's centre camera: 0.56 m above the road, pitched down 6.8 degrees, 15 Hz, 5 m/s, 60 m and the
    first bend, with the arc's rear axle slipping as the kart's tyres do and without (the turn is then short).

    A check that the method carries over to another camera, not an accuracy claim: on the simulator's weak
    asphalt texture the end drift varied with the seed (2.9 to 16 % over seeds 1 to 3 on the earlier 0.6 m
    mount), so the bound only catches a broken scale; benchmarks/vo_accuracy.py measures whole drives.
    Through the perfect camera: through the real one the slip's gain in the bend is within the noise (0.48 deg at the
    end with it, 0.24 without, on 2026-11-28). The frames as the drive draws them (the grey images a recording reads
    back, `tests.conftest.GreyFrames`), not written to disk and read again."""
    from kartpilot.core.trajectory import Trajectory
    from kartpilot.eval.trajectory_metrics import evaluate_trajectory
    from kartpilot.runtime.simulate import run_simulation
    from kartpilot.sim.drivers import CenterlineDriverConfig
    from kartpilot.sim.simulator import SimConfig, perfect_camera

    config = SimConfig(track="sdc-assen", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=15.0,
                       max_time_s=12.0, seed=1, effects=perfect_camera())
    frames = GreyFrames("center")
    run = run_simulation(config, "centerline", driver_config=CenterlineDriverConfig(speed_mps=5.0), taps=(frames,))
    camera = get_vehicle("sdc-kart").camera("center")
    images = frames.frames
    truth = run.ground_truth
    config = MonoVOConfig(ground=GroundConfig(camera_height_m=float(camera.pose_body_cam_array[2, 3])))
    results = {}
    for slip in (True, False):
        vo = MonoVO(camera, replace(config, tyre_slip=slip), "center", get_vehicle("sdc-kart"))
        estimates = [vo.process(FrameSet(k, stamp, {"center": image})) for k, (stamp, image) in enumerate(images)]
        estimate = Trajectory.from_poses([e.pose_world_cam for e in estimates],
                                         [e.stamp_ns * 1e-9 for e in estimates])
        results[slip] = metrics = evaluate_trajectory(truth, estimate)
        print(f"\nsdc-kart centre camera, monocular VO, ground-plane scale, tyre slip {slip}\n" + metrics.table())
        assert "ground plane" in estimates[-1].scale_source
        assert vo.bridged <= 5
    assert results[True].end_drift_percent <= 20.0
    # the first bend at 5 m/s: without the rear axle's slip the arc takes the turn short
    assert results[True].end_rotation_deg < results[False].end_rotation_deg


def test_a_rotation_alone_explains_views_without_parallax_and_not_views_with_it():
    """``rotation_only``: a camera that only turned is explained, and the turn found; one that drove a metre
    past near points is not (its translation shows)."""
    k = np.array([[400.0, 0, 320], [0, 400.0, 240], [0, 0, 1]])
    rng = np.random.default_rng(3)
    points = np.c_[rng.uniform(-6, 6, 300), rng.uniform(-2, 1, 300), rng.uniform(3, 30, 300)]

    def seen(rotation: np.ndarray, position: np.ndarray) -> np.ndarray:
        local = (points - position) @ rotation  # the world seen from a camera turned by ``rotation``
        pixels = local @ k.T
        return pixels[:, :2] / pixels[:, 2:] + rng.normal(0, 0.3, (len(points), 2))

    turn = Rotation.from_euler("y", 3.0, degrees=True).as_matrix()
    first = seen(np.eye(3), np.zeros(3))
    found, explained = rotation_only(first, seen(turn, np.zeros(3)), k, 1.0)
    angle = np.degrees(Rotation.from_matrix(found @ turn).magnitude())  # x_second = turn^T x_first
    print(f"turned 3 deg in place: {explained.mean():.0%} explained, rotation off by {angle:.3f} deg")
    assert explained.mean() > 0.9 and angle < 0.05
    _, explained = rotation_only(first, seen(np.eye(3), np.array([0.0, 0.0, 1.0])), k, 1.0)
    print(f"drove 1 m: {explained.mean():.0%} explained")
    assert explained.mean() < 0.5

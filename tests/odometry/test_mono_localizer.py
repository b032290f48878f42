"""One camera on a reference: the pieces of the fusion of monocular VO and place fixes, with arrays."""

import math

import numpy as np
import pytest

from kartpilot.core.geometry import mount_pose
from kartpilot.odometry.mono_localizer import FixFilter, MonoLocalizerConfig, along_arc, place_ground_poses


def test_a_step_keeps_its_length_and_turn_and_loses_its_sideways_part():
    forward, sideways, turn = along_arc((0.5, 0.2, 0.1))
    assert math.hypot(forward, sideways) == pytest.approx(math.hypot(0.5, 0.2))
    assert sideways / forward == pytest.approx(math.tan(0.05))  # the chord of an arc turning 0.1 rad
    assert turn == 0.1
    assert along_arc((-0.3, 0.0, 0.0))[0] == pytest.approx(-0.3)  # backwards stays backwards


def test_camera_poses_become_the_rear_axle_on_the_ground_in_the_first_place_s_frame():
    body_cam = mount_pose(1.2, 0.0, 0.6, 0.0, 12.0, 0.0)  # the SDC kart's centre camera
    world_body = np.eye(4)
    world_body[:3, 3] = (5.0, 3.0, 0.0)
    yaw = math.radians(30)
    turned = world_body.copy()
    turned[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    turned[0, 3] += 2.0
    ground = place_ground_poses(np.stack([world_body @ body_cam, turned @ body_cam]), body_cam, world_body @ body_cam)
    assert np.allclose(ground[0], 0.0, atol=1e-9)
    assert np.allclose(ground[1], (2.0, 0.0, yaw), atol=1e-9)


def _noise(sigma_m: float, sigma_rad: float) -> np.ndarray:
    return np.diag([sigma_m ** 2, sigma_m ** 2, sigma_rad ** 2])


def test_fixes_teach_the_filter_vo_s_scale_and_hold_the_position():
    """VO says 0.7 m where the kart drives 1 m; fixes with 0.5 m noise every metre: the filter learns the
    factor 1/0.7 and keeps the position within the fixes' noise."""
    config = MonoLocalizerConfig(scale_sigma=0.5)
    rng = np.random.default_rng(0)
    fusion = FixFilter(config)
    fusion.place(np.zeros(3), _noise(0.5, 0.1))
    errors = []
    for k in range(1, 121):
        fusion.predict((0.7, 0.0, 0.0))
        truth = np.array([float(k), 0.0, 0.0])
        assert fusion.correct(truth + np.r_[rng.normal(0, 0.5, 2), 0.0], _noise(0.5, 0.1))
        errors.append(float(np.hypot(*(fusion.state[:2] - truth[:2]))))
    assert fusion.scale == pytest.approx(1 / 0.7, rel=0.05)
    assert np.mean(errors[-40:]) < 0.3


def test_a_fix_far_outside_the_gate_is_rejected_and_changes_nothing():
    fusion = FixFilter(MonoLocalizerConfig())
    fusion.place(np.zeros(3), _noise(0.3, 0.05))
    fusion.predict((1.0, 0.0, 0.0))
    before = fusion.state.copy(), fusion.covariance.copy()
    assert not fusion.correct(np.array([25.0, 0.0, 0.0]), _noise(0.5, 0.1))
    assert np.array_equal(fusion.state, before[0]) and np.array_equal(fusion.covariance, before[1])


def test_a_wild_heading_is_dropped_and_the_position_still_used():
    fusion = FixFilter(MonoLocalizerConfig())
    fusion.place(np.zeros(3), _noise(0.3, 0.02))
    fusion.predict((1.0, 0.0, 0.0))
    assert fusion.correct(np.array([1.5, 0.0, 1.0]), _noise(0.3, 0.05))
    assert fusion.state[0] > 1.1  # pulled toward the fix's position
    assert abs(fusion.state[2]) < 0.01  # the heading one radian off was not believed


def test_the_wheels_measured_distance_teaches_the_scale_between_fixes():
    """VO says 0.8 m where the wheels measured 1 m (with 0.05 m noise): without any fix after the first,
    the scale factor converges to 1.25 and the position follows the wheels, not VO."""
    rng = np.random.default_rng(1)
    fusion = FixFilter(MonoLocalizerConfig())
    fusion.place(np.zeros(3), _noise(0.1, 0.02))
    for _ in range(60):
        fusion.predict((0.8, 0.0, 0.0))
        fusion.correct_distance(0.8, 1.0 + rng.normal(0, 0.05), 0.05)
    print(f"scale learnt from the wheels: {fusion.scale:.3f} (truth 1.25)")
    assert fusion.scale == pytest.approx(1.25, rel=0.02)
    assert fusion.state[0] > 0.9 * 60  # without the wheels, 0.8 * 60 = 48 m
    standing = fusion.state.copy()
    fusion.correct_distance(0.0, 0.0, 0.05)  # standing still says nothing about the scale
    assert np.array_equal(fusion.state, standing)

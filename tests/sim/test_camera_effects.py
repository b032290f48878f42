"""What a real camera adds to a rendering (kartpilot.sim.camera_effects): each effect's size against what the
camera's motion, light and lens predict, and the simulator delivering them."""

import math
from dataclasses import replace

import numpy as np
import pytest

from kartpilot.core.vehicle import get_vehicle
from kartpilot.eval.camera_realism import vertical_offset_px
from kartpilot.sim.camera_effects import (
    add_shot_noise,
    auto_exposure_gain,
    body_motion,
    jpeg_roundtrip,
    motion_maps,
    moving_exposure,
    shift_rows,
)
from kartpilot.sim.simulator import CameraEffectsConfig, SimConfig, Simulator, perfect_camera, real_camera

CAMERA = get_vehicle("sdc-kart").camera("center")  # 848x480, f 640 px, 0.56 m up, 6.8 deg down, 1.2 m ahead
ROWS = np.arange(CAMERA.height_px)
U, V = np.meshgrid(np.arange(CAMERA.width_px, dtype=np.float32), ROWS.astype(np.float32))


def test_shot_noise_grows_with_the_light_and_keeps_its_level() -> None:
    """A sensor counts photons: the noise's variance grows with the level, so the sunlit road is noisier than its
    shade (at strength 0.5: sigma 3.2 grey levels at 20, 10 at 200)."""
    unit = np.random.default_rng(0).standard_normal((64, 64, 3), dtype=np.float32)
    dark = add_shot_noise(np.full((64, 64, 3), 20, np.uint8), 0.5, unit).astype(np.float64)
    bright = add_shot_noise(np.full((64, 64, 3), 200, np.uint8), 0.5, unit).astype(np.float64)
    assert abs(dark.mean() - 20) < 0.3 and abs(bright.mean() - 200) < 0.5
    assert dark.std() == pytest.approx(np.sqrt(0.5 * 20), rel=0.1)
    assert bright.std() == pytest.approx(np.sqrt(0.5 * 200), rel=0.1)


def test_an_mjpg_frame_loses_detail_with_its_quality() -> None:
    image = np.random.default_rng(1).integers(0, 256, (48, 64, 3), dtype=np.uint8)  # fine texture: smeared first
    errors = [float(np.abs(jpeg_roundtrip(image, q).astype(int) - image).mean()) for q in (100, 80, 20)]
    assert jpeg_roundtrip(image, 80).shape == image.shape and jpeg_roundtrip(image, 80).dtype == np.uint8
    assert 0 < errors[0] < errors[1] < errors[2]


def test_the_body_moves_on_an_arc() -> None:
    """A quarter circle of radius 2 m at 1 m/s and 0.5 rad/s: 2 m ahead, 2 m to the left, facing left."""
    pose = body_motion(1.0, 0.5, math.pi)
    assert pose[:3, 3] == pytest.approx([2.0, 2.0, 0.0], abs=1e-9)
    assert math.atan2(pose[1, 0], pose[0, 0]) == pytest.approx(math.pi / 2)
    assert body_motion(2.0, 0.0, -0.5)[:3, 3] == pytest.approx([-1.0, 0.0, 0.0])


def test_a_camera_that_stands_still_sees_the_rendering() -> None:
    map_x, map_y = motion_maps(CAMERA, 0.0, 0.0, np.full(CAMERA.height_px, 0.02))
    assert np.abs(map_x - U).max() < 1e-3 and np.abs(map_y - V).max() < 1e-3


def test_a_rolling_shutter_leans_a_turning_camera_s_verticals() -> None:
    """Turning left at 0.5 rad/s with rows read over 20 ms: above the horizon (the scene at infinity) the first
    row sees the scene as it was 10 ms earlier, fx * 0.5 * 0.01 = 3.2 px to the left of where it is now, the
    middle row as now; the last row, on the near road, further the other way (the camera 1.2 m ahead of the rear
    axle also slides sideways, and the road is 1 m away)."""
    readout = (ROWS / (CAMERA.height_px - 1) - 0.5) * 0.02
    map_x, _ = motion_maps(CAMERA, 0.0, 0.5, readout)
    centre = CAMERA.width_px // 2
    shift = map_x[:, centre] - centre
    assert shift[0] == pytest.approx(CAMERA.fx_px * 0.5 * 0.01, rel=0.05)
    assert abs(shift[CAMERA.height_px // 2]) < 0.1
    assert shift[-1] < -CAMERA.fx_px * 0.5 * 0.01
    assert np.all(np.diff(shift) <= 0)  # the vertical leans one way, row after row


def test_driving_ahead_moves_the_road_not_the_sky() -> None:
    """5 cm ahead (5 m/s, 10 ms): the near road, 1.08 m ahead at the last row, is 1.13 m ahead at the instant
    rendered, so it is higher in that image; the sky does not move."""
    map_x, map_y = motion_maps(CAMERA, 5.0, 0.0, np.full(CAMERA.height_px, 0.01))
    centre = CAMERA.width_px // 2
    assert abs(map_y[0, centre] - 0) < 1e-3 and abs(map_x[0, centre] - centre) < 1e-3
    assert -16.0 < map_y[-1, centre] - (CAMERA.height_px - 1) < -10.0
    # straight ahead stays straight ahead
    assert abs(map_x[-1, centre] - centre) < 0.6


def test_motion_blur_smears_the_near_road_along_the_motion() -> None:
    """A row of sharp stripes across the road: blurred by driving ahead over 8 ms, hardly by standing still."""
    image = np.zeros((CAMERA.height_px, CAMERA.width_px), np.uint8)
    image[400::6] = 255
    still = moving_exposure(image, CAMERA, 0.0, 0.0, 0.0, 0.008, 4)
    moving = moving_exposure(image, CAMERA, 6.0, 0.0, 0.0, 0.008, 4)
    assert np.array_equal(still, image)
    sharp = float(np.abs(np.diff(image[400:470, 424].astype(int))).mean())
    blurred = float(np.abs(np.diff(moving[400:470, 424].astype(int))).mean())
    assert blurred < 0.6 * sharp
    assert abs(float(moving[380:].mean()) - float(image[380:].mean())) < 3.0  # the light is kept


def test_the_auto_exposure_settles_with_its_time_constant() -> None:
    """The light halves at once: the gain starts where it was and closes 63 % of the way in one time constant."""
    gain, dt = 1.0, 0.02
    for _ in range(round(0.3 / dt)):
        gain = auto_exposure_gain(gain, 55.0, 110.0, dt, 0.3)
    assert gain == pytest.approx(1.0 + (1 - math.exp(-1)) * 1.0, abs=0.01)
    assert auto_exposure_gain(1.0, 1.0, 110.0, dt, 0.0) == 4.0  # the sensor's limit, not infinity


def test_a_rectification_residual_moves_the_rows_by_a_fraction_of_a_pixel() -> None:
    ramp = np.tile(np.arange(100, dtype=np.uint8)[:, None] * 2, (1, 8))
    assert float(shift_rows(ramp, 0.5)[50, 0]) == pytest.approx(99.0, abs=0.51)  # row 50 now shows row 49.5
    assert np.array_equal(shift_rows(ramp, 0.0), ramp)


def test_the_simulator_delivers_its_frames_through_the_sensor_and_the_mjpg_stream() -> None:
    """On by default (the kart presets' real camera), off in the perfect camera; on, the frames the stack reads are
    the compressed, noisier ones, of the camera's own size."""
    assert CameraEffectsConfig() == real_camera("sdc-kart") == real_camera("rc-kart")
    assert CameraEffectsConfig().jpeg_quality > 0 and CameraEffectsConfig().rolling_shutter_s > 0
    perfect = perfect_camera()
    assert (perfect.jpeg_quality, perfect.shot_noise, perfect.rolling_shutter_s, perfect.exposure_blur_samples,
            perfect.auto_exposure_s, perfect.rectification_residual_px) == (0, 0.0, 0.0, 0, 0.0, 0.0)
    base = SimConfig(track="utrack", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=10.0, effects=perfect)
    honest = SimConfig(track="utrack", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=10.0,
                       effects=replace(perfect, jpeg_quality=80, shot_noise=0.5))
    with Simulator(base) as plain, Simulator(honest) as camera:
        a, b = plain.read(), camera.read()
    assert a is not None and b is not None
    plain_image, camera_image = a.images["center"], b.images["center"]
    assert camera_image.shape == plain_image.shape == (480, 848, 3) and camera_image.dtype == np.uint8
    assert 2.0 < float(np.abs(camera_image.astype(int) - plain_image).mean()) < 15.0


def test_the_real_camera_of_a_stereo_kart_differs_from_the_ideal_one_as_measured() -> None:
    """The small kart's pair through its real cameras: a vertical offset between the two of about the residual
    (measured by matching the pair as on KITTI), the brightness held near the auto-exposure's level."""
    config = SimConfig(track="utrack", vehicle="rc-kart", cameras=("left", "right"), camera_rate_hz=10.0, seed=3,
                       effects=perfect_camera())
    real = real_camera("rc-kart")
    with Simulator(config) as ideal_sim, Simulator(SimConfig(**{**config.__dict__, "effects": real})) as real_sim:
        ideal, honest = ideal_sim.read(), real_sim.read()
    assert ideal is not None and honest is not None

    assert abs(vertical_offset_px(ideal.images["left"], ideal.images["right"])[0]) < 0.05
    offset, tracked = vertical_offset_px(honest.images["left"], honest.images["right"])
    assert tracked > 30
    print(f"\nvertical offset of the real pair: {offset:+.3f} px (residual {real.rectification_residual_px} px)")
    assert offset == pytest.approx(-real.rectification_residual_px, abs=0.08)
    assert abs(float(honest.images["left"].mean()) - real.auto_exposure_level) < 25.0


def test_a_knocked_mount_tilts_the_camera_by_its_angles_and_raises_it() -> None:
    from kartpilot.sim.simulator import mount_off

    mount = CAMERA.pose_body_cam_array
    knocked = mount_off(mount, CameraEffectsConfig(mount_pitch_deg=1.5, mount_roll_deg=-1.0, mount_height_m=0.03))
    axis, axis_knocked = mount[:3, 2], knocked[:3, 2]
    assert math.degrees(math.asin(-axis_knocked[2])) - math.degrees(math.asin(-axis[2])) == pytest.approx(1.5,
                                                                                                        abs=0.05)
    assert knocked[2, 3] - mount[2, 3] == pytest.approx(0.03)
    right, right_knocked = mount[:3, 0], knocked[:3, 0]  # the image's x axis: the camera's right
    assert math.degrees(math.asin(right_knocked[2])) - math.degrees(math.asin(right[2])) == pytest.approx(1.0,
                                                                                                        abs=0.05)


def test_a_camera_pitched_down_sees_the_far_scene_higher_in_its_image() -> None:
    """1.5 deg down about the camera itself: the whole image moves up by about f tan(1.5 deg), 16.8 px for the
    kart's 640 px lens (a rotation about the camera moves near and far alike); the calibration keeps the rig's
    mount."""
    import cv2

    base = SimConfig(track="lelystad", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=10.0,
                     effects=CameraEffectsConfig(noise_sigma=0.0))
    knocked = SimConfig(**{**base.__dict__, "effects": CameraEffectsConfig(noise_sigma=0.0, mount_pitch_deg=1.5)})
    with Simulator(base) as a, Simulator(knocked) as b:
        first, second = a.read(), b.read()
        assert b.cameras["center"] == a.cameras["center"]
    assert first is not None and second is not None
    middle = [cv2.cvtColor(f.images["center"][100:400, 100:750], cv2.COLOR_BGR2GRAY).astype(np.float32)
              for f in (first, second)]
    (dx, dy), _ = cv2.phaseCorrelate(middle[0], middle[1])
    print(f"\nthe image moved {dy:+.1f} px (expected {-CAMERA.fx_px * math.tan(math.radians(1.5)):+.1f})")
    assert dy == pytest.approx(-CAMERA.fx_px * math.tan(math.radians(1.5)), abs=1.5) and abs(dx) < 1.0

"""The simulator as a frame source and command sink: recordings, determinism, camera effects."""

import hashlib
import json
from dataclasses import replace

import numpy as np
import pytest

from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand
from kartpilot.core.vehicle import get_vehicle
from kartpilot.record.recording import RecordingReader, RecordingStereoSource
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.simulator import CameraEffectsConfig, SimConfig, Simulator, camera_poses_on_route, perfect_camera
from kartpilot.sim.track import load_track

SHORT = SimConfig(track="straight20", vehicle="rc-kart", cameras=("left", "right"), camera_rate_hz=10.0,
                  max_time_s=1.0)


def folder_digest(folder) -> str:
    digest = hashlib.sha256()
    for path in sorted(folder.rglob("*.png")):
        digest.update(path.read_bytes())
    return digest.hexdigest()


def without_wall_time(result: dict) -> dict:
    return {k: v for k, v in result.items() if k not in ("wall_time_s", "real_time_factor", "stage_ms")}


def test_same_seed_same_images_and_same_result(tmp_path):
    driver = CenterlineDriverConfig(speed_mps=1.0, weave_amplitude_m=0.1)
    runs = [run_simulation(SHORT, driver_config=driver, outputs=SessionOutputs(record_dir=tmp_path / f"run{k}"))
            for k in range(2)]
    other = run_simulation(SHORT.__class__(**{**SHORT.__dict__, "seed": 2}), driver_config=driver,
                           outputs=SessionOutputs(record_dir=tmp_path / "other"))
    digests = [folder_digest(tmp_path / f"run{k}") for k in range(2)]
    results = [json.loads((tmp_path / f"run{k}" / "result.json").read_text()) for k in range(2)]
    assert digests[0] == digests[1]
    assert without_wall_time(results[0]) == without_wall_time(results[1])
    assert folder_digest(tmp_path / "other") != digests[0]  # another seed: other sensor noise
    assert runs[0].steps == 10 and other.steps == 10


def test_a_recorded_run_holds_frames_commands_ground_truth_and_the_result(tmp_path):
    run_simulation(SHORT, outputs=SessionOutputs(record_dir=tmp_path / "rec", video_path=tmp_path / "view.mp4"))
    reader = RecordingReader(tmp_path / "rec")
    assert reader.closed and reader.stereo_pair == ("left", "right")
    assert len(reader.frames("left")) == len(reader.frames("right")) == 10
    assert len(reader.commands()) == 10
    gt = reader.groundtruth()
    assert gt is not None and len(gt) == 10
    # ground truth is the left camera's pose: 19 cm up, moving forward along +x
    assert np.allclose(gt.poses[:, 2, 3], 0.19) and gt.poses[-1, 0, 3] > gt.poses[0, 0, 3]
    source = RecordingStereoSource(tmp_path / "rec")
    assert source.rig.baseline_m == pytest.approx(0.14) and source.rig.camera.fx_px == pytest.approx(743.0)
    result = json.loads((tmp_path / "rec" / "result.json").read_text())
    for key in ("disqualified", "reason", "distance_m", "lap_time_s", "cones_hit", "mean_center_offset_m",
                "max_center_offset_m", "sim_time_s", "wall_time_s"):
        assert key in result
    assert (tmp_path / "view.mp4").stat().st_size > 1000


def test_dropped_frames_vibration_and_exposure_are_applied():
    effects = replace(perfect_camera(), drop_probability=0.5, vibration_m=0.005, exposure_gain=0.5, noise_sigma=0.0)
    config = SimConfig(track="straight20", cameras=("left",), camera_rate_hz=10.0, effects=effects, max_time_s=2.0)
    with Simulator(config) as sim:
        images = []
        sim.state = type(sim.state)(x_m=sim.state.x_m, y_m=sim.state.y_m, vx_mps=1.0)
        while (frames := sim.read()) is not None:
            images += list(frames.images.values())
            sim.send(ActuatorCommand(frames.stamp_ns, 0.0, 0.2, 0.0))
        heights = np.array(sim.camera_poses["left"])[:, 2, 3]
    assert 0 < sim.dropped_frames < 20 and len(images) == 20 - sim.dropped_frames
    assert heights.std() > 0.001  # the cameras shake
    assert max(float(image.mean()) for image in images) < 100  # half exposure: a dark image


def test_the_light_changes_at_the_given_time():
    effects = replace(perfect_camera(), noise_sigma=0.0, light_change_at_s=0.2, light_change_gain=0.3)
    config = SimConfig(track="straight20", cameras=("left",), camera_rate_hz=10.0, effects=effects, max_time_s=0.4)
    with Simulator(config) as sim:
        means = []
        while (frames := sim.read()) is not None:
            means.append(float(frames.images["left"].mean()))
            sim.send(ActuatorCommand.stop(frames.stamp_ns))
    assert len(means) == 4
    assert means[1] == pytest.approx(means[0], rel=0.02)  # before the change: the same light
    assert means[2] < 0.4 * means[1] and means[3] < 0.4 * means[1]


def test_the_simulator_stops_delivering_when_the_run_is_over():
    with Simulator(SimConfig(track="straight20", render_images=False, max_time_s=0.5)) as sim:
        steps = 0
        while (frames := sim.read()) is not None:
            sim.send(ActuatorCommand.stop(frames.stamp_ns))
            steps += 1
    assert steps == 15 and sim.done


def test_motion_blur_smooths_the_image_of_a_moving_kart():
    def sharpness(subframes: int) -> float:
        effects = CameraEffectsConfig(noise_sigma=0.0, motion_blur_subframes=subframes, exposure_time_s=0.03)
        with Simulator(SimConfig(track="straight20", cameras=("left",), effects=effects)) as sim:
            sim.state = type(sim.state)(x_m=sim.state.x_m, y_m=sim.state.y_m, vx_mps=4.0, yaw_rate_radps=0.5)
            image = sim.read().images["left"]
        gray = image.mean(axis=2)
        return float(np.var(np.diff(gray[300:], axis=0)))

    assert sharpness(4) < 0.8 * sharpness(1)


def test_the_centerline_driver_trims_against_a_kart_that_pulls_to_one_side():
    from kartpilot.sim.simulator import DisturbanceConfig

    pulled = SimConfig(track="utrack", vehicle="rc-kart", render_images=False,
                       disturbances=DisturbanceConfig(steer_bias_rad=0.03, cross_slope=True))
    runs = {trim: run_simulation(pulled, driver_config=CenterlineDriverConfig(
        speed_mps=2.0, trim_gain_rad_per_m_s=trim)).result for trim in (0.0, 0.1)}
    print(f"utrack at 2 m/s pulled 0.03 rad left: mean centre offset {runs[0.0].mean_center_offset_m:.3f} m "
          f"untrimmed, {runs[0.1].mean_center_offset_m:.3f} m trimmed")
    assert runs[0.0].mean_center_offset_m > 0.1
    assert runs[0.1].mean_center_offset_m < 0.02 and runs[0.1].finished


def test_the_video_overlay_names_the_supervisor_s_state_and_fault_on_every_frame():
    """After a fault the overlay must not read as if all were well: the supervisor's state and its reason are
    on the frame, as an alarm."""
    from kartpilot.core.types import OperatorInput
    from kartpilot.runtime.simulate import overlay_lines
    from kartpilot.runtime.supervisor import Supervisor

    sim = Simulator(SimConfig(track="straight20", vehicle="rc-kart", render_images=False))
    supervisor = Supervisor()
    drive = ActuatorCommand(0, 0.0, 0.3, 0.0)
    supervisor.step(0, [], OperatorInput(connected=True, hold=True, request="autonomous", source="test"), drive)
    assert overlay_lines(sim, supervisor)[-1] == ("supervisor: autonomous", False)
    supervisor.step(10**8, ["camera left: no frame for 0.5 s"], OperatorInput(connected=True, hold=True), drive)
    text, alarm = overlay_lines(sim, supervisor)[-1]
    assert alarm and text.startswith("supervisor: fault") and "no frame" in text
    assert not any("supervisor" in line for line, _ in overlay_lines(sim))


@pytest.mark.parametrize(("key", "value"), [("jpeg_quality", 101), ("jpeg_quality", -1), ("shot_noise", -0.1),
                                            ("shot_noise", float("nan")), ("rolling_shutter_s", -0.01),
                                            ("rolling_shutter_s", float("inf")), ("exposure_blur_samples", 1),
                                            ("exposure_blur_samples", 40), ("auto_exposure_s", float("nan")),
                                            ("auto_exposure_level", 300), ("rectification_residual_px", 9.0)])
def test_the_camera_effects_refuse_what_no_camera_does(key: str, value: float) -> None:
    from kartpilot.sim.simulator import CameraEffectsConfig

    with pytest.raises(ConfigError, match=f"sim.effects.{key}"):
        CameraEffectsConfig(**{key: value})


def test_camera_poses_on_route_put_the_rear_axle_on_the_centre_line_and_wrap_round_the_lap():
    track = load_track("straight20")
    camera = get_vehicle("rc-kart").camera("left")
    route = track.route
    first = camera_poses_on_route(track, {"left": camera}, 0)["left"]
    body = first @ np.linalg.inv(camera.pose_body_cam_array)  # the rear axle's pose
    i = track.start_index
    assert np.allclose(body[:2, 3], route.xy_m[i])
    assert np.isclose(np.arctan2(body[1, 0], body[0, 0]), route.heading_rad[i])
    assert np.array_equal(camera_poses_on_route(track, {"left": camera}, len(route.s_m))["left"], first)

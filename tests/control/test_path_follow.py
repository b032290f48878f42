"""Path following, closed loop on the simulator's vehicle model: the tracking error is what is tested."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from kartpilot.control.path_follow import (
    BiasConfig,
    PathFollowConfig,
    PathFollowState,
    path_follow_step,
    steer_bias_of_drive,
)
from kartpilot.control.stanley import StanleyConfig, stanley_steer
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand, VehiclePose
from kartpilot.core.vehicle import get_vehicle
from kartpilot.planning.reference_path import (
    PathConfig,
    ReferencePath,
    advance_progress,
    build_reference_path,
    lateral_offset,
)
from kartpilot.sim.dynamics import Disturbances, VehicleState, step_vehicle

KART = get_vehicle("rc-kart")
RATE_HZ = 15.0


def straight(length_m: float = 30.0, noise_m: float = 0.0) -> np.ndarray:
    xy = np.column_stack([np.arange(0.0, length_m, 0.04), np.zeros(int(length_m / 0.04))])
    return xy + np.random.default_rng(7).normal(0.0, noise_m, xy.shape)


def drive(path: ReferencePath, config: PathFollowConfig, start: VehicleState, seconds: float,
          bias_rad: float = 0.0, pose_noise_m: float = 0.0) -> dict[str, np.ndarray]:
    """Close the loop with the true pose (plus noise) as the odometry."""
    dt = 1.0 / RATE_HZ
    rng = np.random.default_rng(1)
    state, follow = start, PathFollowState.start(config)
    log: dict[str, list[float]] = {k: [] for k in ("t", "cross", "steer", "speed", "x", "y")}
    for k in range(int(seconds * RATE_HZ)):
        noise = rng.normal(0.0, pose_noise_m, 2)
        pose = VehiclePose(round(k * dt * 1e9), state.x_m + noise[0], state.y_m + noise[1], state.yaw_rad,
                           state.vx_mps, state.yaw_rate_radps, "ok")
        out, follow = path_follow_step(config, follow, path, pose, dt, KART.wheelbase_m, KART.max_steer_rad)
        state = step_vehicle(KART, state, ActuatorCommand(pose.stamp_ns, out.steer_rad, out.throttle, out.brake),
                             dt, Disturbances(steer_bias_rad=bias_rad))
        for key, value in (("t", k * dt), ("cross", out.cross_track_m), ("steer", out.steer_rad),
                           ("speed", state.vx_mps), ("x", state.x_m), ("y", state.y_m)):
            log[key].append(value)
        if out.done and state.vx_mps < 0.01:
            break
    return {k: np.asarray(v) for k, v in log.items()}


def true_offset_from_line(log: dict[str, np.ndarray], after_m: float) -> np.ndarray:
    return log["y"][log["x"] > after_m]


def test_stanley_law_signs_and_softening() -> None:
    config = StanleyConfig(curvature_feedforward=False)
    assert stanley_steer(config, 0.2, 0.0, 1.0) < 0  # left of the path: steer right
    assert stanley_steer(config, 0.0, 0.1, 1.0) == pytest.approx(0.05)  # k_h * heading error
    # the softening constant keeps the correction finite at standstill
    assert stanley_steer(config, 0.2, 0.0, 0.0) == pytest.approx(-math.atan(1.2 * 0.2 / 0.5))
    # in a steady bend (heading error (L + look-ahead) * curvature) the feed-forward leaves exactly atan(L k)
    ff = replace(config, curvature_feedforward=True)
    steady = (0.35 + ff.heading_lookahead_m + ff.heading_lookahead_time_s * 1.0) * 0.5
    assert stanley_steer(ff, 0.0, steady, 1.0, 0.5, 0.35) == pytest.approx(math.atan(0.175))


@pytest.mark.parametrize("controller", ["stanley", "pure_pursuit"])
def test_converges_from_an_offset_without_overshoot(controller: str) -> None:
    path = build_reference_path(straight(), PathConfig(cruise_speed_mps=0.62))
    config = PathFollowConfig(controller=controller, bias=BiasConfig(gain_rad_per_m_s=0.0))
    log = drive(path, config, VehicleState(y_m=0.3), 40.0)
    y = log["y"]
    print(f"{controller}: |y| after 8 m {np.abs(true_offset_from_line(log, 8.0)).max():.3f} m, "
          f"overshoot {max(-y.min(), 0):.3f} m")
    assert np.abs(true_offset_from_line(log, 8.0)).max() < 0.03
    assert y.min() > -0.05


def test_bias_compensation_removes_the_steady_offset_of_a_kart_that_drags_to_one_side() -> None:
    path = build_reference_path(straight(40.0), PathConfig(cruise_speed_mps=0.62))
    bias = 0.05  # the servo pulls 2.9 degrees to the left
    plain = drive(path, PathFollowConfig(bias=BiasConfig(gain_rad_per_m_s=0.0)), VehicleState(), 70.0, bias)
    compensated = drive(path, PathFollowConfig(), VehicleState(), 70.0, bias)
    steady_plain = np.abs(true_offset_from_line(plain, 20.0)).mean()
    steady_comp = np.abs(true_offset_from_line(compensated, 20.0)).mean()
    print(f"steady offset with a {bias} rad bias: {steady_plain:.3f} m plain, {steady_comp:.3f} m compensated")
    assert steady_plain > 0.02
    assert steady_comp < 0.01
    assert np.abs(compensated["y"]).max() < 0.06


@pytest.mark.parametrize("speed_mps", [0.62, 2.0])
def test_holds_a_bend_with_small_error(speed_mps: float) -> None:
    angle = np.linspace(0, np.pi, 600)
    radius = 5.0
    bend = np.column_stack([radius * np.sin(angle), radius * (1 - np.cos(angle))])
    xy = np.vstack([straight(5.0) - [5.0, 0.0], bend[1:]])
    path = build_reference_path(xy, PathConfig(cruise_speed_mps=speed_mps))
    log = drive(path, PathFollowConfig(), VehicleState(x_m=-5.0), 60.0)
    index, offsets = 0, []
    for x, y in zip(log["x"], log["y"], strict=True):
        index = advance_progress(path, x, y, index, 2.0)
        offsets.append(lateral_offset(path, index, x, y)[1])
    worst = float(np.abs(offsets).max())
    print(f"bend R {radius} m at {speed_mps} m/s: rear axle at most {worst:.3f} m from the path")
    assert worst < 0.03  # the rear axle runs L^2 / 2R = 0.012 m inside when the front axle is on the path
    assert log["speed"].max() < speed_mps * 1.15


def test_recorded_path_noise_no_longer_shakes_the_steering() -> None:
    """The thesis's configuration (raw path, heading at the nearest waypoint, hand-measured speed) against ours."""
    noisy = straight(30.0, noise_m=0.01)
    thesis_path = build_reference_path(noisy, PathConfig(smoothing_m=0.0, spacing_m=0.04, cruise_speed_mps=0.62))
    thesis = PathFollowConfig(stanley=StanleyConfig(heading_lookahead_m=0.0, heading_lookahead_time_s=0.0,
                                                    curvature_feedforward=False),
                              bias=BiasConfig(gain_rad_per_m_s=0.0), max_steer_rate_radps=100.0,
                              speed_control="constant_throttle", speed_input="assumed")
    ours_path = build_reference_path(noisy, PathConfig(cruise_speed_mps=0.62))
    runs = {"thesis": drive(thesis_path, thesis, VehicleState(), 40.0, pose_noise_m=0.005),
            "kartpilot": drive(ours_path, PathFollowConfig(), VehicleState(), 40.0, pose_noise_m=0.005)}
    rate = {k: float(np.sqrt(np.mean((np.diff(v["steer"]) * RATE_HZ) ** 2))) for k, v in runs.items()}
    print(f"steer-rate RMS: thesis {rate['thesis']:.2f} rad/s, kartpilot {rate['kartpilot']:.2f} rad/s")
    assert rate["kartpilot"] < rate["thesis"] / 3
    assert np.abs(runs["kartpilot"]["y"]).max() < 0.05


def test_the_bias_is_estimated_from_a_recorded_drive_and_removes_the_start_transient() -> None:
    path = build_reference_path(straight(40.0), PathConfig(cruise_speed_mps=2.0))
    bias = 0.04
    taught = drive(path, PathFollowConfig(), VehicleState(), 20.0, bias)
    poses = np.column_stack([taught["x"], taught["y"], np.zeros_like(taught["x"])])
    stamps = np.round(taught["t"] * 1e9).astype(np.int64)
    estimate = steer_bias_of_drive(path, poses, stamps, stamps, taught["steer"], KART.wheelbase_m)
    print(f"steering bias {bias} rad, estimated from the drive {estimate:.4f} rad")
    assert estimate == pytest.approx(bias, abs=0.005)
    cold = drive(path, PathFollowConfig(), VehicleState(), 10.0, bias)
    warm = drive(path, PathFollowConfig(bias=BiasConfig(initial_rad=estimate)), VehicleState(), 10.0, bias)
    print(f"largest offset at 2 m/s: {np.abs(cold['y']).max():.3f} m cold, {np.abs(warm['y']).max():.3f} m warm")
    assert np.abs(warm["y"]).max() < 0.3 * np.abs(cold["y"]).max()


def test_limits_and_the_end_of_the_path() -> None:
    path = build_reference_path(straight(3.0), PathConfig(cruise_speed_mps=0.62))
    config = PathFollowConfig(max_steer_rad=0.2, max_steer_rate_radps=1.0)
    pose = VehiclePose(0, 0.0, 1.0, 0.0, 0.5, 0.0, "ok")  # 1 m left: wants a hard right
    out, state = path_follow_step(config, PathFollowState(), path, pose, 0.1, KART.wheelbase_m, KART.max_steer_rad)
    assert out.steer_rad == pytest.approx(-0.1)  # rate limit: 1 rad/s for 0.1 s
    for _ in range(10):
        out, state = path_follow_step(config, state, path, pose, 0.1, KART.wheelbase_m, KART.max_steer_rad)
    assert out.steer_rad == pytest.approx(-0.2)  # range
    log = drive(path, PathFollowConfig(), VehicleState(), 30.0)
    assert log["x"][-1] == pytest.approx(path.x_m[-1], abs=0.1)  # stops at the end of the path
    with pytest.raises(ConfigError, match="controller"):
        PathFollowConfig(controller="mpc")  # type: ignore[arg-type]

"""Reference paths: resampling, smoothing, curvature, speed profile, forward-only progress, files."""

from __future__ import annotations

import numpy as np
import pytest

from kartpilot.core.errors import ConfigError, PlanningError
from kartpilot.planning.reference_path import (
    PathConfig,
    advance_progress,
    build_reference_path,
    index_ahead,
    lateral_offset,
    load_reference_path,
    save_reference_path,
)


def circle_points(radius_m: float, turns: float, count: int, noise_m: float = 0.0, seed: int = 0) -> np.ndarray:
    angle = np.linspace(0.0, 2 * np.pi * turns, count)
    xy = np.column_stack([radius_m * np.sin(angle), radius_m * (1 - np.cos(angle))])  # starts at 0, heading +x
    return xy + np.random.default_rng(seed).normal(0.0, noise_m, xy.shape)


def test_resampled_evenly_with_the_curvature_and_heading_of_a_circle() -> None:
    xy = circle_points(5.0, 0.5, 400)
    path = build_reference_path(xy, PathConfig(spacing_m=0.1, smoothing_m=0.3))
    steps = np.hypot(np.diff(path.x_m), np.diff(path.y_m))
    assert np.allclose(steps, steps[0], atol=2e-3) and 0.095 < steps[0] <= 0.1
    assert np.allclose([path.x_m[-1], path.y_m[-1]], xy[-1], atol=1e-6)  # the end is kept
    middle = slice(len(path) // 5, -len(path) // 5)
    assert np.allclose(path.curvature_per_m[middle], 0.2, rtol=0.03)  # 1 / 5 m, turning left
    assert abs(path.heading_rad[0]) < 0.05
    assert abs(path.heading_rad[-1] - np.pi) < 0.1


def test_speed_profile_slows_for_bends_and_stops_at_the_end() -> None:
    straight = np.column_stack([np.linspace(0, 20, 200), np.zeros(200)])
    bend = circle_points(2.0, 0.25, 100) + np.array([20.0, 0.0])
    config = PathConfig(cruise_speed_mps=2.0, max_lateral_accel_mps2=0.5, max_decel_mps2=1.0)
    path = build_reference_path(np.vstack([straight, bend[1:]]), config)
    on_straight = path.speed_mps[(path.s_m > 2) & (path.s_m < 12)]
    assert np.allclose(on_straight, 2.0)
    in_bend = path.speed_mps[(path.s_m > 21.0) & (path.s_m < 22.0)]
    assert np.all(in_bend <= np.sqrt(0.5 * 2.0) * 1.05)  # sqrt(a R) = 1 m/s
    assert path.speed_mps[-1] == 0.0 and path.speed_mps[0] > 0.0
    # deceleration into the bend is bounded: v^2 drops by at most 2 a ds per step
    dv2 = np.diff(path.speed_mps**2)
    assert np.all(dv2 >= -2 * config.max_decel_mps2 * config.spacing_m - 1e-9)


def test_smoothing_removes_the_frame_to_frame_heading_noise_of_a_recorded_path() -> None:
    """The thesis's oscillation came from a heading that changed at high frequency along the reference."""
    noisy = np.column_stack([np.arange(0, 20, 0.05), np.zeros(400)])
    noisy += np.random.default_rng(3).normal(0, 0.01, noisy.shape)  # 1 cm of VO noise per frame
    raw = build_reference_path(noisy, PathConfig(smoothing_m=0.0))
    smooth = build_reference_path(noisy, PathConfig(smoothing_m=0.5))
    print(f"heading std: raw {np.std(raw.heading_rad):.3f} rad, smoothed {np.std(smooth.heading_rad):.4f} rad")
    assert np.std(raw.heading_rad) > 0.05
    assert np.std(smooth.heading_rad) < 0.01


def test_progress_only_moves_forward_where_a_lap_passes_near_its_start() -> None:
    path = build_reference_path(circle_points(5.0, 0.98, 600))  # the end lies 0.6 m from the start
    assert np.hypot(path.x_m[-1] - path.x_m[0], path.y_m[-1] - path.y_m[0]) < 1.0
    start = advance_progress(path, float(path.x_m[-1]), float(path.y_m[-1]), 0, 2.0)
    assert path.s_m[start] < 2.0  # near the start: the end of the lap is not in the window
    late = len(path) - 20
    index = advance_progress(path, float(path.x_m[0]), float(path.y_m[0]), late, 2.0)
    assert index >= late  # never back to the beginning
    assert advance_progress(path, float(path.x_m[50]), float(path.y_m[50]), 10, 5.0) == 50
    assert advance_progress(path, float(path.x_m[50]), float(path.y_m[50]), 10, 2.0) == 30  # the window's end
    ahead = index_ahead(path, 50, 1.0)
    assert path.s_m[ahead - 1] - path.s_m[50] < 1.0 <= path.s_m[ahead] - path.s_m[50] + 1e-9
    assert index_ahead(path, len(path) - 3, 5.0) == len(path) - 1


def test_lateral_offset_is_positive_left_of_the_path() -> None:
    path = build_reference_path(np.column_stack([np.linspace(0, 10, 101), np.zeros(101)]))
    s, offset = lateral_offset(path, 30, 3.05, 0.2)
    assert s == pytest.approx(3.05) and offset == pytest.approx(0.2)
    assert lateral_offset(path, 30, 2.95, -0.1)[1] == pytest.approx(-0.1)


@pytest.mark.parametrize("suffix", [".csv", ".yaml"])
def test_saved_and_loaded(tmp_path, suffix: str) -> None:
    path = build_reference_path(circle_points(4.0, 0.3, 200))
    loaded = load_reference_path(save_reference_path(path, tmp_path / f"ref{suffix}"))
    for name in ("s_m", "x_m", "y_m", "heading_rad", "curvature_per_m", "speed_mps"):
        assert np.allclose(getattr(loaded, name), getattr(path, name), atol=1e-6), name


def test_bad_files_and_trajectories_give_clear_errors(tmp_path) -> None:
    with pytest.raises(PlanningError, match="no such reference path"):
        load_reference_path(tmp_path / "missing.csv")
    (tmp_path / "cols.csv").write_text("s_m,x_m,y_m\n0,0,0\n")
    with pytest.raises(PlanningError, match="heading_rad"):
        load_reference_path(tmp_path / "cols.csv")
    (tmp_path / "text.csv").write_text("s_m,x_m,y_m,heading_rad,curvature_per_m,speed_mps\n0,0,zero,0,0,1\n")
    with pytest.raises(PlanningError, match="unreadable"):
        load_reference_path(tmp_path / "text.csv")
    with pytest.raises(PlanningError, match=r"\.csv or \.yaml"):
        save_reference_path(build_reference_path(circle_points(4.0, 0.3, 200)), tmp_path / "ref.txt")
    with pytest.raises(ConfigError, match="too short"):
        build_reference_path(np.zeros((50, 2)))

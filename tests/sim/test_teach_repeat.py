"""Acceptance: the thesis's autonomous run (teach, VO reference, repeat) on straight20, at the thesis's speed
(0.62 m/s) and frame rate (12 to 13 frames/s; the default is 15), with the kart's drag and the track's slope on.
The figures are printed and bounded. Through the perfect camera, for the suite's time: through the kart's real camera
(the simulator's default) the same drive passes the same bounds but takes twice as long (134 s against 60 on a
clean clone, 2026-11-28); `make demo` drives it through the real camera."""

import json

import pytest

from kartpilot.runtime.experiment import THESIS_END_ERROR_M, TeachRepeatConfig, run_teach_repeat
from kartpilot.sim.simulator import perfect_camera


@pytest.mark.slow
def test_teach_repeat_on_straight20_ends_where_the_teach_drive_ended(tmp_path):
    result = run_teach_repeat(TeachRepeatConfig(track="straight20", speed_mps=0.62, seed=1, camera_rate_hz=12.5,
                                                effects=perfect_camera()), tmp_path, video=False, keep_teach=False)
    print(f"straight20 at 0.62 m/s: end point {result['end_error_along_m']:+.3f} m along, "
          f"{result['end_error_across_m']:+.3f} m across (thesis {THESIS_END_ERROR_M} m); "
          f"max {result['max_distance_from_taught_path_m']:.3f} m from the taught path; "
          f"steer-rate RMS {result['steer_rate_rms_radps']:.3f} rad/s; "
          f"{result['relocalised_frames']} of {result['steps']} frames relocalised")
    assert result["finished"] and not result["disqualified"] and result["cones_hit"] == 0
    assert result["stop_reason"] == "reached the end of the reference"
    assert abs(result["end_error_along_m"]) < 0.1 and abs(result["end_error_across_m"]) < 0.05
    assert result["max_distance_from_taught_path_m"] < 0.05
    assert result["steer_rate_rms_radps"] < 0.1  # no oscillation
    assert result["relocalised_frames"] > 0.8 * result["steps"]
    assert json.loads((tmp_path / "result.json").read_text())["end_error_along_m"] == result["end_error_along_m"]
    for name in ("path.png", "steering.png", "reference.csv", "reference.map.npz", "drive_log.csv"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert not (tmp_path / "teach").exists()  # the reference came from the teach drive's frames as they came

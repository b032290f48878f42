"""Values checked where they become a model (issue 56), whoever builds it: a camera with an infinite focal length,
non-finite distortion or a mirrored pose; a track tighter than the kart can turn."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import CalibrationError, ConfigError
from kartpilot.core.geometry import mount_pose

CAMERA = PinholeCamera(640.0, 640.0, 423.5, 239.5, 848, 480)


@pytest.mark.parametrize(("change", "says"), [
    ({"fx_px": math.inf}, "field of view under half a degree"),
    ({"fy_px": 1e9}, "field of view under half a degree"),
    ({"fx_px": math.nan}, "focal lengths must be positive"),
    ({"fx_px": 0.0}, "focal lengths must be positive"),
    ({"distortion": (0.1, math.nan, 0.0, 0.0, 0.0)}, "distortion coefficients must be finite"),
    ({"pose_body_cam": tuple(map(tuple, np.diag([1.0, 1.0, -1.0, 1.0])))}, "not a rigid motion"),
    ({"pose_body_cam": tuple(map(tuple, np.diag([2.0, 2.0, 2.0, 1.0])))}, "not a rigid motion"),
    ({"pose_body_cam": tuple(map(tuple, np.full((4, 4), math.nan)))}, "4x4 of finite numbers"),
], ids=["fx-inf", "fy-huge", "fx-nan", "fx-zero", "distortion-nan", "pose-mirrored", "pose-scaled", "pose-nan"])
def test_a_camera_that_cannot_be_is_refused_whoever_builds_it(change: dict, says: str) -> None:
    with pytest.raises(CalibrationError, match=says):
        replace(CAMERA, **change)


def test_a_real_mount_and_a_long_lens_are_accepted() -> None:
    camera = replace(CAMERA, fx_px=20_000.0, fy_px=20_000.0).on_body(mount_pose(1.2, 0.0, 0.56, 10.0, 6.8, 1.0))
    assert camera.fx_px == 20_000.0


def test_a_track_tighter_than_the_kart_can_turn_is_refused_naming_the_bend(tmp_path) -> None:
    """A 2 m radius hairpin: the RC kart turns it (0.72 m at full lock), the SDC kart (2.48 m) cannot."""
    from kartpilot.sim.simulator import SimConfig, Simulator

    track = tmp_path / "hairpin.yaml"
    track.write_text("name: hairpin\ncenterline:\n  closed: false\n  segments:\n    - {straight_m: 10.0}\n"
                     "    - {angle_deg: 180.0, radius_m: 2.0}\n    - {straight_m: 10.0}\nwidth_m: 2.0\n")
    Simulator(SimConfig(track=str(track), vehicle="rc-kart", render_images=False))
    with pytest.raises(ConfigError, match=r"track 'hairpin': a bend of 2.0\d m radius at \d+ m along the route is "
                                          r"tighter than the sdc-kart's tightest turn \(2.48 m at full lock\)"):
        Simulator(SimConfig(track=str(track), vehicle="sdc-kart", render_images=False))


@pytest.mark.parametrize(("change", "says"), [
    ({"wheelbase_m": 0.0}, "wheelbase_m must be a positive number"),
    ({"mass_kg": math.nan}, "mass_kg must be a positive number"),
    ({"max_steer_rad": 2.0}, "under 90 degrees"),
    ({"cg_to_rear_m": 5.0}, "lies beyond the front axle"),
    ({"steer_lag_s": -0.1}, "steer_lag_s must be zero or more"),
])
def test_a_vehicle_that_cannot_be_is_refused(change: dict, says: str) -> None:
    from kartpilot.core.vehicle import get_vehicle

    with pytest.raises(ConfigError, match=says):
        replace(get_vehicle("rc-kart"), **change)


@pytest.mark.parametrize("segments", ["    - {straight_m: 1.0e+9}\n", "    - {angle_deg: 360.0, radius_m: 1.0e+7}\n"])
def test_a_track_of_thousands_of_kilometres_is_refused_before_it_is_sampled(tmp_path, segments: str) -> None:
    from kartpilot.sim.track import load_track

    track = tmp_path / "long.yaml"
    track.write_text(f"name: long\ncenterline:\n  closed: false\n  segments:\n{segments}width_m: 2.0\n")
    with pytest.raises(ConfigError, match=r"a track is at most 20 km"):
        load_track(track)


def test_a_birdseye_view_larger_than_its_bound_or_upside_down_is_refused() -> None:
    from kartpilot.calibration.ground import BirdseyeView

    with pytest.raises(ConfigError, match="more than 40 megapixels"):
        BirdseyeView((0.0, 1e4), (-5.0, 5.0), 100.0)
    with pytest.raises(ConfigError, match="ranges from low to high"):
        BirdseyeView((8.0, 0.0))
    assert BirdseyeView().size_wh == (1000, 800)


def test_a_sweep_beyond_its_bound_is_refused_before_a_cell_is_made() -> None:
    from kartpilot.study.sweep import MAX_SWEEP_EVENTS, sweep_cells

    with pytest.raises(ConfigError, match=f"at most {MAX_SWEEP_EVENTS}"):
        sweep_cells(10**9, 0)
